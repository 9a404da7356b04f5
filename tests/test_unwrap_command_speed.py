"""`calib unwrap`'s cheaper start and end (docs/speed.md, branch unwrapcmd2): unwrap.h5 written by
threaded direct chunk writes reads back the same values as h5py's own writer, frames decoded on a
thread pool are checked in order, the numba kernels loaded on a background thread are the ones the
decode uses, and the ONNX predictor's input is padded once."""
import h5py
import numpy as np
import pytest

from unwrap import phase_io


def _maps(H, W, seed=0):
    rng = np.random.default_rng(seed)
    phase = rng.uniform(0, 300, (H, W))
    phase[rng.random((H, W)) < 0.1] = np.nan
    return {"phase": phase, "order": rng.integers(-1, 48, (H, W)).astype(np.int32),
            "valid": np.isfinite(phase),
            "extra": {"prior": rng.standard_normal((H, W)), "confidence": rng.random((H, W)).astype(np.float32),
                      "code": rng.integers(0, 65535, (H, W)).astype(np.uint16),
                      "levels": rng.standard_normal((H, W, 3)), "order_u8": rng.integers(0, 255, (H, W)).astype(np.uint8)}}


@pytest.mark.parametrize("chunk_bytes", [1 << 19, 3000])
def test_threaded_deflate_writes_the_values_h5py_writes(tmp_path, monkeypatch, chunk_bytes):
    """Every dataset reads back bitwise equal to the array given (NaNs where they were), through
    HDF5's own gzip + shuffle filters, as h5py's writer gives it; small chunks force many chunks and
    a partial edge chunk."""
    monkeypatch.setattr(phase_io, "CHUNK_BYTES", chunk_bytes)
    groups = {"v": {**_maps(173, 211, 1), "frequency": 48.0}, "h": {**_maps(173, 211, 2), "frequency": 32.0}}
    path = phase_io.write_phase_file(tmp_path / "fast.h5", groups, attrs={"capture": "x"})
    monkeypatch.setattr(phase_io, "_create_dataset", lambda g, name, data, options: g.create_dataset(
        name, data=data, **options))
    ref = phase_io.write_phase_file(tmp_path / "h5py.h5", groups)
    partial_edge = []
    with h5py.File(path) as f, h5py.File(ref) as r:
        assert f.attrs["capture"] == "x"
        for o in ("v", "h"):
            assert set(f[o]) == set(r[o]) == {"phase", "order", "valid", "prior", "confidence", "code", "levels",
                                                "order_u8"}
            assert f[o].attrs["frequency"] == groups[o]["frequency"]
            for name in f[o]:
                d, e = f[o][name], r[o][name]
                assert d.compression == "gzip" and d.shuffle and d.chunks[1:] == d.shape[1:]
                partial_edge.append(d.shape[0] % d.chunks[0] != 0)
                a, b = d[()], e[()]
                assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), (o, name)
        assert any(partial_edge) and not all(partial_edge)
        given = groups["v"]["extra"]["levels"]
        assert f["v/levels"][()].tobytes() == given.tobytes()
        assert np.array_equal(np.isnan(f["v/phase"][()]), np.isnan(groups["v"]["phase"]))


def test_datasets_the_threaded_writer_does_not_take_go_through_h5py(tmp_path):
    """Empty and 0-d arrays, strings and uncompressed files are written by h5py as before."""
    groups = {"v": {"phase": np.ones((3, 4)), "extra": {"empty": np.zeros((0, 4)), "scalar": np.float64(2.5),
                                                        "names": np.array([b"a", b"bc"])}}}
    for compression in ("gzip", None):
        path = phase_io.write_phase_file(tmp_path / f"{compression}.h5", groups, compression=compression)
        with h5py.File(path) as f:
            assert f["v/empty"].shape == (0, 4) and f["v/scalar"][()] == 2.5
            assert list(f["v/names"][()]) == [b"a", b"bc"]
            assert (f["v/phase"].compression == "gzip") == (compression == "gzip")


def test_deflate_chunk_is_a_zlib_stream_of_the_shuffled_bytes():
    import zlib

    a = np.arange(12, dtype="<f8").reshape(3, 4) * np.pi
    raw = zlib.decompress(phase_io.deflate_chunk(a))
    assert raw == a.view(np.uint8).reshape(-1, 8).T.tobytes()
    b = np.array([[True, False, True]])
    assert zlib.decompress(phase_io.deflate_chunk(b)) == b.tobytes()


def _frames(folder, n, size=(30, 40), dtype=np.uint8):
    import cv2

    folder.mkdir(parents=True, exist_ok=True)
    files = []
    rng = np.random.default_rng(n)
    for i in range(n):
        path = folder / f"f{i:02d}.png"
        cv2.imwrite(str(path), rng.integers(0, 200, size).astype(dtype))
        files.append(path)
    return files


