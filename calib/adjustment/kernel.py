"""Residual kernel of the bundle adjustment: one observed board point -> its predicted pixel and
the Jacobian of that pixel, as one casadi function evaluated over every point.

The model of one point (DESIGN.md conventions; ``calib.adjustment.problem`` has the whole problem):

    X  = (x, y, z + warp . warp_basis)                      board frame, mm
    Y  = R1 Exp(w1) X + t1                                  pose 1: board -> device (or camera), mm
    Y  = R2 Exp(w2) Y + t2                                  pose 2 (chain 2 only): camera -> projector
    q  = K distort(Y_x / Y_z, Y_y / Y_z)                    pixels

``w1``, ``w2`` are rotation increments on the right of the reference rotations, with ``Exp`` expanded
to second order; the kernel is always evaluated at ``w = 0`` (the solver folds every accepted
increment into ``R``), so its first and second derivatives with respect to ``w`` are exact.

Structure, not data, defines a kernel: ``KernelSpec(n_distortion, chain, hessian)``. Its casadi
function is turned into C, compiled once with the system C compiler (``$CC``, else ``cc``/``gcc``) and
cached on disk (``$SLTWIN_CACHE_DIR/ba_kernels``, else ``$XDG_CACHE_HOME/sltwin/ba_kernels``, else
``~/.cache/sltwin/ba_kernels``),
keyed by this module's source, the spec, casadi's installed files and the compiler; two small C loops
beside it evaluate the points reading numpy arrays in place: ``evaluate`` (outputs per point, or
summed per row for the second-order kernels) and ``assemble`` (residuals and Jacobian entries
written straight into the adjustment's padded arrays, ``calib.adjustment.problem``). Building a
problem therefore costs the same for 100 points or 100 000, and a cached kernel loads without
importing casadi. Where no compiler works, the same function runs on casadi's virtual machine
(``Function.map``), with a one-line note in the log; both give the same numbers to rounding.

Per-point inputs (numpy float64; a shared input is a 1-D array used for every point):

| # | name | size | meaning |
|---|---|---|---|
| 0 | intr | 5 + n | fx, fy, cx, cy, skew, distortion (OpenCV order), px |
| 1 | R1 | 9 | rotation of pose 1, row-major |
| 2 | t1 | 3 | translation of pose 1, mm |
| 3 | R2 | 9 | rotation of pose 2 (chain 2 only) |
| 4 | t2 | 3 | translation of pose 2 (chain 2 only) |
| 5 | X | 3 | board point, mm |
| 6 | warp_basis | 2 | ``(1 - xn^2, 1 - yn^2)`` of the point |
| 7 | warp | 2 | board warp coefficients, mm |
| 8 | mu | 2 | (second-order kernels only) weights of the two pixel coordinates |

Output row of a point (``KernelSpec.layout``): ``q`` (2) px, ``z`` (1) mm depth in the last device
frame, then the Jacobian ``dq/dz`` (2, L) row-major with respect to the point's local variables
``z = (intr (5 + n), pose1 (6: w then t), pose2 (6, chain 2), warp (2))`` (``local_blocks``). A
second-order kernel outputs ``d2(mu . q)/dz2`` (L, L).

SYNOPSIS

    >>> import numpy as np
    >>> from calib.adjustment.kernel import KernelSpec, point_kernel
    >>> k = point_kernel(KernelSpec(0, 1), backend="vm")
    >>> out = k.evaluate([np.array([1000.0, 1000.0, 320.0, 240.0, 0.0]), np.eye(3).ravel(),
    ...                   np.array([0.0, 0.0, 500.0]), np.array([[10.0, 0.0, 0.0]]),
    ...                   np.zeros((1, 2)), np.zeros(2)])
    >>> out[0, :3].tolist()     # q = (320 + 1000 * 10 / 500, 240), z = 500
    [340.0, 240.0, 500.0]
"""
from __future__ import annotations

import ctypes
import hashlib
import logging
import os
import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..errors import BundleAdjustmentError

log = logging.getLogger(__name__)

N_INTRINSIC = 5          # fx fy cx cy skew
BACKENDS = ("auto", "compiled", "vm")
_C_FLAGS = ("-O2", "-fPIC", "-shared", "-fno-math-errno")


