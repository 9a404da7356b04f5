"""Crash-safe, resumable HDF5 shards of the fringe-order dataset, and joining shards without copying.

How a shard is written (``OUT.h5``):

1. every finished sample goes to its own small HDF5 file in ``OUT.h5.parts/`` - written as
   ``sample_NNNNNNNNN.h5.tmp``, flushed and fsynced, then renamed (atomic on POSIX), so a part
   that exists is complete and a killed export loses at most the sample in flight;
2. when every sample of the shard is there, the shard file is assembled into ``OUT.h5.tmp`` by
   copying the parts' compressed chunks as they are (``read_direct_chunk`` /
   ``write_direct_chunk``: no second compression), fsynced and renamed to ``OUT.h5``; then the
   parts are removed.

A rerun after ``kill -9`` (or a full disk) removes stale ``*.tmp`` files, skips the samples whose
parts exist and continues; because sample i depends only on (seed, i) and the file is built by
the same sequence of HDF5 calls, the resumed shard is bit-identical to an uninterrupted one. A
shard file exists only when it is complete (attribute ``complete`` True), so no half-written
sample is ever readable as valid. ``parts/meta.json`` records the config fingerprint: a rerun with
another config is refused instead of mixing samples.

``combine`` joins complete shards into one file of HDF5 virtual datasets (no data copied; source
paths relative to the combined file, so the folder can move as a whole). It refuses a missing,
duplicated, incomplete or foreign shard before building anything (a virtual dataset would
silently return fill values for a missing source) and writes through a temporary file, so an
interrupted combine leaves no broken output.
"""
from __future__ import annotations

import errno
import hashlib
import io
import json
import logging
import os
from pathlib import Path

import numpy as np

from unwrap.dataset_schema import SCHEMA, DatasetSchemaError, check_schema, read_attrs

from ..errors import ExportError, SynthError  # noqa: F401  (ExportError re-exported)

LOG = logging.getLogger("synth")

#: datasets written as values (not chunk copies) at assembly: small per-sample records
_SMALL = ("sample_index", "params", "label_check")


# -- shard ranges --------------------------------------------------------------------------------

def parse_shard(text: str) -> tuple[int, int]:
    """``"i/n"`` -> (i, n) with 0 <= i < n."""
    try:
        i, n = (int(x) for x in str(text).split("/"))
    except ValueError:
        raise ExportError(f"--shard {text!r}: expected i/n with whole numbers, e.g. 0/4") from None
    if not (n >= 1 and 0 <= i < n):
        raise ExportError(f"--shard {text!r}: expected 0 <= i < n")
    return i, n


def shard_from_environment(env=None) -> tuple[int, int] | None:
    """(i, n) from torchrun (RANK, WORLD_SIZE) or a SLURM job array (SLURM_ARRAY_TASK_ID minus
    SLURM_ARRAY_TASK_MIN, SLURM_ARRAY_TASK_COUNT), or None when neither is set."""
    env = os.environ if env is None else env
    if "SLURM_ARRAY_TASK_ID" in env and "SLURM_ARRAY_TASK_COUNT" in env:
        i = int(env["SLURM_ARRAY_TASK_ID"]) - int(env.get("SLURM_ARRAY_TASK_MIN", 0))
        n = int(env["SLURM_ARRAY_TASK_COUNT"])
        src = "SLURM_ARRAY_TASK_ID/COUNT"
    elif "RANK" in env and "WORLD_SIZE" in env:
        i, n, src = int(env["RANK"]), int(env["WORLD_SIZE"]), "RANK/WORLD_SIZE"
    else:
        return None
    if not 0 <= i < n:
        raise ExportError(f"{src} give shard {i} of {n}: expected 0 <= i < n")
    return i, n