def test_frames_decoded_on_threads_come_back_in_order_and_checked_in_order(tmp_path):
    import cv2

    from unwrap.capture import FrameReader, read_image
    from unwrap.errors import UnwrapError

    files = _frames(tmp_path / "ok", 9)
    stack = FrameReader().stack(files)
    assert stack.dtype == np.uint8 and stack.shape == (9, 30, 40)
    for i, f in enumerate(files):
        assert np.array_equal(stack[i], read_image(f))
    # frame 3 of another bit depth, frame 6 missing: the first bad frame in order is named
    bad = _frames(tmp_path / "bad", 8)
    cv2.imwrite(str(bad[3]), np.zeros((30, 40), np.uint16))
    bad[6].unlink()
    with pytest.raises(UnwrapError, match=r"f03\.png: uint16 frame among uint8 frames"):
        FrameReader().stack(bad)
    with pytest.raises(FileNotFoundError, match=r"f06\.png"):
        FrameReader().stack(bad[4:])
    with pytest.raises(UnwrapError, match="capture.toml \\[camera\\] size says 41x30"):
        FrameReader((41, 30)).stack(files)


def test_the_warm_up_loads_the_overload_the_decode_uses(tmp_path):
    """The fused MF kernel and the plane-fit kernel warmed on tiny inputs are the overloads the real
    calls then find (no second compile or load), and the decode's result does not depend on it."""
    pytest.importorskip("numba")
    from bench.deploy_speed import write_capture
    from unwrap import _fused_kernel, warmup
    from unwrap.learned import _plane_kernel
    from unwrap.learned.fast_features import plane_filter
    from unwrap.pipeline import unwrap_capture

    w = warmup.fused_mf(np.uint8, 3, 12)
    w.wait()
    assert w.error is None and warmup.fused_mf(np.uint8, 3, 12) is w          # once per process
    known = set(_fused_kernel.mf_kernel.signatures)
    cap = write_capture(tmp_path / "cap", (64, 48), seed=2)
    a = unwrap_capture(cap, "mf")
    assert set(_fused_kernel.mf_kernel.signatures) == known
    p = warmup.plane_filter()
    p.wait()
    assert p.error is None
    passes = set(_plane_kernel._pass1.signatures), set(_plane_kernel._pass2.signatures)
    y, x = np.mgrid[0:40, 0:50].astype(float)
    plane_filter(0.01 * x + 0.02 * y, x < 30)
    assert (set(_plane_kernel._pass1.signatures), set(_plane_kernel._pass2.signatures)) == passes
    b = unwrap_capture(cap, "mf")
    for o in ("v", "h"):
        assert np.array_equal(a[o].result.order, b[o].result.order)
        assert a[o].result.phase.tobytes() == b[o].result.phase.tobytes()


def test_a_failing_warm_up_is_silent_and_the_decode_reports_the_problem(tmp_path):
    from unwrap import warmup

    w = warmup.fused_mf_for(tmp_path / "missing.png", 3, 12)
    w.wait()                                                       # never raises
    assert isinstance(w.error, FileNotFoundError)


def test_onnx_predictor_pads_once_and_crops_back(tmp_path):
    """``prepare`` pads to the graph's block multiple (zeros bottom/right); the logits of the
    prepared input cropped back equal those of the raw input."""
    pytest.importorskip("onnxruntime")
    pytest.importorskip("torch")
    from unwrap.learned.runtime import export_onnx, load_predictor

    pred = load_predictor(export_onnx("learned", tmp_path / "m.onnx"))
    C = pred.session.get_inputs()[0].shape[1]
    x = np.random.default_rng(0).standard_normal((1, C, 37, 53)).astype(np.float32)
    p = pred.prepare(x)
    assert p.shape[-2] % pred.multiple == 0 and p.shape[-1] % pred.multiple == 0 and p.flags.c_contiguous
    assert np.array_equal(p[..., :37, :53], x) and not p[..., 37:, :].any() and not p[..., 53:].any()
    assert pred.prepare(p) is p or np.array_equal(pred.prepare(p), p)
    np.testing.assert_array_equal(pred.logits(p)[..., :37, :53], pred.logits(x))


