"""The fused MF kernel's C replica (unwrap._fused_c) and numpy replica (unwrap._fused_numpy) give numba's
kernel's outputs bit for bit; the traditional command then never imports numba."""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from tests.conftest import shared_data
from tests.test_unwrap_fused import W_P, _stacks
from unwrap import _fused_c, _fused_numpy, fused_mf
from unwrap.fused_mf import mf_unwrap_stacks

ROOT = Path(__file__).resolve().parent.parent
needs_c = pytest.mark.skipif(fused_mf.native_kernel() is None, reason="no C compiler (the numba kernel runs)")


def _numba():
    return pytest.importorskip("unwrap._fused_kernel")


def _fields(r):
    u = r.result
    return [u.phase, u.order, u.valid, u.prior, r.modulation, r.background,
            *[a for lev in u.levels for a in lev[1:]]]


def _both(monkeypatch, stacks, freqs, **kw):
    """(C result, numba result) of mf_unwrap_stacks on the same input."""
    _numba()
    c = mf_unwrap_stacks(stacks, freqs, fast=True, **kw)
    with monkeypatch.context() as m:
        m.setattr(fused_mf, "native_kernel", lambda: None)
        n = mf_unwrap_stacks(stacks, freqs, fast=True, **kw)
    return c, n


def _assert_bitwise(a, b):
    for x, y in zip(_fields(a), _fields(b), strict=True):
        assert x.dtype == y.dtype and x.shape == y.shape
        assert x.tobytes() == y.tobytes()


CASES = [  # freqs, steps, dtype, options
    ((1, 8, 48), (12, 12, 12), np.uint8, dict(levels=True)),
    ((1, 8, 48), (12, 12, 12), np.uint8, dict(levels=False, min_modulation=5.1)),
    ((1, 6, 36), (4, 7, 5), np.uint16, dict(levels=True, min_modulation=300.0)),
    ((1, 8, 48), (3, 3, 3), np.uint8, dict(valid_range=(1, 254), min_modulation=5.1)),
    ((1, 8, 48), (12, 9, 12), np.uint8, dict(saturation=None, levels=True)),
    ((1, 16), (12, 12), np.uint8, dict(min_modulation=5.1)),
    ((0.5, 4, 16, 64), (5, 6, 8, 12), np.uint16, dict(levels=True, saturation=60000)),
]


@needs_c
@pytest.mark.parametrize("freqs, steps, dtype, kw", CASES)
def test_c_kernel_is_numbas_bit_for_bit(monkeypatch, freqs, steps, dtype, kw):
    scale = 250.0 if dtype == np.uint16 else 1.0
    stacks = _stacks(freqs, steps, dtype=dtype, scale=scale, seed=len(steps) + steps[0])
    c, n = _both(monkeypatch, stacks, freqs, width=W_P, **kw)
    assert c.fast and n.fast and c.result.valid.any() and not c.result.valid.all()
    _assert_bitwise(c, n)