@dataclass(frozen=True)
class KernelSpec:
    """The structure of a point kernel: distortion terms (0, 4, 5, 8, 12), pose chain length
    (1: board -> device; 2: board -> camera -> projector), and what it computes: the prediction
    and its Jacobian blocks, or (``hessian``) the second-order term ``mu . d2q/dz2`` (L, L) of
    the point for a given ``mu`` (2,), z = (intr, pose1, pose2, warp) its local variables,
    summed over the points of each pose block."""

    n_distortion: int
    chain: int
    hessian: bool = False

    @property
    def n_intr(self) -> int:
        return N_INTRINSIC + self.n_distortion

    @property
    def n_local(self) -> int:
        """L: local variables of a point (intr, pose1 (6), pose2 (6, chain 2), warp (2))."""
        return self.n_intr + 6 * self.chain + 2

    @property
    def local_blocks(self) -> dict:
        """{block: (start, stop)} of the local variables."""
        out = {"intr": (0, self.n_intr), "pose1": (self.n_intr, self.n_intr + 6)}
        k = self.n_intr + 6
        if self.chain == 2:
            out["pose2"] = (k, k + 6)
            k += 6
        out["warp"] = (k, k + 2)
        return out

    @property
    def inputs(self) -> tuple:
        """(name, size) of the kernel's inputs, in order."""
        pose2 = (("R2", 9), ("t2", 3)) if self.chain == 2 else ()
        mu = (("mu", 2),) if self.hessian else ()
        return (("intr", self.n_intr), ("R1", 9), ("t1", 3)) + pose2 + \
               (("X", 3), ("warp_basis", 2), ("warp", 2)) + mu

    @property
    def layout(self) -> dict:
        """{block: (start, stop)} column ranges of the output row."""
        L = self.n_local
        if self.hessian:
            return {"hessian": (0, L * L)}
        return {"q": (0, 2), "z": (2, 3), "jacobian": (3, 3 + 2 * L)}

    @property
    def n_out(self) -> int:
        return max(stop for _, stop in self.layout.values())

    @property
    def name(self) -> str:
        return f"ba_point_d{self.n_distortion}_c{self.chain}" + ("_h" if self.hessian else "")


def distort_casadi(ca, x, y, c):
    """OpenCV distortion of casadi scalars ``x, y``; ``c``: 0..12 coefficients (OpenCV order)."""
    n = len(c)
    if n == 0:
        return x, y
    c = list(c) + [0.0] * (12 - n)
    k1, k2, p1, p2, k3, k4, k5, k6, s1, s2, s3, s4 = c
    r2 = x * x + y * y
    r4 = r2 * r2
    r6 = r4 * r2
    radial = 1 + k1 * r2 + k2 * r4 + k3 * r6
    if n >= 8:
        radial = radial / (1 + k4 * r2 + k5 * r4 + k6 * r6)
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    if n == 12:
        xd = xd + s1 * r2 + s2 * r4
        yd = yd + s3 * r2 + s4 * r4
    return xd, yd


def _exp_applied(ca, w, X):
    """``Exp(w) X`` to second order in ``w`` (exact value, first and second derivatives at w = 0)."""
    wX = ca.cross(w, X)
    return X + wX + 0.5 * ca.cross(w, wX)


def casadi_point_function(spec: KernelSpec):
    """The casadi ``Function`` of one point (inputs and output as in the module docstring)."""
    import casadi as ca

    syms = {name: ca.SX.sym(name, n) for name, n in spec.inputs}
    intr, X, basis, warp = syms["intr"], syms["X"], syms["warp_basis"], syms["warp"]
    Xb = ca.vertcat(X[0], X[1], X[2] + ca.dot(basis, warp))
    w1 = ca.SX.sym("w1", 3)
    R1 = ca.reshape(syms["R1"], 3, 3).T          # row-major input
    Y = R1 @ _exp_applied(ca, w1, Xb) + syms["t1"]
    pose_vars = [ca.vertcat(w1, syms["t1"])]
    increments = [w1]
    if spec.chain == 2:
        w2 = ca.SX.sym("w2", 3)
        R2 = ca.reshape(syms["R2"], 3, 3).T
        Y = R2 @ _exp_applied(ca, w2, Y) + syms["t2"]
        pose_vars.append(ca.vertcat(w2, syms["t2"]))
        increments.append(w2)
    x, y = Y[0] / Y[2], Y[1] / Y[2]
    xd, yd = distort_casadi(ca, x, y, [intr[N_INTRINSIC + j] for j in range(spec.n_distortion)])
    q = ca.vertcat(intr[0] * xd + intr[4] * yd + intr[2], intr[1] * yd + intr[3])
    if spec.hessian:
        H, _ = ca.hessian(ca.dot(syms["mu"], q), ca.vertcat(intr, *pose_vars, warp))
        out = ca.reshape(ca.densify(H), -1, 1)    # symmetric: row- and column-major alike
    else:
        J = ca.jacobian(q, ca.vertcat(intr, *pose_vars, warp))
        out = ca.vertcat(q, Y[2], ca.reshape(ca.densify(J).T, -1, 1))          # J row-major
    out = ca.substitute(out, ca.vertcat(*increments), ca.DM.zeros(3 * len(increments)))
    return ca.Function(spec.name, [syms[name] for name, _ in spec.inputs], [out])