def shard_range(samples: int, i: int, n: int) -> range:
    """Contiguous block of global sample indices of shard i of n (sizes differ by at most 1)."""
    return range(samples * i // n, samples * (i + 1) // n)


def shard_path(out, i: int, n: int) -> Path:
    """``data.h5`` -> ``data-00001-of-00004.h5`` for n > 1 (the path itself for one shard)."""
    out = Path(out)
    return out if n == 1 else out.with_name(f"{out.stem}-{i:05d}-of-{n:05d}{out.suffix or '.h5'}")


# -- dataset creation ------------------------------------------------------------------------------

def _filters(codec: str) -> dict:
    if codec == "none":
        return {}
    if codec == "lzf":
        return {"compression": "lzf", "shuffle": True}
    level = int(codec.split("-")[1]) if "-" in codec else 4
    return {"compression": "gzip", "compression_opts": level, "shuffle": True}


def _create(h5, name: str, shape: tuple, dtype, codec: str):
    """A per-sample dataset (sample axis first) chunked one sample (and frequency) per chunk."""
    if name in _SMALL:
        if name == "params":
            import h5py
            return h5.create_dataset(name, shape, dtype=h5py.string_dtype(), track_times=False)
        return h5.create_dataset(name, shape, dtype=dtype, track_times=False)
    chunks = (1,) * (len(shape) - 2) + tuple(shape[-2:])
    return h5.create_dataset(name, shape, dtype=dtype, chunks=chunks, track_times=False, **_filters(codec))


def _fsync_path(path: Path):
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _disk_error(exc: OSError, what: str, parts_dir: Path, done: int) -> ExportError:
    if exc.errno == errno.ENOSPC and exc.strerror and exc.strerror != os.strerror(errno.ENOSPC):
        return ExportError(f"cannot write {what}: {exc.strerror}. {done} finished sample(s) are kept in "
                           f"{parts_dir}; free space and rerun the same command to resume")
    why = {errno.ENOSPC: "disk full", errno.EFBIG: "file size limit reached", errno.EDQUOT: "disk quota exceeded",
           errno.EACCES: "permission denied", errno.EROFS: "read-only file system"}.get(exc.errno, exc.strerror or str(exc))
    return ExportError(f"cannot write {what}: {why}. {done} finished sample(s) are kept in {parts_dir}; "
                       "fix the cause and rerun the same command to resume")


# -- the shard writer -------------------------------------------------------------------------------

class ShardWriter:
    """Writes the samples of one shard as parts, then assembles the shard (module docstring).

    ``attrs``: root attributes (schema, system, config, ...); ``fingerprint``: what a resumed run
    must share with the first (config + system + schema)."""

    def __init__(self, out, indices: range, attrs: dict, codec: str, fingerprint: str, group_attrs=None):
        self.group_attrs = group_attrs or {}
        self.out = Path(out)
        self.indices = indices
        self.attrs = dict(attrs)
        self.codec = codec
        self.fingerprint = fingerprint
        self.parts = self.out.with_name(self.out.name + ".parts")

    # - state on disk -
    def part_path(self, index: int) -> Path:
        return self.parts / f"sample_{index:09d}.h5"

    def complete(self) -> bool:
        """True when the shard file exists, is complete and was made from the same config."""
        if not self.out.exists():
            return False
        import h5py
        try:
            with h5py.File(self.out, "r") as h5:
                a = read_attrs(h5)
        except OSError as exc:
            raise ExportError(f"{self.out} exists but is not a readable HDF5 file ({exc}); remove it") from None
        if a.get("schema") != SCHEMA or a.get("fingerprint") != self.fingerprint:
            raise ExportError(f"{self.out} exists and was not made by this config (fingerprint differs); "
                              "remove it or choose another output")
        return bool(a.get("complete"))

    def prepare(self) -> list:
        """Create or check the parts folder; return the indices still to do."""
        try:
            self.out.parent.mkdir(parents=True, exist_ok=True)
            self.parts.mkdir(exist_ok=True)
        except OSError as exc:
            raise ExportError(f"cannot create the output folder for {self.out}: {exc.strerror or exc}") from None
        meta = self.parts / "meta.json"
        if meta.exists():
            m = json.loads(meta.read_text())
            if m.get("fingerprint") != self.fingerprint:
                raise ExportError(f"{self.parts} holds samples of another config (fingerprint differs): remove it "
                                  "or choose another output")
            if m.get("code_version") != self.attrs.get("code_version"):
                LOG.warning("resuming %s written by %s with %s: samples may differ in the last bits", self.out,
                            m.get("code_version"), self.attrs.get("code_version"))
        else:
            try:
                tmp = meta.with_suffix(".json.tmp")
                tmp.write_text(json.dumps({"fingerprint": self.fingerprint,
                                           "code_version": self.attrs.get("code_version")}))
                os.replace(tmp, meta)
            except OSError as exc:
                raise _disk_error(exc, meta, self.parts, 0) from None
        for stale in self.parts.glob("*.tmp"):
            stale.unlink()
        for i in self.indices:              # a part damaged since it was written is rendered again
            problem = self.part_problem(i) if self.part_path(i).exists() else None
            if problem:
                LOG.warning("%s: %s; rendering that sample again", self.part_path(i), problem)
                self.part_path(i).unlink()
        return [i for i in self.indices if not self.part_path(i).exists()]

    def part_problem(self, index: int) -> str | None:
        """Why the finished part of sample ``index`` cannot be used (unreadable, another sample,
        a dataset that does not decompress), or None when every dataset of it reads back."""
        import h5py

        try:
            with h5py.File(self.part_path(index), "r") as part:
                if int(part["sample_index"][0]) != index:
                    return f"holds sample {int(part['sample_index'][0])}, not {index}"
                for name, d in _datasets(part).items():
                    d[...]                        # decompresses every chunk: a damaged one fails here
        except (OSError, KeyError, ValueError, RuntimeError) as exc:
            return f"damaged part ({type(exc).__name__}: {str(exc).split('(')[0].strip()[:120]})"
        return None

    def done_count(self) -> int:
        return sum(self.part_path(i).exists() for i in self.indices)

    # - writing -
    def write_part(self, index: int, arrays: dict, params: str, label_check: np.ndarray):
        """One sample as ``parts/sample_N.h5`` (atomic)."""
        import h5py

        path = self.part_path(index)
        tmp = path.with_name(path.name + ".tmp")
        # built in memory, then written by plain file I/O: a full disk is a clean OSError, never a
        # half-closed HDF5 file
        buf = io.BytesIO()
        with h5py.File(buf, "w", libver="latest") as h5:
            _create(h5, "sample_index", (1,), np.int64, self.codec)[0] = index
            _create(h5, "params", (1,), None, self.codec)[0] = params
            _create(h5, "label_check", (1,) + label_check.shape, np.int32, self.codec)[0] = label_check
            for name in sorted(arrays):
                a = arrays[name]
                _create(h5, name, (1,) + a.shape, a.dtype, self.codec)[0] = a
        try:
            with open(tmp, "wb") as fh:
                fh.write(buf.getbuffer())
                fh.flush()
                os.fsync(fh.fileno())
            os.replace(tmp, path)
        except OSError as exc:
            tmp.unlink(missing_ok=True)
            raise _disk_error(exc, f"sample {index} ({tmp})", self.parts, self.done_count()) from None
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise

    def _check_space(self, parts_bytes: int):
        """Refuse to assemble when the shard file (about the parts' size) cannot fit: free disk
        space, or the process's file size limit (RLIMIT_FSIZE)."""
        import resource
        import shutil

        need = int(parts_bytes * 1.02) + (1 << 20)
        free = shutil.disk_usage(self.out.parent).free
        limit = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
        if free < need or (limit != resource.RLIM_INFINITY and limit < need):
            why = (f"{free / 1e6:.1f} MB free" if free < need else f"file size limit {limit / 1e6:.1f} MB")
            raise _disk_error(OSError(errno.ENOSPC, f"the shard file needs about {need / 1e6:.1f} MB, {why}"),
                              f"the shard file {self.out}", self.parts, self.done_count())

    def assemble(self) -> Path:
        """Build the shard file from the parts (all must exist), atomically; remove the parts."""
        import h5py

        missing = [i for i in self.indices if not self.part_path(i).exists()]
        if missing:
            raise ExportError(f"{self.out}: {len(missing)} sample(s) missing in {self.parts} (first {missing[:5]})")
        for i in self.indices:     # every part verified before any is copied into the shard file
            problem = self.part_problem(i)
            if problem:
                raise ExportError(f"{self.part_path(i)}: {problem}; rerun the export: it renders that sample again")
        tmp = self.out.with_name(self.out.name + ".tmp")
        S = len(self.indices)
        self._check_space(sum(self.part_path(i).stat().st_size for i in self.indices))
        try:
            with h5py.File(tmp, "w", libver="latest") as out:
                first = None
                for k, index in enumerate(self.indices):
                    with h5py.File(self.part_path(index), "r") as part:
                        if first is None:
                            first = _datasets(part)
                            dsets = {n: _create(out, n, (S,) + o.shape[1:], o.dtype, self.codec) for n, o in first.items()}
                            small = {n: [] for n in _SMALL}
                        for n in _SMALL:
                            small[n].append(part[n][0])
                        for n, d in dsets.items():
                            if n in _SMALL:
                                continue
                            src = part[n]
                            for offset in _chunk_offsets(src.shape):
                                mask, data = src.id.read_direct_chunk(offset)
                                d.id.write_direct_chunk((k,) + offset[1:], data, mask)
                for n in _SMALL:
                    dsets[n][...] = np.stack(small[n]) if n != "params" else np.array(small[n], dtype=object)
                for g, ga in self.group_attrs.items():
                    out[g].attrs.update(ga)
                for key, v in {**self.attrs, "n_samples": S, "first_sample": self.indices.start,
                               "complete": True}.items():
                    out.attrs[key] = v
            _fsync_path(tmp)
            os.replace(tmp, self.out)
        except (OSError, RuntimeError) as exc:  # h5py reports some failed writes as RuntimeError
            tmp.unlink(missing_ok=True)
            if not isinstance(exc, OSError):
                exc = OSError(errno.EIO, str(exc).split("(")[0].strip())
            raise _disk_error(exc, f"the shard file {tmp}", self.parts, self.done_count()) from None
        except BaseException:
            tmp.unlink(missing_ok=True)
            raise
        for p in self.parts.iterdir():
            p.unlink()
        self.parts.rmdir()
        return self.out


def _datasets(h5) -> dict:
    """{path: dataset} of every dataset in an open file (sorted by path)."""
    import h5py

    out = {}

    def visit(name, obj):
        if isinstance(obj, h5py.Dataset):
            out[name] = obj
    h5.visititems(visit)
    return dict(sorted(out.items()))


def _chunk_offsets(shape):
    """Offsets of every chunk of a per-sample dataset (chunks (1, ..., 1, H, W))."""
    lead = shape[:-2]
    for idx in np.ndindex(*lead):
        yield tuple(int(i) for i in idx) + (0, 0)


def fingerprint_of(*parts) -> str:
    h = hashlib.sha256()
    for p in parts:
        h.update(json.dumps(p, sort_keys=True, default=str).encode())
    return h.hexdigest()[:32]


# -- combine ---------------------------------------------------------------------------------------

def combine(shards, out, *, progress=None) -> Path:
    """Join complete shards into one file of virtual datasets (see the module docstring).

    ``progress``: optional callable(name) called after each virtual dataset (for a progress line)."""
    import h5py

    out = Path(out)
    if any(Path(s).resolve() == out.resolve() for s in shards):
        raise ExportError(f"--combine: the output {out} is one of the shards (a file joined into itself "
                          "would point at itself and be lost); name another output")
    infos, total = _checked_shards([Path(s) for s in shards])
    names = infos[0][2]
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    try:
        with h5py.File(tmp, "w", libver="latest") as h5:
            for name, (shape, dtype) in sorted(names.items()):
                layout = h5py.VirtualLayout(shape=(total,) + tuple(shape[1:]), dtype=dtype)
                p = 0
                for s, a, _ in infos:
                    m = int(a["n_samples"])
                    rel = os.path.relpath(s.resolve(), out.resolve().parent)
                    layout[p:p + m] = h5py.VirtualSource(rel, name, shape=(m,) + tuple(shape[1:]))
                    p += m
                kw = {"fillvalue": -1} if np.issubdtype(dtype, np.integer) else {}
                h5.create_virtual_dataset(name, layout, **kw)
                if progress is not None:
                    progress(name)
            with h5py.File(infos[0][0], "r") as first:
                for g in first:
                    if isinstance(first[g], h5py.Group):
                        h5[g].attrs.update(dict(first[g].attrs))
            for k, v in infos[0][1].items():
                if k in ("widths", "config_json", "system_dict"):
                    v = json.dumps(v)
                h5.attrs[k] = v
            h5.attrs.update({"shard": [0, 1], "first_sample": 0, "n_samples": total, "complete": True,
                             "combined_from": [os.path.relpath(s.resolve(), out.resolve().parent) for s, _, _ in infos]})
        os.replace(tmp, out)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return out


def _checked_shards(shards: list) -> tuple[list, int]:
    """[(path, attrs, {dataset: (shape, dtype)})] sorted by shard, and the sample total; refuses
    a missing, duplicated, incomplete, foreign or mismatched shard (ExportError)."""
    import h5py

    if not shards:
        raise ExportError("--combine: no shard files given")
    infos = []
    for s in shards:
        if not s.exists():
            raise ExportError(f"--combine: shard {s} does not exist")
        try:
            with h5py.File(s, "r") as h5:
                a = check_schema(h5, str(s), require_complete=True)
                shapes = {n: (o.shape, o.dtype) for n, o in _datasets(h5).items()}
        except DatasetSchemaError as exc:
            raise ExportError(f"--combine: {exc}") from None
        except OSError as exc:
            raise ExportError(f"--combine: shard {s} is not a readable HDF5 file ({exc}); rerun its export") from None
        infos.append((s, a, shapes))
    fp = {a.get("fingerprint") for _, a, _ in infos}
    if len(fp) != 1:
        raise ExportError("--combine: the shards come from different exports (config fingerprints differ)")
    n = int(infos[0][1]["shard"][1])
    seen = {}
    for s, a, _ in infos:
        i, nn = (int(v) for v in a["shard"])
        if nn != n:
            raise ExportError(f"--combine: {s} is shard {i} of {nn}, others are of {n}")
        if i in seen:
            raise ExportError(f"--combine: shard {i} of {n} given twice ({seen[i]} and {s})")
        seen[i] = s
    missing = [i for i in range(n) if i not in seen]
    if missing:
        raise ExportError(f"--combine: shard(s) {missing} of {n} missing; export them first (--shard i/{n})")
    infos.sort(key=lambda x: int(x[1]["shard"][0]))
    total = int(infos[0][1]["samples_total"])
    pos = 0
    for s, a, _ in infos:
        if int(a["first_sample"]) != pos:
            raise ExportError(f"--combine: {s} starts at sample {a['first_sample']}, expected {pos}")
        pos += int(a["n_samples"])
    if pos != total:
        raise ExportError(f"--combine: the shards hold {pos} samples, the export has {total}")
    names = infos[0][2]
    for s, _, shapes in infos[1:]:
        if set(shapes) != set(names) or any(shapes[k][0][1:] != names[k][0][1:] for k in names):
            raise ExportError(f"--combine: {s} has other datasets or shapes than {infos[0][0]}")
    return infos, total

