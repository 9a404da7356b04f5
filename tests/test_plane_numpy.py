"""The plane-fit kernel's numpy replica (unwrap/learned/_plane_numpy.py) gives numba's bits, and
`calib unwrap --model` on one capture no longer loads numba for it (docs/speed.md, session 9)."""
import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from conftest import shared_data

ROOT = Path(__file__).resolve().parent.parent


def _scene(H, W, seed):
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:H, 0:W].astype(float)
    Phi = 2 * np.pi * (0.002 * x + 0.001 * y) + 0.3 * np.sin(x / 11) + rng.normal(0, 0.05, (H, W))
    valid = rng.random((H, W)) > 0.25
    valid[H // 3:H // 2, W // 4:W // 2] = False                  # a hole wider than any box
    valid[:, -2:] = False
    Phi[~valid] = np.nan                                         # invalid pixels may hold anything
    Phi[0, 0] = -0.0
    return Phi, valid


def _bits(a):
    return np.ascontiguousarray(a).view(np.int64)


def _replicas():
    """(name, f(Phi, valid, r, block=...)) of the numba-free engines available here."""
    from unwrap.learned import _plane_c, _plane_numpy

    out = [("numpy", _plane_numpy.plane_filter_numpy)]
    c = _plane_c.kernel()
    return out + ([("C", c)] if c is not None else [])


@pytest.mark.parametrize("shape", [(5, 3), (37, 150), (130, 64), (150, 333), (129, 193)])
def test_replicas_give_the_compiled_kernels_bits(shape, monkeypatch):
    """Frames narrower and shorter than a box or a block, several blocks and partial last blocks,
    holes, NaN at invalid pixels, -0.0: every output bit equal, for both boxes, also with another
    block length (the runs' restart points move together), for the C replica as for numpy's."""
    pytest.importorskip("numba")
    from unwrap.learned import _plane_c
    from unwrap.learned import _plane_kernel as K
    from unwrap.learned import _plane_numpy as N

    assert N.BLOCK == K.BLOCK == _plane_c.BLOCK
    Phi, valid = _scene(*shape, seed=shape[0])
    ref = {r: _bits(K.plane_filter_kernel(Phi, valid, r)) for r in (3, 7)}
    for name, f in _replicas():
        for r in (3, 7):
            assert np.array_equal(_bits(f(Phi, valid, r)), ref[r]), (name, r)
    both = N.plane_filter_numpy(Phi, valid, (3, 7))                 # every box in one numpy pass: the same
    for r, got in zip((3, 7), both):
        assert np.array_equal(_bits(got), ref[r])
    monkeypatch.setattr(K, "BLOCK", 7)
    a = _bits(K.plane_filter_kernel(Phi, valid, 3))
    for name, f in _replicas():
        assert np.array_equal(_bits(f(Phi, valid, 3, block=7)), a), name


def test_the_compiled_kernel_serves_a_process_that_has_numba_loaded():
    pytest.importorskip("numba")
    from unwrap.learned import fast_features as FF
    from unwrap.learned._plane_kernel import plane_filter_kernel

    assert FF._kernel() is plane_filter_kernel          # (numba is imported by now)


@pytest.mark.parametrize("engine", ["numpy", "C"])
def test_replicas_fit_planes(engine):
    """On their own (no numba needed): a plane is reproduced to rounding, even at the frame's edge
    and beside a hole; a box with fewer than 3 valid pixels gives their mean; invalid pixels keep Phi."""
    engines = dict(_replicas())
    if engine not in engines:
        pytest.skip("no C compiler here")
    plane_filter_numpy = engines[engine]

    y, x = np.mgrid[0:70, 0:140].astype(float)
    Phi = 0.013 * x - 0.021 * y + 1.5
    valid = np.ones_like(Phi, bool)
    valid[20:40, 50:90] = False
    Phi[~valid] = 7.0
    valid[55:66, 0:10] = False
    valid[60, 3] = True                                          # alone in its 7 x 7 box
    out = plane_filter_numpy(Phi, valid, 3)
    keep = valid.copy()
    keep[60, 3] = False
    np.testing.assert_allclose(out[keep], Phi[keep], rtol=0, atol=1e-12)
    assert abs(out[60, 3] - Phi[60, 3]) < 1e-12                  # the mean of one pixel (sliding sums round)
    assert np.array_equal(out[~valid], Phi[~valid])


@pytest.mark.realdata
def test_numpy_replica_on_a_real_capture():
    """The SLStudio skull's coarse (unit-frequency) phase and mask: the same bits."""
    pytest.importorskip("numba")
    from unwrap.capture import load_capture, read_stack
    from unwrap.learned._plane_kernel import plane_filter_kernel
    from unwrap.phase_shift import wrapped_phase

    oc = load_capture(shared_data("slstudio-ps2x3-calib") / "skull_2x3").orientations["v"]
    s = min(oc.sets, key=lambda s: s.frequency)
    w = wrapped_phase(read_stack(s.files), s.shifts, min_modulation=0.02 * 255)
    valid = np.asarray(w.valid, bool)
    assert valid.sum() > 50_000
    for r in (3, 7):
        for name, f in _replicas():
            assert np.array_equal(_bits(f(w.phase, valid, r)), _bits(plane_filter_kernel(w.phase, valid, r))), name


_CHILD = """
import json, sys
from sltwin.cli import main
code = main(sys.argv[1:])
print("STATE " + json.dumps({"code": code, "numba": "numba" in sys.modules,
                             "kernel": "unwrap.learned._plane_kernel" in sys.modules}))
"""


def _calib(args, tmp_path):
    p = subprocess.run([sys.executable, "-c", _CHILD, *map(str, args)], capture_output=True, text=True, cwd=ROOT,
                       env=dict(os.environ, PYTHONPATH=str(ROOT)), timeout=600)
    line = [x for x in p.stdout.splitlines() if x.startswith("STATE ")]
    assert line, p.stderr[-2000:]
    return json.loads(line[-1][6:])


def test_one_capture_with_a_model_loads_no_numba_and_a_batch_only_without_a_c_compiler(tmp_path):
    """`calib unwrap CAPTURE --model M` (one capture): no numba in the process (its features' plane
    fits run in C or numpy, the same bits); a batch of captures warms numba's kernel up only where
    the C replica cannot be built."""
    pytest.importorskip("numba")
    from unwrap.learned.fast_features import native_plane_filter

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench.deploy_speed import write_capture
    from test_learned_use import constant_model

    model = constant_model(tmp_path / "m.pt", kind="physics")
    batch = tmp_path / "batch"
    for name in ("a", "b"):
        write_capture(batch / name, (64, 48), seed=5)
    one = _calib(["unwrap", batch / "a", "--model", model, "-o", tmp_path / "one", "--no-previews", "-q"], tmp_path)
    assert one == {"code": 0, "numba": False, "kernel": False}
    many = _calib(["unwrap", batch, "--model", model, "-o", tmp_path / "many", "--no-previews", "-q"], tmp_path)
    native = native_plane_filter()
    assert many == {"code": 0, "numba": not native, "kernel": not native}
    import h5py

    with h5py.File(tmp_path / "one" / "unwrap.h5") as f, h5py.File(tmp_path / "many" / "a" / "unwrap.h5") as g:
        for o in ("v", "h"):
            for name in ("order", "phase", "confidence", "prior"):
                assert f[o][name][()].tobytes() == g[o][name][()].tobytes(), (o, name)


def _rss_mb():
    with open("/proc/self/status") as f:
        return next(int(line.split()[1]) / 1024 for line in f if line.startswith("VmRSS"))


def test_trim_heap_gives_freed_heap_pages_back():
    """Blocks of the heap freed between live ones stay resident until trim_heap (glibc's
    malloc_trim) hands their pages back."""
    import ctypes
    import platform

    from unwrap.memory import trim_heap

    if platform.libc_ver()[0] != "glibc":
        assert trim_heap() is False
        return
    libc = ctypes.CDLL("libc.so.6")
    libc.malloc.restype, libc.malloc.argtypes = ctypes.c_void_p, [ctypes.c_size_t]
    libc.free.argtypes = [ctypes.c_void_p]
    size, n = 60 * 1024, 1600                                   # below any mmap threshold: heap blocks
    blocks = [libc.malloc(size) for _ in range(n)]
    for b in blocks:
        ctypes.memset(b, 1, size)                                 # resident
    for b in blocks[::2]:
        libc.free(b)                                              # holes between live blocks
    before = _rss_mb()
    assert trim_heap() is True
    assert before - _rss_mb() > 0.15 * n / 2 * size / 2 ** 20     # ~20 of the ~47 MB of holes measured (free alone: 0)
    for b in blocks[1::2]:
        libc.free(b)


def test_the_learned_path_trims_the_heap_right_before_the_forward(monkeypatch):
    """unwrap_learned calls trim_heap after the input is built and before the network runs (the
    forward is the command's peak), once per frame size in a process (a second frame of the size
    reuses the freed blocks: no trim, no page faults); the orders do not depend on it."""
    from unwrap.learned import infer
    from unwrap.learned.runtime import load_predictor

    calls = []
    pred = load_predictor(_model())
    logits = pred.logits
    monkeypatch.setattr(infer, "trim_heap", lambda: calls.append("trim"))
    monkeypatch.setattr(infer, "_TRIMMED", {})
    monkeypatch.setattr(pred, "logits", lambda x: calls.append("forward") or logits(x))
    rng = np.random.default_rng(0)
    u = np.linspace(10, 900, 64)[None, :].repeat(48, 0) + rng.normal(0, 0.2, (48, 64))
    phi = [np.angle(np.exp(2j * np.pi * f * u / 912)) for f in (1, 48)]
    B = np.full((48, 64), 0.4)
    r = infer.unwrap_learned("mf", phi[0], phi[1], B, B, np.ones((48, 64), bool), (1, 48), width=912, model=pred)
    assert calls == ["trim", "forward"] and (r.order >= 0).any()
    r2 = infer.unwrap_learned("mf", phi[0], phi[1], B, B, np.ones((48, 64), bool), (1, 48), width=912, model=pred)
    assert calls == ["trim", "forward", "forward"] and np.array_equal(r.order, r2.order)


def test_an_onnxruntime_forward_is_preceded_by_a_trim_every_frame(monkeypatch):
    """onnxruntime's arena does not reuse the heap's freed blocks: a trim before every forward (the
    ONNX command's peak at 900 x 700: ~320 MB, ~355 MB with a trim once per size)."""
    from unwrap.learned import infer
    from unwrap.learned.runtime import OnnxPredictor, load_predictor

    calls, torch_pred = [], load_predictor(_model())

    class OnnxLike:        # the policy is the onnxruntime predictor's; the forward is the torch one's
        trim_every_frame, arch, meta, input_layout, multiple = (OnnxPredictor.trim_every_frame, torch_pred.arch,
                                                                torch_pred.meta, "nchw", torch_pred.multiple)

        def logits(self, x):
            calls.append("forward")
            return torch_pred.logits(x)
    monkeypatch.setattr(infer, "trim_heap", lambda: calls.append("trim") or True)
    monkeypatch.setattr(infer, "_TRIMMED", {})
    rng = np.random.default_rng(0)
    u = np.linspace(10, 900, 64)[None, :].repeat(48, 0) + rng.normal(0, 0.2, (48, 64))
    phi = [np.angle(np.exp(2j * np.pi * f * u / 912)) for f in (1, 48)]
    B = np.full((48, 64), 0.4)
    for _ in range(2):
        infer.unwrap_learned("mf", phi[0], phi[1], B, B, np.ones((48, 64), bool), (1, 48), width=912, model=OnnxLike())
    assert calls == ["trim", "forward", "trim", "forward"]


def _model():
    import tempfile

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from test_learned_use import constant_model

    return constant_model(Path(tempfile.mkdtemp()) / "m.pt", kind="physics")


def _fresh_c_kernel(monkeypatch, tmp_path, cc):
    """``_plane_c.kernel()`` built afresh with ``$CC`` = ``cc`` into a cache under ``tmp_path``."""
    from unwrap.learned import _plane_c

    monkeypatch.setattr(_plane_c, "_LIB", [])
    monkeypatch.setenv("SLTWIN_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.setenv("CC", cc)
    return _plane_c.kernel()


def test_c_kernel_takes_a_compiler_with_arguments_and_refuses_one_that_changes_the_bits(monkeypatch, tmp_path):
    """``CC="gcc -std=gnu99"`` (a compiler with its own arguments, as ``ccache gcc``) builds the
    kernel; a compiler whose arithmetic differs (here: one operation of the source changed on the
    way, as a fast-math default would) is caught by the load-time check and the numpy replica runs;
    a cache that cannot be written gives None, not an error."""
    import shutil

    from unwrap.learned import _plane_numpy as N

    gcc = shutil.which("gcc") or pytest.skip("no gcc here")
    Phi, valid = _scene(37, 150, seed=1)
    f = _fresh_c_kernel(monkeypatch, tmp_path / "a", f"{gcc} -std=gnu99")
    assert f is not None
    assert np.array_equal(_bits(f(Phi, valid, 3)), _bits(N.plane_filter_numpy(Phi, valid, 3)))
    odd = tmp_path / "oddcc"
    odd.write_text("#!/bin/sh\nfor a; do last=$a; done\n"
                   "sed -i 's|double plane = num / det;|double plane = num / det * 1.0000000000001;|' \"$last\"\n"
                   f"exec {gcc} \"$@\"\n")
    odd.chmod(0o755)
    assert _fresh_c_kernel(monkeypatch, tmp_path / "b", str(odd)) is None
    built = tmp_path / "b" / "cache" / "unwrap_kernels"
    assert not list(built.glob("*.so"))                                   # built, refused, not cached
    (note,) = built.glob("*.refused")
    assert "bits differ" in note.read_text()
    assert _fresh_c_kernel(monkeypatch, tmp_path / "c", f'{gcc} "-O2') is None   # unbalanced quote: numpy
    (tmp_path / "file").write_text("")
    assert _fresh_c_kernel(monkeypatch, tmp_path / "file", gcc) is None          # cache under a regular file


def test_c_kernel_is_not_loaded_from_a_folder_others_can_write(monkeypatch, tmp_path):
    """A library loaded from the cache runs in our process: a cache folder (or file) writable by
    group or others is not used, the numpy replica runs instead."""
    import shutil

    gcc = shutil.which("gcc") or pytest.skip("no gcc here")
    assert _fresh_c_kernel(monkeypatch, tmp_path, gcc) is not None
    folder = tmp_path / "cache" / "unwrap_kernels"
    folder.chmod(0o777)
    assert _fresh_c_kernel(monkeypatch, tmp_path, gcc) is None
    folder.chmod(0o755)
    (lib,) = folder.glob("*.so")
    lib.chmod(0o666)
    assert _fresh_c_kernel(monkeypatch, tmp_path, gcc) is None
    lib.chmod(0o755)
    assert _fresh_c_kernel(monkeypatch, tmp_path, gcc) is not None



def test_c_kernel_rebuilds_a_damaged_library_remembers_a_refusal_and_sweeps_killed_builds(monkeypatch, tmp_path):
    """A cached library that no longer loads is rebuilt (not refused for good); a compiler whose build
    the check refused is not run again by the next process (its ``.refused`` note says why); a build
    folder a killed compile left is removed once it is old, a young one (another process's build) kept."""
    import os
    import shutil
    import time

    gcc = shutil.which("gcc") or pytest.skip("no gcc here")
    folder = tmp_path / "cache" / "unwrap_kernels"
    assert _fresh_c_kernel(monkeypatch, tmp_path, gcc) is not None
    (lib,) = folder.glob("*.so")
    damaged = folder / "damaged"
    damaged.write_bytes(b"not a shared object")
    os.replace(damaged, lib)        # a new file: truncating the loaded one in place would SIGBUS this process
    old, young = folder / "tmpkilled", folder / "tmpbuilding"
    old.mkdir()
    young.mkdir()
    os.utime(old, (time.time() - 3600, time.time() - 3600))
    assert _fresh_c_kernel(monkeypatch, tmp_path, gcc) is not None            # rebuilt in place
    assert lib.read_bytes()[:4] == b"\x7fELF"
    assert not old.exists() and young.exists()

    calls = tmp_path / "calls"
    odd = tmp_path / "oddcc"
    odd.write_text("#!/bin/sh\necho run >> " + str(calls) + "\nfor a; do last=$a; done\n"
                   "sed -i 's|double plane = num / det;|double plane = num / det * 1.0000000000001;|' \"$last\"\n"
                   f"exec {gcc} \"$@\"\n")
    odd.chmod(0o755)
    assert _fresh_c_kernel(monkeypatch, tmp_path / "o", str(odd)) is None
    assert _fresh_c_kernel(monkeypatch, tmp_path / "o", str(odd)) is None
    assert calls.read_text().count("run") == 1                                # the refusal is remembered
    failing = tmp_path / "failcc"
    failing.write_text("#!/bin/sh\necho 'no such header' >&2\nexit 1\n")
    failing.chmod(0o755)
    assert _fresh_c_kernel(monkeypatch, tmp_path / "f", str(failing)) is None
    notes = list((tmp_path / "f" / "cache" / "unwrap_kernels").glob("*.refused"))   # with -march=native, and without
    assert len(notes) == 2
    assert all("exited 1" in n.read_text() and "no such header" in n.read_text() for n in notes)
