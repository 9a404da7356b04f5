"""Absolute phase maps on disk: the one reader, and the one writer of DESIGN.md's HDF5 phase layout.

Layout (DESIGN.md): one group per orientation, ``v`` (fringes along projector columns -> u_p) or
``h`` (rows -> v_p), holding

- ``phase``: (H, W) float64 absolute phase of the group's frequency, rad, NaN where invalid;
- ``order``: (H, W) int32 fringe order, -1 where invalid (when known);
- ``valid``: (H, W) bool;
- any further per-pixel datasets a writer adds (``prior``, ``modulation``, ``phase_f008`` ...);
- attribute ``frequency`` (periods across the projector pattern) when known.

``phase_orientations`` lists the orientations (and frequencies) an HDF5 file holds, ``phase_groups``
their attributes.
``read_phase`` also reads the phase maps others publish: a MATLAB ``.mat`` (the dp-tpu ball
phase: one 2-D array, e.g. ``phase3``) and ``.npy``. Pixels stored as 0, NaN or inf are invalid
and come back as NaN.

SYNOPSIS

    >>> import numpy as np, tempfile, os
    >>> from unwrap.phase_io import read_phase, write_phase_file
    >>> phase = np.array([[0.0, 1.5], [2.5, np.nan]])
    >>> path = write_phase_file(os.path.join(tempfile.mkdtemp(), "p.h5"), {"v": {"phase": phase}}, frequency=8.0)
    >>> read_phase(path).tolist()
    [[nan, 1.5], [2.5, nan]]
"""
from __future__ import annotations

import zlib
from pathlib import Path

import numpy as np

from .errors import UnwrapError

ORIENTATIONS = ("v", "h")


def read_phase(path, key: str | None = None, orientation: str = "v") -> np.ndarray:
    """Absolute phase map (H, W) float64, NaN where invalid (stored as 0, NaN or inf).

    ARGUMENTS
    - path: ``.h5``/``.hdf5`` (DESIGN.md layout: dataset ``{orientation}/phase``, or ``key``),
      ``.mat`` (the only 2-D array, or the variable ``key``) or ``.npy``.
    - key: dataset (HDF5) or variable (.mat) name; orientation: ``v`` or ``h`` (HDF5 only).
    Raises UnwrapError naming the file and what it holds when the map cannot be read.
    """
    path = Path(path)
    if not path.exists():
        raise UnwrapError(f"{path}: no such phase file")
    suffix = path.suffix.lower()
    if suffix == ".mat":
        phase = _read_mat(path, key)
    elif suffix == ".npy":
        try:
            phase = np.load(path, allow_pickle=False)
        except (ValueError, OSError, EOFError) as exc:
            raise UnwrapError(f"{path}: not a readable .npy array ({exc})") from None
    elif suffix in (".h5", ".hdf5"):
        phase = _read_h5(path, key or f"{orientation}/phase")
    else:
        raise UnwrapError(f"{path}: unknown phase format (expected .h5, .mat or .npy)")
    try:
        phase = np.array(phase, dtype=np.float64)
    except (TypeError, ValueError):
        raise UnwrapError(f"{path}: the phase map holds {np.asarray(phase).dtype} values, not numbers") from None
    if phase.ndim != 2:
        raise UnwrapError(f"{path}: a phase map is 2-D, got shape {phase.shape}")
    phase[~np.isfinite(phase) | (phase == 0)] = np.nan
    return phase


def phase_groups(path) -> dict:
    """``{orientation: attributes}`` of the groups an HDF5 phase file holds (DESIGN.md layout:
    ``v`` and/or ``h`` with a ``phase`` dataset; attributes as stored, e.g. ``frequency``,
    ``width``, ``method`` by ``calib unwrap``); ``{}`` for ``.mat``/``.npy`` files, which hold one
    map and no attributes. Raises UnwrapError for a missing or unreadable HDF5 file."""
    path = Path(path)
    if path.suffix.lower() not in (".h5", ".hdf5"):
        return {}
    import h5py

    if not path.exists():
        raise UnwrapError(f"{path}: no such phase file")
    try:
        with h5py.File(path, "r") as f:
            return {o: {k: (v.item() if hasattr(v, "item") else v) for k, v in f[o].attrs.items()}
                    for o in ORIENTATIONS if o in f and "phase" in f[o]}
    except OSError as exc:
        raise UnwrapError(f"{path}: not a readable HDF5 file ({exc})") from None


def phase_orientations(path) -> dict:
    """``{orientation: frequency (float) or None}`` of the groups an HDF5 phase file holds
    (:func:`phase_groups`); ``{}`` for ``.mat``/``.npy`` files, which hold one map of an
    orientation they do not record."""
    return {o: (float(a["frequency"]) if "frequency" in a else None) for o, a in phase_groups(path).items()}