@needs_c
def test_unequal_shifts_and_a_frame_split_across_threads(monkeypatch):
    """Unequal shifts (no all-ones group: the separate max pass) and a frame larger than
    SPLIT_MIN, cut into block-aligned ranges on threads, with a partial last block."""
    shifts = np.array([0.0, 1.3, 2.9, 4.1, 5.3])
    base = _stacks((1, 8, 48), (5, 5, 5), shifts=shifts, seed=3)
    reps = -(-_fused_c.SPLIT_MIN // base[0][0].size) + 1
    stacks = [np.ascontiguousarray(np.tile(s, (1, reps, 1))[:, :, :-3]) for s in base]
    assert stacks[0][0].size > _fused_c.SPLIT_MIN and stacks[0][0].size % _fused_c.K.BLOCK
    c, n = _both(monkeypatch, stacks, (1, 8, 48), width=W_P, shifts=[shifts] * 3, min_modulation=5.1, levels=True)
    _assert_bitwise(c, n)


@needs_c
def test_out_arrays_are_reused_by_the_c_kernel():
    stacks = _stacks((1, 8, 48), (12, 12, 12))
    first = mf_unwrap_stacks(stacks, (1, 8, 48), width=W_P, fast=True)
    again = mf_unwrap_stacks(_stacks((1, 8, 48), (12, 12, 12), seed=5), (1, 8, 48), width=W_P, fast=True, out=first)
    assert again.result.phase is first.result.phase or np.shares_memory(again.result.phase, first.result.phase)
    fresh = mf_unwrap_stacks(_stacks((1, 8, 48), (12, 12, 12), seed=5), (1, 8, 48), width=W_P, fast=True)
    _assert_bitwise(again, fresh)


@pytest.mark.parametrize("case", [
    (0, np.uint8, (12, 12, 12), True, 255.0, -np.inf, np.inf),
    (1, np.uint16, (4, 7, 5), True, np.inf, 30.0, 60000.0),
    (2, np.uint8, (3, 9, 12), False, np.inf, -np.inf, np.inf),
    (3, np.uint8, (6, 6, 6), True, 250.0, 2.0, np.inf),
    (2, np.uint8, (3, 9, 12), False, np.inf, -np.inf, np.inf, _fused_c.K.BLOCK + 300, 12.0),
    (4, np.uint16, (5, 5, 5), True, 65535.0, -np.inf, np.inf, 2 * _fused_c.K.BLOCK + 7, 12.0)])
def test_numpy_replica_is_numbas_bit_for_bit(case):
    K = _numba()
    stacks, args, a = _fused_c._check_case(fused_mf._kernel_weights, *case)
    _, _, b = _fused_c._check_case(fused_mf._kernel_weights, *case)
    _fused_numpy.mf_kernel(stacks, *args, *a)
    K.mf_kernel(tuple(stacks), np.empty(0, np.int32), *args, *b)
    assert all(x.tobytes() == y.tobytes() for x, y in zip(a, b, strict=True))
    assert a[2].any() and not a[2].all()


def test_per_process_check_covers_blocks_and_the_wrap():
    """The library's per-process check runs a frame of more than one block and moves results both ways
    by the pattern's wrap (a miscompiled block loop or wrap select would otherwise pass it)."""
    sizes, moved = [], set()
    for case in _fused_c.CHECK_CASES:
        stacks, args, out = _fused_c._check_case(fused_mf._kernel_weights, *case)
        _fused_numpy.mf_kernel(stacks, *args, *out)
        sizes.append(stacks[0].shape[1])
        if len(case) > 8 and case[8] > 0:           # the same input without the wrap: the orders it moved
            _, args0, out0 = _fused_c._check_case(fused_mf._kernel_weights, *case[:8], 0.0)
            _fused_numpy.mf_kernel(stacks, *args0, *out0)
            both = out[2] & out0[2]
            moved |= set(np.unique(out[1][both] - out0[1][both]).tolist())
    assert max(sizes) > _fused_c.K.BLOCK and moved == {-12, 0, 12}


def test_numpy_arctangent_is_the_kernels():
    K = _numba()
    rng = np.random.default_rng(0)
    y = np.concatenate([rng.normal(0, 1, 20000), [0.0, -0.0, 0.0, -0.0, 1.0, -1.0, 1.0, 0.0]])
    x = np.concatenate([rng.normal(0, 1, 20000), [0.0, 0.0, -0.0, -0.0, 1.0, 1.0, -1.0, -2.0]])
    out = np.empty_like(y)
    K.atan2_array(y, x, out)
    assert _fused_numpy.atan2(y, x).tobytes() == out.tobytes()


@needs_c
def test_a_library_with_other_bits_is_not_used(monkeypatch):
    """The per-process check: a library whose outputs differ from the numpy replica's is refused."""
    funcs = fused_mf.native_kernel()
    assert _fused_c._same_bits(funcs, fused_mf._kernel_weights)
    real = _fused_c._call

    def off_by_one_ulp(f, stacks, *rest):
        real(f, stacks, *rest)
        phase = rest[16]
        phase[np.isfinite(phase)] = np.nextafter(phase[np.isfinite(phase)], np.inf)
    monkeypatch.setattr(_fused_c, "_call", off_by_one_ulp)
    assert not _fused_c._same_bits(funcs, fused_mf._kernel_weights)


def test_no_compiler_or_a_shared_cache_falls_back(tmp_path, monkeypatch):
    from unwrap import _native

    monkeypatch.setenv("SLTWIN_CACHE_DIR", str(tmp_path / "c"))
    monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))
    assert _native.build("t", "int f(void) { return 1; }") is None
    monkeypatch.delenv("CC")
    if _native.build("t", "int f(void) { return 1; }") is None:
        pytest.skip("no C compiler")
    lib = next((tmp_path / "c" / "unwrap_kernels").glob("t_*.so"))
    os.chmod(lib.parent, 0o777)                       # writable by others: not loaded from
    assert _native.build("t", "int f(void) { return 1; }") is None
    os.chmod(lib.parent, 0o755)
    assert _native.build("t", "int f(void) { return 1; }").f() == 1


def _fake_cc(tmp_path, body: str, name: str) -> str:
    cc = tmp_path / name
    cc.write_text(f"#!/bin/sh\necho run >> {tmp_path / 'calls'}\n{body}\n")
    cc.chmod(0o755)
    return str(cc)