# -- compiled backend -------------------------------------------------------------------------
_LOOP_C = """
/* sltwin: evaluate {name} over n points; input i of point k at in_base[i] + k * in_stride[i].
   Point k's output goes to row (row ? row[k] : k) of out (out_stride doubles a row), or is
   added to that row when accumulate is set. */
CASADI_SYMBOL_EXPORT int {name}_points(long long n, const double** in_base, const long long* in_stride,
                                       double* out, long long out_stride, const long long* row,
                                       int accumulate) {{
  const casadi_real* arg[{sz_arg}];
  casadi_real* res[{sz_res}];
  casadi_int iw[{sz_iw}];
  casadi_real w[{sz_w}];
  casadi_real tmp[{n_out}];
  long long k, j;
  int i;
  for (i = 0; i < {sz_arg}; ++i) arg[i] = 0;
  for (i = 0; i < {sz_res}; ++i) res[i] = 0;
  for (k = 0; k < n; ++k) {{
    double* dst = out + (row ? row[k] : k) * out_stride;
    for (i = 0; i < {n_in}; ++i) arg[i] = in_base[i] + k * in_stride[i];
    res[0] = accumulate ? tmp : dst;
    if ({name}(arg, res, iw, w, 0)) return 1;
    if (accumulate) for (j = 0; j < {n_out}; ++j) dst[j] += tmp[j];
  }}
  return 0;
}}
"""

_ASSEMBLE_C = """
/* sltwin: residuals and Jacobian entries of n points written into padded arrays: point k at
   row p = row[k]: r[2p + c] = q_c - q_obs[2k + c] (c = u, v), z[k] = depth; local Jacobian column
   j goes to Jg column jmap[j] (>= 0), to Jv column -2 - jmap[j] (<= -2), or nowhere (-1).
   Jg has n_g columns, Jv 6; rows 2p, 2p + 1. Jg == 0: residuals only. */
CASADI_SYMBOL_EXPORT int {name}_assemble(long long n, const double** in_base, const long long* in_stride,
                                         const long long* row, const double* q_obs, const long long* jmap,
                                         long long n_g, double* r, double* z, double* Jg, double* Jv) {{
  const casadi_real* arg[{sz_arg}];
  casadi_real* res[{sz_res}];
  casadi_int iw[{sz_iw}];
  casadi_real w[{sz_w}];
  casadi_real tmp[{n_out}];
  long long k, j, p, d;
  int i, c;
  for (i = 0; i < {sz_arg}; ++i) arg[i] = 0;
  for (i = 0; i < {sz_res}; ++i) res[i] = 0;
  res[0] = tmp;
  for (k = 0; k < n; ++k) {{
    for (i = 0; i < {n_in}; ++i) arg[i] = in_base[i] + k * in_stride[i];
    if ({name}(arg, res, iw, w, 0)) return 1;
    p = row[k];
    r[2 * p] = tmp[0] - q_obs[2 * k];
    r[2 * p + 1] = tmp[1] - q_obs[2 * k + 1];
    z[k] = tmp[2];
    if (!Jg) continue;
    for (c = 0; c < 2; ++c) {{
      const double* jrow = tmp + 3 + c * {n_local};
      double* g = Jg + (2 * p + c) * n_g;
      double* v = Jv + (2 * p + c) * 6;
      for (j = 0; j < {n_local}; ++j) {{
        d = jmap[j];
        if (d >= 0) g[d] = jrow[j];
        else if (d <= -2) v[-2 - d] = jrow[j];
      }}
    }}
  }}
  return 0;
}}
"""