def test_low_memory_gives_the_same_unwrap_h5(tmp_path):
    """``calib unwrap --low-memory`` (a fixed glibc mmap threshold, set in its own process here)
    writes the maps the default command writes."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    from bench.deploy_speed import write_capture
    from sltwin.cli import main

    root = Path(__file__).resolve().parent.parent
    cap = write_capture(tmp_path / "cap", (96, 64), seed=5)
    assert main(["unwrap", str(cap), "-o", str(tmp_path / "a"), "--no-previews", "-q"]) == 0
    code = ("import platform, sys\nfrom sltwin.cli import main\nfrom unwrap.memory import fix_mmap_threshold\n"
            "assert fix_mmap_threshold() == (platform.libc_ver()[0] == 'glibc')\n"
            f"sys.exit(main(['unwrap', {str(cap)!r}, '-o', {str(tmp_path / 'b')!r}, '--low-memory', '--no-previews', "
            "'-q']))\n")
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=root, timeout=600,
                       env={**os.environ, "PYTHONPATH": str(root)})
    assert p.returncode == 0, p.stderr[-2000:]
    with h5py.File(tmp_path / "a" / "unwrap.h5") as a, h5py.File(tmp_path / "b" / "unwrap.h5") as b:
        for o in ("v", "h"):
            assert set(a[o]) == set(b[o])
            for name in a[o]:
                assert a[o][name][()].tobytes() == b[o][name][()].tobytes(), (o, name)


@pytest.mark.skipif(not hasattr(__import__("os"), "fork"), reason="no fork on this platform")
def test_a_child_forked_after_the_pools_ran_decodes_and_writes(tmp_path):
    """A process forked after frames were decoded and a file deflated on the pools (a DataLoader or
    multiprocessing worker) decodes and writes too: the inherited pools have no threads in the
    child, so it makes its own instead of waiting forever. Run in a fresh interpreter that forks
    (the child is stopped by an alarm after 30 s, which fails the test)."""
    import os
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    files = _frames(tmp_path / "f", 6)
    code = f"""
import os, signal, numpy as np
from unwrap.capture import FrameReader
from unwrap.phase_io import read_phase, write_phase_file
files = {[str(f) for f in files]!r}
maps = {{"v": {{"phase": np.arange(1.0, 12001.0).reshape(120, 100)}}}}
FrameReader().stack(files); write_phase_file({str(tmp_path / 'parent.h5')!r}, maps)
pid = os.fork()
if pid == 0:
    signal.alarm(30)
    s = FrameReader().stack(files)
    p = write_phase_file({str(tmp_path / 'child.h5')!r}, maps)
    os._exit(0 if s.shape == (6, 30, 40) and np.array_equal(read_phase(p), maps["v"]["phase"]) else 3)
_, status = os.waitpid(pid, 0)
raise SystemExit(f"child: {{status}}" if status else 0)
"""
    p = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, cwd=root, timeout=120,
                       env={**os.environ, "PYTHONPATH": str(root)})
    assert p.returncode == 0, (p.stdout + p.stderr)[-2000:]


def test_low_memory_says_when_it_cannot_act(tmp_path, monkeypatch, capsys):
    """Where the C library is not glibc (``fix_mmap_threshold`` False) ``--low-memory`` says it has
    no effect instead of passing in silence; the command still runs."""
    from bench.deploy_speed import write_capture
    from sltwin.cli import main
    from unwrap import memory

    monkeypatch.setattr(memory, "fix_mmap_threshold", lambda nbytes=memory.DEFAULT_THRESHOLD: False)
    cap = write_capture(tmp_path / "cap", (64, 48), seed=3)
    assert main(["unwrap", str(cap), "-o", str(tmp_path / "out"), "--low-memory", "--no-previews"]) == 0
    assert "--low-memory has no effect here" in capsys.readouterr().err
    assert (tmp_path / "out" / "unwrap.h5").is_file()


def test_a_gzip_level_other_than_1_is_written_by_h5py_at_that_level(tmp_path, monkeypatch):
    """``write_phase_group(..., compression="gzip", compression_opts=9, shuffle=True)`` gets level 9
    (h5py's writer), not the threaded writer's level 1 under a header that says 9; level 1 (what
    ``write_phase_file`` asks for) takes the threaded writer."""
    calls = []
    deflate = phase_io.deflate_chunk
    monkeypatch.setattr(phase_io, "deflate_chunk", lambda b: calls.append(b.shape) or deflate(b))
    phase = np.random.default_rng(0).uniform(0, 300, (64, 80))
    for level in (9, 1):
        calls.clear()
        with h5py.File(tmp_path / f"l{level}.h5", "w") as f:
            phase_io.write_phase_group(f, "v", phase, compression="gzip", compression_opts=level, shuffle=True)
        with h5py.File(tmp_path / f"l{level}.h5") as f:
            assert f["v/phase"].compression_opts == level and np.array_equal(f["v/phase"][()], phase)
        assert bool(calls) == (level == 1), level


def test_the_learned_capture_path_starts_no_warm_up(tmp_path, monkeypatch):
    """unwrap_capture_learned no longer loads numba's plane-fit kernel for one capture (its numpy
    replica gives the same bits: tests/test_plane_numpy.py); only a batch of captures asks for it
    (`calib unwrap` with several captures)."""
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from bench.deploy_speed import write_capture
    from test_learned_use import constant_model
    from unwrap import warmup
    from unwrap.learned.capture import unwrap_capture_learned

    started = []
    monkeypatch.setattr(warmup, "plane_filter", lambda: started.append(1))
    cap = write_capture(tmp_path / "cap", (64, 48), seed=4)
    for kind in ("prior_free", "physics"):
        out = unwrap_capture_learned(cap, "mf", constant_model(tmp_path / f"{kind}.pt", kind=kind))
        assert set(out) == {"v", "h"} and started == [], kind
