"""The plane-fit kernel of :mod:`unwrap.learned._plane_kernel` in C, bit for bit, loaded with ctypes.

Why: the numpy replica (:mod:`unwrap.learned._plane_numpy`) spares a one-capture ``calib unwrap
--model`` numba's ~1 s of start-up but spends ~0.1 s of CPU a box on numpy's per-step overhead;
the same loops in C take ~10-20 ms a box and load in ~1 ms. The source below is
``_plane_kernel``'s functions line for line (one thread: no ``prange``), compiled once by the
system C compiler without fast-math and with ``-ffp-contract=off`` (no fused multiply-adds, as
numba compiles), and cached on disk (``$SLTWIN_CACHE_DIR/unwrap_kernels``, else
``$XDG_CACHE_HOME/sltwin/unwrap_kernels``, else ``~/.cache/sltwin/unwrap_kernels``) under a hash of
the source, the compiler (``$CC``, which may carry arguments: ``ccache gcc``), its flags and the
machine's architecture. Same operations in the same order: the outputs are bitwise the compiled
kernel's (tests/test_plane_numpy.py); each process checks that on a small frame against the numpy
replica before using the library (a compiler that defaults to fast-math, a foreign or damaged file)
and falls back to numpy where the bits differ; a damaged cached file is rebuilt, a refused build is
not cached but remembered (:func:`_build`).

:func:`kernel` returns ``plane_filter_c(Phi, valid, r)``, or None where there is no C compiler or
the cache cannot be written (the caller then runs the numpy replica).
"""
from __future__ import annotations

import hashlib
import os
import platform
import shlex
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np

BLOCK = 64
"""Outputs per sliding run (:data:`unwrap.learned._plane_kernel.BLOCK`; a test holds them equal)."""

_FLAGS = ("-O2", "-fPIC", "-shared", "-fno-math-errno", "-ffp-contract=off")