def c_source(spec: KernelSpec) -> str:
    """C source of the kernel: casadi's generated function plus the loop over points."""
    import casadi as ca

    f = casadi_point_function(spec)
    cg = ca.CodeGenerator(spec.name, {"with_header": False, "casadi_real": "double",
                                      "casadi_int": "long long"})
    cg.add(f)
    sizes = dict(name=spec.name, n_in=f.n_in(), n_out=spec.n_out, n_local=spec.n_local,
                 sz_arg=max(f.sz_arg(), 1), sz_res=max(f.sz_res(), 1), sz_iw=max(f.sz_iw(), 1),
                 sz_w=max(f.sz_w(), 1))
    return cg.dump() + _LOOP_C.format(**sizes) + ("" if spec.hessian else _ASSEMBLE_C.format(**sizes))


def cache_dir() -> Path:
    """Where compiled kernels are kept (see the module docstring)."""
    if os.environ.get("SLTWIN_CACHE_DIR"):
        return Path(os.environ["SLTWIN_CACHE_DIR"]) / "ba_kernels"
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "sltwin" / "ba_kernels"


def c_compiler() -> str | None:
    """The C compiler used for kernels (``$CC``, else ``cc`` or ``gcc`` on PATH), or None."""
    cc = os.environ.get("CC")
    if cc:
        return shutil.which(cc)
    return shutil.which("cc") or shutil.which("gcc")


def _cache_key(spec: KernelSpec, cc: str) -> str:
    """Hash of what determines a kernel's binary: this module's source (the model), the spec,
    casadi's installation (path, size and time of its ``__init__``), the compiler and its flags.
    Needs no symbolic work, so a cached kernel loads without importing casadi."""
    from importlib.util import find_spec

    casadi = find_spec("casadi")             # its installed files, without importing it
    stamp = os.stat(casadi.origin) if casadi and casadi.origin else None
    h = hashlib.sha256(Path(__file__).read_bytes())
    h.update(f"{spec}|{casadi and casadi.origin}|{stamp and (stamp.st_size, stamp.st_mtime_ns)}|"
             f"{os.path.basename(cc)}|{' '.join(_C_FLAGS)}".encode())
    return h.hexdigest()[:20]


def compile_kernel(spec: KernelSpec) -> Path:
    """Path of the compiled shared library of ``spec``, compiling it unless cached."""
    cc = c_compiler()
    if cc is None:
        raise BundleAdjustmentError("no C compiler found ($CC, cc, gcc)")
    folder = cache_dir()
    lib = folder / f"{spec.name}_{_cache_key(spec, cc)}.so"
    if lib.exists():
        return lib
    src = c_source(spec)
    try:
        folder.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryDirectory(dir=folder) as tmp:
            c_file = Path(tmp) / f"{spec.name}.c"
            c_file.write_text(src)
            tmp_lib = Path(tmp) / lib.name
            proc = subprocess.run([cc, *_C_FLAGS, "-o", str(tmp_lib), str(c_file), "-lm"],
                                  capture_output=True, text=True, timeout=300)
            if proc.returncode != 0:
                raise BundleAdjustmentError(f"{os.path.basename(cc)} failed: {proc.stderr.strip()[:300]}")
            os.replace(tmp_lib, lib)    # atomic: concurrent builders leave one complete file
    except OSError as exc:
        raise BundleAdjustmentError(f"cannot write the kernel cache {folder}: {exc}") from None
    return lib


