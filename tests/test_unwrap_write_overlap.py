"""``unwrap.h5``'s deflate with stored noisy byte planes, and the work ``calib unwrap`` now runs on threads
(the noise estimate beside the decode, the previews beside the write) giving the same results."""
import zlib

import h5py
import numpy as np
import pytest

from unwrap import phase_io


def _shuffled(a):
    return np.ascontiguousarray(a.reshape(-1).view(np.uint8).reshape(-1, a.dtype.itemsize).T).tobytes()


def _map(rows=120, cols=900, seed=0):
    """A phase-like float64 map: smooth values (compressible high bytes, noisy low bytes), NaN holes."""
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:rows, 0:cols]
    a = 0.01 * x + 0.003 * y + rng.normal(0, 1e-3, (rows, cols))
    a[:10, :50] = np.nan
    return a


@pytest.mark.parametrize("a", [_map(), _map(73, 1000), _map()[:, :7], np.zeros((5, 4)),
                               np.arange(300_000, dtype=np.int64).reshape(300, 1000),
                               np.random.default_rng(1).random((90, 900)).astype(np.float32),
                               np.arange(12, dtype=np.int32), np.array([np.nan, 1.0])])
def test_deflate_chunk_is_one_zlib_stream_of_the_shuffled_bytes(a):
    assert zlib.decompress(phase_io.deflate_chunk(a)) == _shuffled(a)
    d = zlib.decompressobj()
    assert d.decompress(phase_io.deflate_chunk(a)) == _shuffled(a) and d.eof and not d.unused_data


def test_noisy_planes_are_stored_and_smooth_ones_deflated():
    a = _map(120, 900)
    planes = np.frombuffer(_shuffled(a), np.uint8).reshape(8, -1)
    noisy = phase_io._noisy(planes)
    assert noisy[:4].all() and not noisy[-1]          # mantissa noise stored; the sign/exponent byte deflated
    n_stored = int(noisy.sum())
    out = phase_io.deflate_chunk(a)
    assert len(out) >= n_stored * planes.shape[1]     # stored planes kept whole (5 bytes a 64 KiB block)
    whole = zlib.compressobj(1, zlib.DEFLATED, 15, 8, zlib.Z_RLE)
    rle = len(whole.compress(_shuffled(a)) + whole.flush())
    assert len(out) <= 1.03 * rle                     # no worse than deflating everything, within 3 %


def test_the_file_reads_back_bitwise_with_h5py(tmp_path):
    maps = {"phase": _map(700, 900), "order": np.arange(630_000, dtype=np.int32).reshape(700, 900) % 49,
            "valid": np.ones((700, 900), bool)}
    extra = {"prior": _map(700, 900, seed=3), "modulation": np.abs(_map(700, 900, seed=4))}
    path = phase_io.write_phase_file(tmp_path / "u.h5", {"v": dict(**maps, extra=extra, frequency=48.0)})
    with h5py.File(path) as f:
        for k, v in {**maps, **extra}.items():
            assert f["v"][k][()].tobytes() == v.tobytes()
            assert f["v"][k].compression == "gzip" and f["v"][k].shuffle


@pytest.fixture(scope="module")
def capture(tmp_path_factory):
    from bench.deploy_speed import write_capture

    return write_capture(tmp_path_factory.mktemp("cap") / "cap", (96, 64), steps=6)


def test_noise_estimated_beside_the_decode_is_the_one_estimated_before(capture):
    from unwrap.capture import FrameReader, load_capture
    from unwrap.pipeline import _noise_sigma, read_orientation, unwrap_orientation

    cap = load_capture(capture)
    for oc in cap.orientations.values():
        r = unwrap_orientation(oc, "mf", camera_size=cap.camera_size)
        sets = sorted(oc.sets, key=lambda s: s.frequency)
        alone = _noise_sigma(read_orientation(oc, FrameReader(cap.camera_size)), sets, None)
        assert r.noise_sigma is not None and r.noise_sigma == alone and r.predicted_error_rate is not None
        given = unwrap_orientation(oc, "mf", camera_size=cap.camera_size, noise_sigma=1.5)
        assert given.noise_sigma == 1.5