def _read_mat(path: Path, key):
    import scipy.io

    try:
        m = {k: v for k, v in scipy.io.loadmat(str(path)).items() if not k.startswith("__")}
    except Exception as exc:   # scipy raises MatReadError, ValueError, OSError, ... for a broken file
        raise UnwrapError(f"{path}: not a readable MATLAB file ({exc})") from None
    arrays = [k for k, v in m.items() if isinstance(v, np.ndarray) and v.ndim == 2]
    if key is None:
        if len(arrays) != 1:
            raise UnwrapError(f"{path}: expected one 2-D phase array, found {arrays}; name the variable")
        key = arrays[0]
    if key not in m:
        raise UnwrapError(f"{path}: no variable {key!r} (2-D arrays: {arrays})")
    return m[key]


def _read_h5(path: Path, key: str):
    import h5py

    try:
        with h5py.File(path, "r") as f:
            if key not in f:
                raise UnwrapError(f"{path}: no dataset {key!r} (a phase file of DESIGN.md holds v/phase, h/phase)")
            return np.asarray(f[key])
    except OSError as exc:
        raise UnwrapError(f"{path}: not a readable HDF5 file ({exc})") from None


def write_phase_group(h5, orientation: str, phase, *, order=None, valid=None, frequency: float | None = None,
                      extra: dict | None = None, attrs: dict | None = None, **dataset_options):
    """Write one orientation group of the layout into an open ``h5py`` file or group ``h5``.

    ``phase`` (H, W) rad (NaN invalid) is stored as float64, ``order`` as int32, ``valid`` as
    bool (default: where the phase is finite); ``extra`` {name: (H, W, ...) array} adds datasets
    as given; ``frequency`` and ``attrs`` become attributes. ``dataset_options`` (compression,
    chunks, ...) go to every ``create_dataset``. Returns the group.
    """
    if orientation not in ORIENTATIONS:
        raise UnwrapError(f"orientation: expected one of {ORIENTATIONS}, got {orientation!r}")
    phase = np.asarray(phase, dtype=np.float64)
    g = h5.require_group(orientation)
    datasets = {"phase": phase}
    if order is not None:
        datasets["order"] = np.asarray(order, dtype=np.int32)
    datasets["valid"] = np.isfinite(phase) if valid is None else np.asarray(valid, dtype=bool)
    datasets.update(extra or {})
    for name, data in datasets.items():
        _create_dataset(g, name, np.ascontiguousarray(data), dataset_options)
    if frequency is not None:
        g.attrs["frequency"] = frequency
    g.attrs.update(attrs or {})
    return g


def _codec(compression) -> dict:
    """gzip at level 1 behind the byte shuffle (lossless; any HDF5 reader decodes it): float64 phase
    maps are noise in their low bytes, so gzip's default level 4 spends twice the time for a larger
    file (docs/speed.md). Such datasets are compressed by :func:`_create_dataset`, chunk by chunk on
    threads."""
    return {"compression_opts": 1, "shuffle": True} if compression == "gzip" else {}


#: about this many bytes per chunk of a dataset written by the threaded deflate (whole rows)
CHUNK_BYTES = 1 << 19


def _pool():
    """The writer's thread pool (zlib releases the GIL while it compresses; :mod:`unwrap._threads`)."""
    from ._threads import pool

    return pool("h5-deflate")


#: a shuffled byte plane whose order-0 entropy is above this share of 8 bits a byte is stored as it is
#: (deflate's "stored" blocks): the noisy low bytes of float64 maps, which deflate cannot shrink
STORE_ENTROPY = 0.97