_SOURCE = r"""
#include <stddef.h>

static void row_block(const double *Phi, const unsigned char *valid, long W, long r, long y, long x0,
                      long x1, double *h, size_t HW) {
    double a0 = 0.0, a1 = 0.0, a2 = 0.0, a3 = 0.0, a4 = 0.0;
    const double *P = Phi + (size_t)y * W;
    const unsigned char *v = valid + (size_t)y * W;
    long lo = x0 - r > 0 ? x0 - r : 0, hi = x0 + r < W - 1 ? x0 + r : W - 1;
    for (long xx = lo; xx <= hi; xx++) {
        if (v[xx]) {
            long d = xx - x0;
            double p = P[xx];
            a0 += 1.0;
            a1 += (double)d;
            a2 += (double)(d * d);
            a3 += p;
            a4 += p * (double)d;
        }
    }
    long x = x0;
    for (;;) {
        size_t i = (size_t)y * W + x;
        h[i] = a0; h[HW + i] = a1; h[2 * HW + i] = a2; h[3 * HW + i] = a3; h[4 * HW + i] = a4;
        x += 1;
        if (x >= x1) break;
        a2 = a2 - 2.0 * a1 + a0;
        a1 = a1 - a0;
        a4 = a4 - a3;
        long xo = x - r - 1;
        if (xo >= 0 && v[xo]) {
            double p = P[xo];
            a0 -= 1.0;
            a1 += (double)(r + 1);
            a2 -= (double)((r + 1) * (r + 1));
            a3 -= p;
            a4 += p * (double)(r + 1);
        }
        long xi = x + r;
        if (xi < W && v[xi]) {
            double p = P[xi];
            a0 += 1.0;
            a1 += (double)r;
            a2 += (double)(r * r);
            a3 += p;
            a4 += p * (double)r;
        }
    }
}

static void solve(const double *Phi, const unsigned char *valid, long W, long y, const double *S,
                  double *out) {
    for (long x = 0; x < W; x++) {
        size_t i = (size_t)y * W + x;
        if (!valid[i]) { out[i] = Phi[i]; continue; }
        double S0 = S[x], Sx = S[W + x], Sy = S[2 * W + x], Sxx = S[3 * W + x], Syy = S[4 * W + x];
        double Sxy = S[5 * W + x], SP = S[6 * W + x], SxP = S[7 * W + x], SyP = S[8 * W + x];
        double det = S0 * (Sxx * Syy - Sxy * Sxy) - Sx * (Sx * Syy - Sxy * Sy) + Sy * (Sx * Sxy - Sxx * Sy);
        double t = Sxx + Syy;
        double scale = S0 * (t * t) + 1e-12;
        if (S0 >= 3.0 && det > 1e-6 * scale) {
            double num = SP * (Sxx * Syy - Sxy * Sxy) - Sx * (SxP * Syy - Sxy * SyP) + Sy * (SxP * Sxy - Sxx * SyP);
            out[i] = num / det;
        } else {
            out[i] = SP / (S0 < 1.0 ? 1.0 : S0);
        }
    }
}

static void add_row(double *S, const double *h, long W, size_t HW, long yy, double d, double sign) {
    const double *h0r = h + (size_t)yy * W, *h1r = h + HW + (size_t)yy * W, *h2r = h + 2 * HW + (size_t)yy * W;
    const double *h3r = h + 3 * HW + (size_t)yy * W, *h4r = h + 4 * HW + (size_t)yy * W;
    for (long x = 0; x < W; x++) {
        double h0 = h0r[x], h1 = h1r[x], h3 = h3r[x];
        S[x] += sign * h0;
        S[W + x] += sign * h1;
        S[2 * W + x] += sign * (h0 * d);
        S[3 * W + x] += sign * h2r[x];
        S[4 * W + x] += sign * (h0 * (d * d));
        S[5 * W + x] += sign * (h1 * d);
        S[6 * W + x] += sign * h3;
        S[7 * W + x] += sign * h4r[x];
        S[8 * W + x] += sign * (h3 * d);
    }
}

static void col_block(const double *Phi, const unsigned char *valid, long H, long W, long r, long y0, long y1,
                      const double *h, double *out, double *S) {
    size_t HW = (size_t)H * W;
    for (long k = 0; k < 9 * W; k++) S[k] = 0.0;
    long lo = y0 - r > 0 ? y0 - r : 0, hi = y0 + r < H - 1 ? y0 + r : H - 1;
    for (long yy = lo; yy <= hi; yy++) add_row(S, h, W, HW, yy, (double)(yy - y0), 1.0);
    long y = y0;
    for (;;) {
        solve(Phi, valid, W, y, S, out);
        y += 1;
        if (y >= y1) break;
        for (long x = 0; x < W; x++) {
            S[4 * W + x] = S[4 * W + x] - 2.0 * S[2 * W + x] + S[x];
            S[2 * W + x] = S[2 * W + x] - S[x];
            S[5 * W + x] = S[5 * W + x] - S[W + x];
            S[8 * W + x] = S[8 * W + x] - S[6 * W + x];
        }
        if (y - r - 1 >= 0) add_row(S, h, W, HW, y - r - 1, (double)(-r - 1), -1.0);
        if (y + r < H) add_row(S, h, W, HW, y + r, (double)r, 1.0);
    }
}

void plane_filter(const double *Phi, const unsigned char *valid, long H, long W, long r, long block,
                  double *h, double *S, double *out) {
    size_t HW = (size_t)H * W;
    for (long y = 0; y < H; y++)
        for (long x0 = 0; x0 < W; x0 += block)
            row_block(Phi, valid, W, r, y, x0, x0 + block < W ? x0 + block : W, h, HW);
    for (long y0 = 0; y0 < H; y0 += block)
        col_block(Phi, valid, H, W, r, y0, y0 + block < H ? y0 + block : H, h, out, S);
}
"""

_LIB = []


def cache_dir() -> Path:
    """Where the compiled library is kept (module docstring)."""
    if os.environ.get("SLTWIN_CACHE_DIR"):
        return Path(os.environ["SLTWIN_CACHE_DIR"]) / "unwrap_kernels"
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "sltwin" / "unwrap_kernels"


_STALE_S = 600.0
"""Age (s) after which a build folder in the cache is a killed compile's (a compile times out at 120 s)."""


def _bind(path: Path):
    """``plane_filter`` of the library at ``path``, typed, if it loads and gives the numpy replica's
    bits (:func:`_same_bits`); else None."""
    import ctypes

    try:
        f = ctypes.CDLL(str(path)).plane_filter
    except (OSError, AttributeError):
        return None
    ptr, lng = ctypes.c_void_p, ctypes.c_long
    f.argtypes, f.restype = [ptr, ptr, lng, lng, lng, lng, ptr, ptr, ptr], None
    return f if _same_bits(f) else None


def _sweep(folder: Path) -> None:
    """Remove build folders a killed compile left (older than :data:`_STALE_S`; a younger one may be
    another process's build in progress)."""
    import time

    for d in folder.glob("tmp*"):
        try:
            if d.is_dir() and time.time() - d.stat().st_mtime > _STALE_S:
                shutil.rmtree(d, ignore_errors=True)
        except OSError:
            pass


