"""The run-time C builder (unwrap._native.build) when its compiler misbehaves: a compile that hangs is
killed with its children and remembered (later processes fall back at once, retried after a day),
an interrupted compile is not remembered, a compiler that fails for want of disk space is not
remembered, and a cache folder this process cannot write to falls back without raising."""
from __future__ import annotations

import os
import shutil
import time
from pathlib import Path

import pytest

from unwrap import _native

SRC = "int f(void) { return 7; }"


def _fake_cc(tmp_path: Path, body: str) -> str:
    """A compiler script that logs each run to ``tmp_path/calls`` then runs ``body``."""
    cc = tmp_path / "fake-cc"
    cc.write_text(f"#!/bin/sh\necho run >> {tmp_path / 'calls'}\n{body}\n")
    cc.chmod(0o755)
    return str(cc)


def _calls(tmp_path: Path) -> int:
    f = tmp_path / "calls"
    return f.read_text().count("run") if f.exists() else 0


def _gone(pid: int, within_s: float = 10.0) -> bool:
    """Whether process ``pid`` has ended (or is a zombie) within ``within_s``."""
    end = time.monotonic() + within_s
    while time.monotonic() < end:
        try:
            with open(f"/proc/{pid}/stat") as f:
                if f.read().rsplit(")", 1)[1].split()[0] == "Z":
                    return True
        except OSError:
            return True
        time.sleep(0.05)
    return False


def _kernels(tmp_path: Path) -> Path:
    return tmp_path / "c" / "unwrap_kernels"


@pytest.mark.skipif(not Path("/proc").is_dir() or shutil.which("sleep") is None, reason="needs /proc and sleep")
def test_a_hanging_compile_is_killed_with_its_children_and_remembered(tmp_path, monkeypatch):
    """The compiler (and the child it started, as gcc starts cc1) is killed after TIMEOUT_S; a
    ``.refused`` note makes the next process fall back without compiling; the note of a timeout is
    retried once it is RETRY_TIMED_OUT_S old, and a build that then succeeds removes it."""
    monkeypatch.setenv("SLTWIN_CACHE_DIR", str(tmp_path / "c"))
    monkeypatch.setattr(_native, "TIMEOUT_S", 0.5)
    real = shutil.which("cc") or shutil.which("gcc")
    hang = tmp_path / "hang"
    hang.touch()
    monkeypatch.setenv("CC", _fake_cc(tmp_path, f'if [ -e {hang} ]; then sleep 120 & echo $! > {tmp_path / "child"}; '
                                                f'wait; fi\nexec {real or "false"} "$@"'))
    assert _native.build("t", SRC) is None
    assert _calls(tmp_path) == 1                             # a timeout is not -march=native's refusal
    assert _gone(int((tmp_path / "child").read_text()))      # the compiler's child killed too
    notes = list(_kernels(tmp_path).glob("t_*.refused"))
    assert len(notes) == 1 and notes[0].read_text().startswith("timed out")
    assert not list(_kernels(tmp_path).glob("tmp*"))          # no build folder left
    assert _native.build("t", SRC) is None
    assert _calls(tmp_path) == 1                             # remembered: no compile, no wait
    if real is None:
        return
    hang.unlink()                                            # the load has passed
    old = time.time() - _native.RETRY_TIMED_OUT_S + 3600
    os.utime(notes[0], (old, old))
    assert _native.build("t", SRC) is None and _calls(tmp_path) == 1      # younger than a day: still held
    old = time.time() - _native.RETRY_TIMED_OUT_S - 60
    os.utime(notes[0], (old, old))
    lib = _native.build("t", SRC)
    assert lib is not None and lib.f() == 7 and _calls(tmp_path) == 2
    assert not notes[0].exists()


def test_a_failing_compilers_note_does_not_expire(tmp_path, monkeypatch):
    """Only a timeout's note is retried after a day; a compiler that failed stays refused."""
    monkeypatch.setenv("SLTWIN_CACHE_DIR", str(tmp_path / "c"))
    monkeypatch.setenv("CC", _fake_cc(tmp_path, "echo 'error: no math.h' >&2; exit 1"))
    assert _native.build("t", SRC) is None and _calls(tmp_path) == 2
    notes = list(_kernels(tmp_path).glob("t_*.refused"))
    assert len(notes) == 2 and any("no math.h" in n.read_text() for n in notes)
    old = time.time() - 10 * _native.RETRY_TIMED_OUT_S
    for n in notes:
        os.utime(n, (old, old))
    assert _native.build("t", SRC) is None and _calls(tmp_path) == 2


@pytest.mark.skipif(not hasattr(os, "killpg"), reason="POSIX process groups")
def test_an_interrupted_compile_is_not_remembered(tmp_path, monkeypatch):
    """Ctrl-C during a compile: KeyboardInterrupt reaches the caller, the compiler is killed with its
    children, and no note is left (the next process compiles).

    The interrupt is raised where Python's default SIGINT handler raises it, in this process's wait
    for the compiler, once the compiler's child runs. (A real SIGINT sent by the fake compiler was
    lost once in a full suite run and in none of ~20 runs since, alone or after the learned tests;
    a likely cause, not confirmed: CPython runs a signal's handler at the next bytecode, and one run
    inside a finaliser, e.g. a garbage collection during the wait, only reports the
    KeyboardInterrupt as unraisable.)"""
    import subprocess

    child = tmp_path / "child"
    monkeypatch.setenv("SLTWIN_CACHE_DIR", str(tmp_path / "c"))
    monkeypatch.setenv("CC", _fake_cc(tmp_path, f"sleep 120 & echo $! > {child}.tmp; mv {child}.tmp {child}; wait"))
    wait = subprocess.Popen.wait

    def interrupted(self, timeout=None):
        if timeout is None:                         # the wait after the kill
            return wait(self)
        deadline = time.monotonic() + 20
        while not child.exists() and time.monotonic() < deadline:
            time.sleep(0.01)
        raise KeyboardInterrupt

    monkeypatch.setattr(subprocess.Popen, "wait", interrupted)
    with pytest.raises(KeyboardInterrupt):
        _native.build("t", SRC)
    assert _gone(int(child.read_text()))
    assert not list(_kernels(tmp_path).glob("t_*.refused")) and not list(_kernels(tmp_path).glob("tmp*"))