def _noisy(planes: np.ndarray) -> np.ndarray:
    """Which of the byte planes ``planes`` (P, n) uint8 are (nearly) incompressible: the entropy of
    the plane's byte histogram (from an even sample of ~4096 of its bytes) is above
    :data:`STORE_ENTROPY` of 8 bits. Deflate's Huffman codes cannot beat that entropy, and its
    run-length matches find nothing in such planes (1.000 of the size on the 900 x 700 maps)."""
    sample = planes[:, ::max(1, planes.shape[1] // 4096)].astype(np.intp)
    sample += 256 * np.arange(planes.shape[0])[:, None]
    p = np.bincount(sample.reshape(-1), minlength=256 * planes.shape[0]).reshape(-1, 256) / sample.shape[1]
    return -(p * np.log2(np.where(p > 0, p, 1.0))).sum(axis=1) > 8.0 * STORE_ENTROPY


def _stored(data) -> bytes:
    """``data`` as non-final deflate "stored" blocks (RFC 1951 3.2.4; the stream is byte-aligned here)."""
    data, out = memoryview(data), []
    for i in range(0, len(data), 65535):
        n = min(65535, len(data) - i)
        out += [bytes((0, n & 255, n >> 8, ~n & 255, (~n >> 8) & 255)), data[i:i + n]]
    return b"".join(out)


def deflate_chunk(block: np.ndarray) -> bytes:
    """One chunk through HDF5's shuffle and deflate filters, as the library would store it: the
    elements' bytes regrouped by position (byte 0 of every element, then byte 1, ...), then a zlib
    stream. Deflate runs at level 1 with the run-length strategy (``Z_RLE``): on shuffled float64
    maps it keeps most of level 1's gain (900 x 700 phase: 0.755 of the raw size against 0.699) in
    about half the time, since the noisy low bytes are not searched for matches; those planes
    (:func:`_noisy`: 5-6 of a float64 map's 8) are not deflated at all but written as stored blocks
    of the same stream, which deflate would not have shrunk anyway (0.4-0.5 s of CPU less for the 16
    maps of a 900 x 700 ``calib unwrap --model``). Any zlib inflater (HDF5's deflate filter) reads
    it: one zlib stream of the shuffled bytes, checksum included."""
    raw = np.ascontiguousarray(block).reshape(-1).view(np.uint8)
    size = block.dtype.itemsize
    if size == 1:
        z = zlib.compressobj(1, zlib.DEFLATED, 15, 8, zlib.Z_RLE)
        return z.compress(raw) + z.flush()
    raw = np.ascontiguousarray(raw.reshape(-1, size).T)
    out, run = [b"\x78\x01"], []            # zlib header: deflate, 32 KiB window, fastest level

    def flush_run():
        if run:
            z = zlib.compressobj(1, zlib.DEFLATED, -15, 8, zlib.Z_RLE)      # raw deflate, its own history
            out.extend((z.compress(np.concatenate(run)), z.flush(zlib.Z_FULL_FLUSH)))   # ends byte-aligned
            run.clear()
    for plane, noisy in zip(raw, _noisy(raw)):
        if noisy:
            flush_run()
            out.append(_stored(plane))
        else:
            run.append(plane)
    flush_run()
    out += [b"\x01\x00\x00\xff\xff", zlib.adler32(raw).to_bytes(4, "big")]   # final empty block, checksum
    return b"".join(out)


def _create_dataset(g, name: str, data: np.ndarray, options: dict) -> None:
    """``g.create_dataset(name, data=data, **options)``; when ``options`` ask for gzip level 1 behind
    the shuffle (:func:`_codec`; another level is h5py's to honour) and ``data`` is a non-empty
    array of plain numbers (bool, integer, float; native byte order), the chunks (whole rows, :data:`CHUNK_BYTES`) are shuffled and
    deflated on threads (:func:`deflate_chunk`) and stored as they are (HDF5 direct chunk writes):
    the same filters, the same values read back; the 16 maps of a 900 x 700 ``calib unwrap --model``
    in 0.40 s of wall against h5py's 0.75 s on 2 shared cores (docs/speed.md)."""
    plain = (options.get("compression") == "gzip" and options.get("compression_opts") == 1 and options.get("shuffle")
        and set(options) <= {"compression", "compression_opts", "shuffle"} and data.ndim >= 1 and data.size > 0
        and data.dtype.kind in "biuf" and data.dtype.isnative)
    if not plain:
        g.create_dataset(name, data=data, **options)
        return
    row = data.itemsize * (data.size // data.shape[0])
    rows = max(1, min(data.shape[0], CHUNK_BYTES // max(row, 1)))
    chunks = (rows, *data.shape[1:])
    d = g.create_dataset(name, shape=data.shape, dtype=data.dtype, chunks=chunks, **options)
    starts = range(0, data.shape[0], rows)

    def block(r0):
        b = data[r0:r0 + rows]
        if b.shape[0] < rows:        # an edge chunk is stored whole: padded beyond the dataset's extent
            b = np.concatenate([b, np.zeros((rows - b.shape[0], *data.shape[1:]), data.dtype)])
        return deflate_chunk(b)
    zero = (0,) * (data.ndim - 1)
    for r0, stored in zip(starts, _pool().map(block, starts)):
        d.id.write_direct_chunk((r0, *zero), stored, 0)


def write_phase_file(path, groups: dict, *, frequency: float | None = None, attrs: dict | None = None,
                     compression: str = "gzip") -> Path:
    """Write a phase file: ``groups`` {orientation: keyword arguments of :func:`write_phase_group`
    (``phase`` required)}, file attributes ``attrs``; ``frequency`` is the default of every group.
    Returns the path (its folder is created). The file is built in memory and then written
    atomically (:mod:`unwrap.safe_output`): a full disk leaves the previous file or none, and is
    reported naming ``path``, never a half-written HDF5 file (or a crash inside the HDF5 library)."""
    import io

    import h5py

    from .safe_output import write_bytes

    buf = io.BytesIO()
    with h5py.File(buf, "w") as f:
        f.attrs.update(attrs or {})
        for orientation, kw in groups.items():
            kw = dict(kw)
            kw.setdefault("frequency", frequency)
            write_phase_group(f, orientation, kw.pop("phase"), compression=compression, **_codec(compression), **kw)
    return write_bytes(path, buf.getbuffer())