class PointKernel:
    """A kernel ready to evaluate: ``evaluate(inputs) -> (N, spec.n_out)`` float64.

    ``inputs``: one array per kernel input (``spec.inputs`` order): (N, size) per point or (size,)
    shared by all points. ``backend``: "compiled" or "vm".
    """

    VM_CHUNK = 4096      # points per virtual-machine call when writing rows

    def __init__(self, spec: KernelSpec, backend: str, lib_path: Path | None = None):
        self.spec = spec
        self.backend = backend
        self.lib_path = lib_path
        self._maps = {}
        if backend == "compiled":
            self._lib = ctypes.CDLL(str(lib_path))
            fn = getattr(self._lib, f"{spec.name}_points")
            fn.restype = ctypes.c_int
            fn.argtypes = [ctypes.c_longlong, ctypes.POINTER(ctypes.c_void_p),
                           ctypes.POINTER(ctypes.c_longlong), ctypes.c_void_p, ctypes.c_longlong,
                           ctypes.c_void_p, ctypes.c_int]
            self._fn = fn
            if not spec.hessian:
                asm = getattr(self._lib, f"{spec.name}_assemble")
                asm.restype = ctypes.c_int
                asm.argtypes = [ctypes.c_longlong, ctypes.POINTER(ctypes.c_void_p),
                                ctypes.POINTER(ctypes.c_longlong)] + [ctypes.c_void_p] * 3 + \
                               [ctypes.c_longlong] + [ctypes.c_void_p] * 4
                self._asm = asm
        else:
            self._f = casadi_point_function(spec)

    def _check(self, inputs) -> tuple[list, int]:
        inputs = [np.ascontiguousarray(a, dtype=np.float64) for a in inputs]
        if len(inputs) != len(self.spec.inputs):
            raise BundleAdjustmentError(f"{self.spec.name}: expected {len(self.spec.inputs)} inputs, got {len(inputs)}")
        for a, (name, size) in zip(inputs, self.spec.inputs):
            if a.shape[-1] != size or a.ndim not in (1, 2):
                raise BundleAdjustmentError(f"{self.spec.name}: input {name} must be ({size},) or (N, {size}), got {a.shape}")
        sizes = {a.shape[0] for a in inputs if a.ndim == 2}
        if len(sizes) > 1:
            raise BundleAdjustmentError(f"{self.spec.name}: per-point inputs disagree on the point count {sorted(sizes)}")
        return inputs, (sizes.pop() if sizes else 1)

    def evaluate(self, inputs, rows=None, n_rows: int = 0, accumulate: bool = False) -> np.ndarray:
        """Outputs of the points, (N, n_out); with ``rows`` (N,) int, point k's output is row
        ``rows[k]`` of an (n_rows, n_out) array (zero elsewhere), or with ``accumulate`` the sum of
        the outputs of the points sharing a row."""
        inputs, n = self._check(inputs)
        L = self.spec.n_out
        if rows is not None:
            rows = np.ascontiguousarray(rows, dtype=np.int64)
            if rows.shape != (n,) or (n and (rows.min() < 0 or rows.max() >= n_rows)):
                raise BundleAdjustmentError(f"{self.spec.name}: rows must be ({n},) in [0, {n_rows})")
        elif accumulate:
            raise BundleAdjustmentError(f"{self.spec.name}: accumulate needs rows")
        if self.backend == "compiled":
            out = np.zeros((n_rows, L)) if rows is not None else np.empty((n, L))
            base = (ctypes.c_void_p * len(inputs))(*[a.ctypes.data for a in inputs])
            stride = (ctypes.c_longlong * len(inputs))(*[a.shape[1] if a.ndim == 2 else 0 for a in inputs])
            if n and self._fn(n, base, stride, out.ctypes.data, L,
                              None if rows is None else rows.ctypes.data, int(accumulate)):
                raise BundleAdjustmentError(f"{self.spec.name}: kernel evaluation failed")
            return out
        if rows is None:
            return self._vm(inputs, 0, n)
        out = np.zeros((n_rows, L))
        for a in range(0, n, self.VM_CHUNK):
            b = min(n, a + self.VM_CHUNK)
            if accumulate:
                np.add.at(out, rows[a:b], self._vm(inputs, a, b))
            else:
                out[rows[a:b]] = self._vm(inputs, a, b)
        return out

    def assemble(self, inputs, rows, q_obs, jmap, r, z, Jg=None, Jv=None) -> None:
        """Write the points' residuals and Jacobian entries into padded arrays (in place).

        ARGUMENTS
        - inputs: as ``evaluate``; rows (N,) int: padded point index of each point.
        - q_obs (N, 2): observed pixels; jmap (L,) int: destination of each local Jacobian column
          (>= 0: column of Jg; <= -2: column -2 - jmap of Jv; -1: dropped).
        - r (P_pad, 2): residuals ``q - q_obs`` written at ``rows``; z (N,): depths.
        - Jg (P_pad, 2, G), Jv (P_pad, 2, 6): C-contiguous float64, entries written at ``rows``
          (other entries untouched); None for residuals only.
        """
        inputs, n = self._check(inputs)
        rows = np.ascontiguousarray(rows, dtype=np.int64)
        q_obs = np.ascontiguousarray(q_obs, dtype=np.float64)
        jmap = np.ascontiguousarray(jmap, dtype=np.int64)
        if rows.shape != (n,) or q_obs.shape != (n, 2) or jmap.shape != (self.spec.n_local,) or \
                z.shape != (n,) or (n and (rows.min() < 0 or rows.max() >= len(r))):
            raise BundleAdjustmentError(f"{self.spec.name}: assemble: inconsistent shapes")
        arrays = [r, z] + ([Jg, Jv] if Jg is not None else [])
        if any(not (a.flags.c_contiguous and a.dtype == np.float64) for a in arrays):
            raise BundleAdjustmentError(f"{self.spec.name}: assemble: outputs must be C-contiguous float64")
        n_g = Jg.shape[-1] if Jg is not None else 0
        if Jg is not None and (Jg.shape != (len(r), 2, n_g) or Jv.shape != (len(r), 2, 6) or
                               jmap.max(initial=-1) >= n_g or jmap.min(initial=0) < -8):
            raise BundleAdjustmentError(f"{self.spec.name}: assemble: Jacobian arrays do not match")
        if self.backend == "compiled":
            base = (ctypes.c_void_p * len(inputs))(*[a.ctypes.data for a in inputs])
            stride = (ctypes.c_longlong * len(inputs))(*[a.shape[1] if a.ndim == 2 else 0 for a in inputs])
            if n and self._asm(n, base, stride, rows.ctypes.data, q_obs.ctypes.data, jmap.ctypes.data, n_g,
                               r.ctypes.data, z.ctypes.data, None if Jg is None else Jg.ctypes.data,
                               None if Jv is None else Jv.ctypes.data):
                raise BundleAdjustmentError(f"{self.spec.name}: kernel evaluation failed")
            return
        L = self.spec.n_local
        to_g, to_v = np.flatnonzero(jmap >= 0), np.flatnonzero(jmap <= -2)
        for a in range(0, n, self.VM_CHUNK):
            b = min(n, a + self.VM_CHUNK)
            out = self._vm(inputs, a, b)
            p = rows[a:b]
            r[p] = out[:, 0:2] - q_obs[a:b]
            z[a:b] = out[:, 2]
            if Jg is not None:
                J = out[:, 3:].reshape(b - a, 2, L)
                Jg[p[:, None], :, jmap[to_g]] = J[:, :, to_g].transpose(0, 2, 1)
                Jv[p[:, None], :, -2 - jmap[to_v]] = J[:, :, to_v].transpose(0, 2, 1)

    def _vm(self, inputs, a: int, b: int) -> np.ndarray:
        n = b - a
        if n not in self._maps:
            if len(self._maps) > 4:
                self._maps.clear()
            self._maps[n] = self._f.map(n, "serial")
        args = [a_.T[:, a:b] if a_.ndim == 2 else a_[:, None] for a_ in inputs]
        return np.asarray(self._maps[n](*args)).T.reshape(n, self.spec.n_out)


_KERNELS: dict = {}
_NOTED: set = set()


def point_kernel(spec: KernelSpec, backend: str = "auto") -> PointKernel:
    """The kernel of ``spec``: compiled (cached on disk) or on casadi's virtual machine.

    ``backend``: "auto" (compiled where a C compiler works, else the virtual machine with a
    one-line note), "compiled" (BundleAdjustmentError where it cannot be built: no compiler, a
    compiler error, a cache folder that cannot be written), "vm".
    """
    if backend not in BACKENDS:
        raise BundleAdjustmentError(f"backend: expected one of {BACKENDS}, got {backend!r}")
    if backend == "auto":
        try:
            return point_kernel(spec, "compiled")
        except BundleAdjustmentError as exc:
            if "vm" not in _NOTED:
                _NOTED.add("vm")
                log.warning("bundle adjustment: residuals on casadi's virtual machine (slower): %s", exc)
            return point_kernel(spec, "vm")
    key = (spec, backend)
    if key not in _KERNELS:
        _KERNELS[key] = PointKernel(spec, backend, compile_kernel(spec) if backend == "compiled" else None)
    return _KERNELS[key]