@pytest.mark.parametrize("message", ["fatal error: error writing to /tmp/ccX.s: No space left on device",
                                     "gcc: fatal error: Killed signal terminated program cc1"])
def test_a_full_disk_is_not_remembered_as_a_refusal(tmp_path, monkeypatch, message):
    """A compile that fails because the disk is full, or whose cc1 the out-of-memory killer ended (gcc
    then exits 1, not by a signal), leaves no note, neither the -march=native one nor a refusal: the
    next process compiles again (a note would refuse the C kernel on this machine for good)."""
    monkeypatch.setenv("SLTWIN_CACHE_DIR", str(tmp_path / "c"))
    monkeypatch.setenv("CC", _fake_cc(tmp_path, f"echo '{message}' >&2; exit 1"))
    assert _native.build("t", SRC) is None
    assert not list(_kernels(tmp_path).glob("t_*.refused")) and not list(_kernels(tmp_path).glob("tmp*"))
    assert _native.build("t", SRC) is None
    assert _calls(tmp_path) == 2                        # compiled again by the second call


def test_a_read_only_cache_folder_falls_back_without_raising(tmp_path, monkeypatch):
    """A cache folder on a read-only file system (no build folder can be made there, root included):
    no library, no exception, no compile run, nothing written."""
    import errno

    monkeypatch.setenv("SLTWIN_CACHE_DIR", str(tmp_path / "c"))
    monkeypatch.setenv("CC", _fake_cc(tmp_path, "exit 1"))
    _kernels(tmp_path).mkdir(parents=True)

    def read_only(*args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system", str(_kernels(tmp_path)))
    monkeypatch.setattr(_native.tempfile, "TemporaryDirectory", read_only)
    assert _native.build("t", SRC) is None
    assert _calls(tmp_path) == 0 and not any(_kernels(tmp_path).iterdir())


def test_a_compiler_that_refuses_march_native_is_not_asked_again(tmp_path, monkeypatch):
    """A compiler that fails with -march=native and builds without it: later processes load the
    build without it and run no compile (before, each ran the failing -march=native compile again)."""
    real = shutil.which("cc") or shutil.which("gcc")
    if real is None:
        pytest.skip("no C compiler")
    monkeypatch.setenv("SLTWIN_CACHE_DIR", str(tmp_path / "c"))
    monkeypatch.setenv("CC", _fake_cc(tmp_path, 'case "$*" in *-march=native*) echo "unknown -march" >&2; exit 1;; '
                                                f'esac\nexec {real} "$@"'))
    assert _native.build("t", SRC).f() == 7 and _calls(tmp_path) == 2
    assert _native.build("t", SRC).f() == 7 and _calls(tmp_path) == 2
    notes = list(_kernels(tmp_path).glob("t_*.refused"))
    assert len(notes) == 1 and notes[0].read_text().startswith(_native.NO_NATIVE)
    assert "unknown -march" in notes[0].read_text()


def test_the_compiler_speaks_c_locale(tmp_path, monkeypatch):
    """The compiler runs under LC_ALL=C, so that its "No space left on device" is the one build looks for."""
    monkeypatch.setenv("SLTWIN_CACHE_DIR", str(tmp_path / "c"))
    monkeypatch.setenv("LC_ALL", "de_DE.UTF-8")
    monkeypatch.setenv("CC", _fake_cc(tmp_path, f'echo "$LC_ALL" > {tmp_path / "locale"}; exit 1'))
    assert _native.build("t", SRC) is None
    assert (tmp_path / "locale").read_text().strip() == "C"



def test_a_note_does_not_outlive_the_compiler_it_is_about(tmp_path, monkeypatch):
    """A compiler fixed or upgraded in place (the same path, another program) is asked again: the key of
    the library and of its notes carries the compiler's size and time, not only its path."""
    monkeypatch.setenv("SLTWIN_CACHE_DIR", str(tmp_path / "c"))
    cc = _fake_cc(tmp_path, "echo 'error: cc1 missing' >&2; exit 1")
    monkeypatch.setenv("CC", cc)
    assert _native.build("t", SRC) is None and _calls(tmp_path) == 2
    assert _native.build("t", SRC) is None and _calls(tmp_path) == 2       # remembered
    real = shutil.which("cc") or shutil.which("gcc")
    if real is None:
        pytest.skip("no C compiler")
    Path(cc).write_text(f"#!/bin/sh\necho run >> {tmp_path / 'calls'}\nexec {real} \"$@\"\n")   # reinstalled
    os.utime(cc, ns=(time.time_ns() + 10**9, time.time_ns() + 10**9))
    assert _native.build("t", SRC).f() == 7 and _calls(tmp_path) == 3
