"""Small C kernels compiled at run time by the system C compiler, cached on disk, loaded with ctypes.

A kernel here replicates a numba kernel's float64 operations in C so that a process can skip
numba's ~1 s start-up (import, lowering registries, cached machine code) without changing a bit
of the result. :func:`build` compiles ``source`` once per machine without fast-math and with
``-ffp-contract=off`` (no fused multiply-adds, as numba compiles) into the cache folder
(``$SLTWIN_CACHE_DIR/unwrap_kernels``, else ``$XDG_CACHE_HOME/sltwin/unwrap_kernels``, else
``~/.cache/sltwin/unwrap_kernels``) under a hash of the source, the compiler (``$CC``, which may
carry arguments: ``ccache gcc``; and the size and time of the programs it names, so an upgraded
compiler builds afresh), the flags and the machine's architecture, and loads it (~1 ms).
A library is loaded only from a folder and file this user owns and no one else can write: it runs
inside this process. The caller checks the loaded functions' bits against a numpy replica on a
small input before it uses them (a compiler that defaults to fast-math, a damaged file).

The same scheme as :mod:`unwrap.learned._plane_c` (the features' plane fit), shared here for the
traditional decode's fused kernel (:mod:`unwrap._fused_c`).
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

FLAGS = ("-O3", "-march=native", "-fPIC", "-shared", "-fno-math-errno", "-fno-trapping-math", "-ffp-contract=off")
"""Compiler flags: optimised for this CPU's vector units, no fast-math, no contraction of ``a * b + c``
into one rounding (``-fno-trapping-math`` only lets selects be computed branch-free: floating-point
traps, not values). Where the compiler refuses ``-march=native`` it is dropped."""


def cpu_id() -> str:
    """This machine's CPU as far as compiled code cares (``/proc/cpuinfo``'s model and feature flags;
    elsewhere the platform's processor string): a library built with ``-march=native`` is cached per
    CPU, so that a home folder shared by machines of different CPUs never loads a foreign build."""
    try:
        with open("/proc/cpuinfo") as f:
            lines = [ln for ln in f.read(1 << 16).splitlines() if ln.startswith(("model name", "flags", "Features"))]
        return "\n".join(dict.fromkeys(lines))
    except OSError:
        return platform.processor()


def cache_dir() -> Path:
    """Where compiled libraries are kept (module docstring)."""
    if os.environ.get("SLTWIN_CACHE_DIR"):
        return Path(os.environ["SLTWIN_CACHE_DIR"]) / "unwrap_kernels"
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "sltwin" / "unwrap_kernels"


def trusted(path: Path) -> bool:
    """Whether ``path`` is this user's and writable by no one else (a shared cache folder such as
    ``$SLTWIN_CACHE_DIR=/tmp`` is not used: the caller falls back to its other engine)."""
    st = path.stat()
    return st.st_uid == os.getuid() and not st.st_mode & 0o022


TIMEOUT_S = 30.0
"""Wall-clock limit (s) of one compile. The largest kernel here compiles in ~1.5 s on an idle core
(``unwrap/_fused_c.py``; the plane kernel in ~0.25 s): 30 s leaves a margin of ~20x for a loaded
machine or a cold disk, where a compiler that hangs cost 120 s before."""

RETRY_TIMED_OUT_S = 86400.0
"""Age (s) after which a compile that timed out is tried again (its ``.refused`` note is a day old): a
timeout may have been a passing load rather than a compiler that hangs."""

STALE_S = 600.0
"""Age (s) after which a build folder in the cache is a killed compile's (a compile times out at
:data:`TIMEOUT_S`)."""


def _sweep(folder: Path) -> None:
    """Remove build folders a killed compile left (older than :data:`STALE_S`; a younger one may be
    another process's build in progress)."""
    import time

    for d in folder.glob("tmp*"):
        try:
            if d.is_dir() and time.time() - d.stat().st_mtime > STALE_S:
                shutil.rmtree(d, ignore_errors=True)
        except OSError:
            pass


def _open(path: Path, check):
    """``check(ctypes.CDLL(path))``, or None where the library does not load or ``check`` refuses it."""
    import ctypes

    try:
        return check(ctypes.CDLL(str(path)))
    except (OSError, AttributeError):
        return None


def compiler_identity(cc) -> tuple:
    """Which programs ``cc`` (the compiler's command words) runs: for each word that names an
    executable on the PATH, its resolved path, size and modification time (ns). Upgrading or
    reinstalling the compiler changes them, so a library or a refusal note of the old one is not
    taken for the new one's (no ``cc --version`` run: a stat costs microseconds)."""
    out = []
    for word in cc:
        found = shutil.which(word)
        if found:
            real = os.path.realpath(found)
            try:
                st = os.stat(real)
            except OSError:
                continue
            out.append(f"{real}:{st.st_size}:{st.st_mtime_ns}")
    return tuple(out)


def _refused_path(name: str, source: str, cc, flags) -> Path:
    """``NAME_HASH.refused`` in the cache (the library beside it: ``NAME_HASH.so``), HASH of the source,
    the compiler (its words and :func:`compiler_identity`), the flags and the machine (module docstring)."""
    key = hashlib.sha256("\0".join((source, *cc, *compiler_identity(cc), *flags, platform.machine(),
                                     cpu_id())).encode()).hexdigest()[:16]
    return cache_dir() / f"{name}_{key}.refused"


NO_NATIVE = "-march=native refused"
"""How the note of a compiler that fails with ``-march=native`` begins: the build goes on without it,
under its own key, library and note."""


_KILLED = (b"Killed signal terminated program", b"internal compiler error: Killed", b"unable to execute command",
           b"due to signal")
"""What a compiler driver prints, exiting with a positive status, when a program it ran was killed by a
signal (gcc: ``fatal error: Killed signal terminated program cc1``; clang: ``unable to execute command:
Killed``, ``... failed due to signal``): the out-of-memory killer's victim, not a refusal."""


def _still_refused(note: Path) -> str | None:
    """The first line of the refusal ``note`` where it holds, else None: every note holds but a
    timed-out compile's older than :data:`RETRY_TIMED_OUT_S`."""
    import time

    try:
        with open(note, "rb") as f:
            first = f.readline().decode(errors="replace")
        timed_out = first.startswith("timed out")
        return first if not timed_out or time.time() - note.stat().st_mtime <= RETRY_TIMED_OUT_S else None
    except OSError:           # removed meanwhile (another process retried it): not refused
        return None


def _without_native(flags) -> tuple:
    return tuple(x for x in flags if x != "-march=native")


def _leave_note(tmp: Path, refused: Path, text: str) -> None:
    """Write ``text`` as the refusal note ``refused`` (atomically, through the build folder ``tmp``)."""
    note = Path(tmp) / "refused"
    note.write_text(text)
    os.replace(note, refused)


def _run_compiler(cmd, tmp: Path):
    """``(exit status, output bytes)`` of ``cmd``, run in its own process group with its output in a
    file of ``tmp``. After :data:`TIMEOUT_S` (``subprocess.TimeoutExpired``), or when this process is
    interrupted (KeyboardInterrupt, re-raised), the whole group is killed: a compiler driver's
    children (``cc1``, ``as``, ``ld``) too, which would otherwise run on, and no pipe is left for
    this process to wait on until they end."""
    import signal

    log, proc = tmp / "compiler-output", None
    try:
        with open(log, "wb") as f:
            proc = subprocess.Popen(cmd, stdin=subprocess.DEVNULL, stdout=f, stderr=subprocess.STDOUT,
                                    env={**os.environ, "LC_ALL": "C"},    # untranslated messages (build reads them)
                                    start_new_session=hasattr(os, "killpg"))
        rc = proc.wait(timeout=TIMEOUT_S)
    except BaseException:
        if proc is None:
            raise
        try:
            if hasattr(os, "killpg"):
                os.killpg(proc.pid, signal.SIGKILL)
            else:                                           # no process groups (not POSIX)
                proc.kill()
        except OSError:
            pass
        proc.wait()
        raise
    return rc, log.read_bytes()


def build(name: str, source: str, check=None, flags=FLAGS):
    """``check(dll)`` of ``source`` compiled with ``flags`` and cached as ``NAME_HASH.so`` (``check``
    None: the ``ctypes.CDLL`` itself), or None where there is no C compiler, the compile fails, the
    cache is not this user's alone or ``check`` returns None (its bits are not the replica's).

    A cached library that does not load or that ``check`` refuses (damaged, or built by another
    compiler under the same name) is rebuilt. A build ``check`` refuses, or a compiler that fails,
    leaves ``NAME_HASH.refused`` saying why, so that later processes go straight to their fallback
    instead of compiling again (delete it to retry). A compiler that fails with ``-march=native``
    leaves one saying so, and the build goes on without the flag under its own key: later processes
    load that library, or read its note, without compiling. A compile that runs over
    :data:`TIMEOUT_S` is killed with its children and leaves one too, retried once it is
    :data:`RETRY_TIMED_OUT_S` old. A compiler that cannot be run, a compile killed by a signal or
    interrupted, or one that failed for want of disk space, leaves none. A new build is loaded and
    checked in its build folder before it is moved into place: a refused build is never cached.
    Build folders a killed compile left are swept after :data:`STALE_S`."""
    check = check or (lambda dll: dll)
    try:
        cc = shlex.split(os.environ.get("CC", "")) or [shutil.which("cc") or shutil.which("gcc")]
    except ValueError:                                  # an unbalanced quote in $CC: no compiler
        return None
    if cc[0] is None:
        return None
    folder = cache_dir()
    if folder.parts[0].startswith("~"):     # no home folder to expand "~" to: no cache (not a "~" folder here)
        return None
    refused = _refused_path(name, source, cc, flags)
    lib = refused.with_suffix(".so")
    try:
        folder.mkdir(mode=0o755, parents=True, exist_ok=True)      # writable by this user only
        if not trusted(folder):
            return None
        if lib.is_file():
            if not trusted(lib):
                return None
            got = _open(lib, check)
            if got is not None:
                return got
        why = _still_refused(refused) if refused.is_file() else None
        if why is not None:
            # a compiler that refuses -march=native: straight to the build without it
            return build(name, source, check, _without_native(flags)) if why.startswith(NO_NATIVE) else None
        _sweep(folder)
        with tempfile.TemporaryDirectory(dir=folder) as tmp:
            src, out = Path(tmp) / f"{name}.c", Path(tmp) / f"{name}.so"
            src.write_text(source)
            try:
                returncode, output = _run_compiler([*cc, *flags, "-o", str(out), str(src)], Path(tmp))
            except subprocess.TimeoutExpired:         # remembered: later processes fall back at once
                _leave_note(tmp, refused, f"timed out: {' '.join(cc)} ran over {TIMEOUT_S:g} s and was killed "
                                          f"(tried again when this note is {RETRY_TIMED_OUT_S / 3600:g} h old, or "
                                          "delete it)\n")
                return None
            if returncode < 0:       # killed by a signal (out of memory, interrupted): not a refusal
                return None
            if returncode and any(m in output for m in (b"No space left on device", *_KILLED)):
                return None     # a full disk passes, and so does a cc1 / ld killed (out of memory): not refusals
            if returncode and "-march=native" in flags:       # a compiler that refuses it
                # remembered: later processes go straight to the build without it (its own library
                # and note), not through this failing compile again
                plain = _without_native(flags)
                _leave_note(tmp, refused, f"{NO_NATIVE}: {' '.join(cc)} exited {returncode} with it; built without "
                                          f"it: {_refused_path(name, source, cc, plain).stem}\n"
                                          f"{output.decode(errors='replace')[-500:]}\n")
                return build(name, source, check, plain)
            got = None
            if returncode == 0:
                os.chmod(out, 0o755)
                got = _open(out, check)     # a path this process never loaded: not a refused file's handle
            if got is None:
                _leave_note(tmp, refused, f"{' '.join(cc)} exited {returncode}: "
                                          f"{output.decode(errors='replace')[-500:]}\n" if returncode else
                                          "the built library failed its check (its bits differ from the replica's)\n")
                return None
            os.replace(out, lib)                  # atomic: another process may build it too
            refused.unlink(missing_ok=True)       # a timed-out compile's note, retried
            return got
    except (OSError, ValueError, subprocess.SubprocessError):
        return None