def test_a_failing_compiler_is_run_once_and_a_killed_compile_not_remembered(tmp_path, monkeypatch):
    """A compiler that fails with and without -march=native is remembered for both (later processes
    run no compile); a compile killed by a signal leaves no refusal (the next process compiles)."""
    from unwrap import _native

    calls = tmp_path / "calls"
    monkeypatch.setenv("SLTWIN_CACHE_DIR", str(tmp_path / "c"))
    monkeypatch.setenv("CC", _fake_cc(tmp_path, "echo 'no math.h' >&2; exit 1", "failing-cc"))
    assert _native.build("t", "int f(void) { return 1; }") is None
    assert calls.read_text().count("run") == 2                  # with -march=native, then without
    assert _native.build("t", "int f(void) { return 1; }") is None
    assert calls.read_text().count("run") == 2                  # remembered: no compile at all
    assert len(list((tmp_path / "c" / "unwrap_kernels").glob("t_*.refused"))) == 2
    calls.unlink()
    monkeypatch.setenv("CC", _fake_cc(tmp_path, "kill -9 $$", "killed-cc"))
    assert _native.build("t", "int f(void) { return 1; }") is None
    assert _native.build("t", "int f(void) { return 1; }") is None
    assert calls.read_text().count("run") == 2                  # once per call, no retry, nothing remembered
    assert len(list((tmp_path / "c" / "unwrap_kernels").glob("t_*.refused"))) == 2


def test_no_home_folder_means_no_cache_in_the_working_folder(monkeypatch, tmp_path):
    from unwrap import _native

    monkeypatch.delenv("SLTWIN_CACHE_DIR", raising=False)
    monkeypatch.delenv("XDG_CACHE_HOME", raising=False)
    monkeypatch.setattr(_native.os.path, "expanduser", lambda p: p)      # "~" left as it is (no home)
    monkeypatch.chdir(tmp_path)
    assert _native.build("t", "int f(void) { return 3; }") is None
    assert not any(tmp_path.iterdir())


def test_the_library_is_cached_per_cpu(monkeypatch, tmp_path):
    from unwrap import _native

    monkeypatch.setenv("SLTWIN_CACHE_DIR", str(tmp_path))
    if _native.build("t", "int f(void) { return 2; }") is None:
        pytest.skip("no C compiler")
    monkeypatch.setattr(_native, "cpu_id", lambda: "another CPU")
    assert _native.build("t", "int f(void) { return 2; }").f() == 2
    assert len(list((tmp_path / "unwrap_kernels").glob("t_*.so"))) == 2


@needs_c
def test_traditional_command_imports_no_numba(tmp_path):
    from bench.deploy_speed import write_capture

    cap = write_capture(tmp_path / "cap", (64, 48), steps=4)
    code = ("import sys\nfrom sltwin.cli import main\nrc = main(sys.argv[1:])\n"
            "print('NUMBA', 'numba' in sys.modules)\nsys.exit(rc)\n")
    p = subprocess.run([sys.executable, "-c", code, "unwrap", str(cap), "-o", str(tmp_path / "out"), "-q"],
                       capture_output=True, text=True, env=dict(os.environ, PYTHONPATH=str(ROOT)), cwd=ROOT,
                       timeout=300)
    assert p.returncode == 0, p.stderr
    assert "NUMBA False" in p.stdout
    assert (tmp_path / "out" / "unwrap.h5").is_file()


@needs_c
@pytest.mark.realdata
def test_real_slstudio_capture_c_equals_numba(monkeypatch):
    from unwrap.capture import load_capture, read_stack

    for o, oc in load_capture(shared_data("slstudio-ps2x3-calib") / "skull_2x3").orientations.items():
        sets = sorted(oc.sets, key=lambda s: s.frequency)
        stacks = [read_stack(s.files) for s in sets]
        c, n = _both(monkeypatch, stacks, [s.frequency for s in sets], shifts=[s.shifts for s in sets],
                     width=oc.width, min_modulation=0.02 * 255, levels=True)
        assert c.result.valid.sum() > 80_000
        _assert_bitwise(c, n)


@needs_c
def test_frames_without_pixels(monkeypatch):
    stacks = [np.zeros((12, 0, 5), np.uint8)] * 3
    c, n = _both(monkeypatch, stacks, (1, 8, 48), width=W_P, levels=True)
    assert c.result.phase.shape == (0, 5)
    _assert_bitwise(c, n)


@needs_c
def test_an_allocation_failure_in_the_kernel_is_a_toolkit_error(monkeypatch, tmp_path, capsys):
    """The C kernel's block buffers not allocated (the process out of memory): an UnwrapError naming
    it, which ``calib unwrap`` reports with exit 2 (before: a MemoryError, exit 1 "internal error")."""
    from bench.deploy_speed import write_capture
    from sltwin.cli import main
    from unwrap.errors import UnwrapError

    funcs = _fused_c.kernel(fused_mf._kernel_weights)
    assert funcs is not None
    monkeypatch.setattr(_fused_c, "_LIB", [{dtype: (lambda *args: -1) for dtype in funcs}])
    stacks = _stacks((1, 8, 48), (4, 4, 4), seed=11)
    with pytest.raises(UnwrapError, match="out of memory"):
        mf_unwrap_stacks(stacks, (1, 8, 48), width=W_P)
    cap = write_capture(tmp_path / "cap", (64, 48), seed=4)
    assert main(["unwrap", str(cap), "-o", str(tmp_path / "out"), "--no-previews", "-q"]) == 2
    err = capsys.readouterr().err
    assert "out of memory" in err and "internal error" not in err