def _build():
    """The loaded library, compiling it unless cached; None when that cannot be done.

    A cached library that does not load or gives other bits (damaged, or built by another compiler
    under the same name) is rebuilt. A build the check refuses, or a compiler that fails, leaves a
    ``.refused`` file beside the library's name saying why, so later processes go straight to the
    numpy replica instead of compiling again (delete it to retry; a compile that timed out leaves
    none). The library is loaded and checked from its build folder before it is moved into place,
    so a refused build is never cached."""
    try:
        cc = shlex.split(os.environ.get("CC", "")) or [shutil.which("cc") or shutil.which("gcc")]
    except ValueError:                                  # an unbalanced quote in $CC: no compiler
        return None
    if cc[0] is None:
        return None
    key = hashlib.sha256("\0".join((_SOURCE, *cc, *_FLAGS, platform.machine())).encode()).hexdigest()[:16]
    folder = cache_dir()
    lib, refused = folder / f"plane_filter_{key}.so", folder / f"plane_filter_{key}.refused"
    try:
        folder.mkdir(mode=0o755, parents=True, exist_ok=True)          # writable by this user only
        if not _trusted(folder):
            return None
        if lib.is_file():
            if not _trusted(lib):
                return None
            f = _bind(lib)
            if f is not None:
                return f
        if refused.is_file():
            return None
        _sweep(folder)
        with tempfile.TemporaryDirectory(dir=folder) as tmp:
            src, out = Path(tmp) / "plane.c", Path(tmp) / "plane.so"
            src.write_text(_SOURCE)
            proc = subprocess.run([*cc, *_FLAGS, "-o", str(out), str(src)], capture_output=True, timeout=120)
            if proc.returncode == 0:
                os.chmod(out, 0o755)
                f = _bind(out)           # a path this process never loaded: not the refused file's handle
            why = (f"{' '.join(cc)} exited {proc.returncode}: {proc.stderr.decode(errors='replace')[-500:]}"
                   if proc.returncode else "the built library's bits differ from the numpy replica's")
            if proc.returncode or f is None:
                note = Path(tmp) / "refused"
                note.write_text(why + "\n")
                os.replace(note, refused)
                return None
            os.replace(out, lib)                  # atomic: another process may build it too
            return f
    except (OSError, ValueError, subprocess.SubprocessError):
        return None


def _trusted(path: Path) -> bool:
    """Whether ``path`` is this user's and writable by no one else: a library loaded from it runs
    inside this process, so a cache folder others can write to (``$SLTWIN_CACHE_DIR=/tmp``, a
    shared folder) is not used (the numpy replica runs)."""
    st = path.stat()
    return st.st_uid == os.getuid() and not st.st_mode & 0o022


def _same_bits(f) -> bool:
    """Whether the library gives the numpy replica's bits on a small noisy frame with holes, two
    blocks each way and both boxes' radii (a few ms once per process; module docstring)."""
    from ._plane_numpy import plane_filter_numpy

    rng = np.random.default_rng(7)
    Phi, valid = rng.normal(0.0, 3.0, (13, 11)), rng.random((13, 11)) > 0.2
    for r in (3, 7):
        h, S, out = np.empty((5, 13, 11)), np.empty((9, 11)), np.empty_like(Phi)       # held while f runs
        f(Phi.ctypes.data, valid.ctypes.data, 13, 11, r, 8, h.ctypes.data, S.ctypes.data, out.ctypes.data)
        if out.tobytes() != plane_filter_numpy(Phi, valid, r, block=8).tobytes():
            return False
    return True


def kernel():
    """``plane_filter_c(Phi, valid, r, block=BLOCK)`` (module docstring), or None."""
    if not _LIB:
        _LIB.append(_build())
    f = _LIB[0]
    if f is None:
        return None

    def plane_filter_c(Phi, valid, r, block: int = BLOCK):
        Phi = np.ascontiguousarray(Phi, dtype=np.float64)
        valid = np.ascontiguousarray(valid, dtype=bool)
        H, W = Phi.shape
        h, S, out = np.empty((5, H, W)), np.empty((9, W)), np.empty((H, W))
        f(Phi.ctypes.data, valid.ctypes.data, H, W, int(r), int(block), h.ctypes.data, S.ctypes.data,
          out.ctypes.data)
        return out
    return plane_filter_c