def test_previews_drawn_beside_the_write_are_the_previews(capture, tmp_path):
    from unwrap.pipeline import unwrap_capture, write_results
    from unwrap.previews import write_previews

    res = unwrap_capture(capture)
    write_results(res, tmp_path / "a")
    write_previews(res, tmp_path / "b")
    for o in res:
        assert (tmp_path / "a" / f"{o}_unwrap.png").read_bytes() == (tmp_path / "b" / f"{o}_unwrap.png").read_bytes()
    assert (tmp_path / "a" / "unwrap.h5").is_file()
    write_results(res, tmp_path / "c", previews=False)
    assert not list((tmp_path / "c").glob("*.png"))
    write_results(res, tmp_path / "d", previews_beside=False)        # drawn after the file (--model)
    for o in res:
        assert (tmp_path / "d" / f"{o}_unwrap.png").read_bytes() == (tmp_path / "b" / f"{o}_unwrap.png").read_bytes()


def test_a_failing_preview_is_reported_after_the_file_is_written(capture, tmp_path, monkeypatch):
    from unwrap import previews
    from unwrap.pipeline import unwrap_capture, write_results

    res = unwrap_capture(capture)

    def broken(results):
        raise OSError("cannot encode the preview of orientation v")
    monkeypatch.setattr(previews, "encode_previews", broken)
    for beside in (True, False):
        with pytest.raises(OSError, match="preview of orientation v"):
            write_results(res, tmp_path / f"o{beside}", previews_beside=beside)
        assert (tmp_path / f"o{beside}" / "unwrap.h5").is_file() and not list((tmp_path / f"o{beside}").glob("*.png"))


def test_the_next_orientations_frames_decoded_ahead_give_the_same_maps(capture):
    from unwrap import capture as capture_mod
    from unwrap.capture import load_capture
    from unwrap.pipeline import unwrap_capture, unwrap_orientation

    res = unwrap_capture(capture)
    assert not capture_mod._AHEAD                     # every prefetched frame was taken or dropped
    cap = load_capture(capture)
    for o, oc in cap.orientations.items():
        alone = unwrap_orientation(oc, "mf", camera_size=cap.camera_size)
        for a, b in ((alone.result.phase, res[o].result.phase), (alone.result.order, res[o].result.order),
                     (alone.modulation, res[o].modulation)):
            assert a.tobytes() == b.tobytes()


def test_frames_decoded_ahead_are_taken_not_decoded_again(capture, monkeypatch):
    """The prefetch is used (each frame decoded once), not silently missed (a frame decoded twice)."""
    from collections import Counter

    from unwrap import capture as capture_mod
    from unwrap.pipeline import unwrap_capture

    calls, real = Counter(), capture_mod.read_image
    monkeypatch.setattr(capture_mod, "read_image", lambda f: (calls.update([str(f)]), real(f))[1])
    res = unwrap_capture(capture)
    assert len(res) == 2 and calls and max(calls.values()) == 1
    assert len(calls) == len(list((capture / "pose_00").glob("*.png")))


def test_a_bad_frame_decoded_ahead_is_reported_in_its_turn(capture, tmp_path):
    import shutil

    from unwrap import capture as capture_mod
    from unwrap.errors import UnwrapError
    from unwrap.pipeline import unwrap_capture

    bad = tmp_path / "cap"
    shutil.copytree(capture, bad)
    (bad / "pose_00" / "h_f048_n01.png").write_bytes(b"not a png")
    (bad / "pose_00" / "h_f008_n02.png").write_bytes(b"not a png")     # the first bad one in reading order
    with pytest.raises(UnwrapError, match="h_f008_n02"):
        unwrap_capture(bad)
    assert not capture_mod._AHEAD
    (bad / "pose_00" / "v_f001_n00.png").write_bytes(b"not a png")      # v fails: h's frames were never read
    with pytest.raises(UnwrapError, match="v_f001_n00"):
        unwrap_capture(bad)
    assert not capture_mod._AHEAD


def test_frames_prefetched_before_a_fork_are_forgotten_in_the_child(capture):
    import os

    from unwrap import capture as capture_mod

    files = sorted((capture / "pose_00").glob("h_*.png"))
    capture_mod.prefetch(files)
    pid = os.fork()
    if pid == 0:                                   # the child: nothing pending from the parent's pool
        os._exit(0 if not capture_mod._AHEAD else 1)
    assert os.waitpid(pid, 0)[1] == 0
    capture_mod.forget_prefetched(files)
    assert not capture_mod._AHEAD
