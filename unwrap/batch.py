"""Unwrap many captures in one process (``calib unwrap DIR_OF_CAPTURES`` or ``calib unwrap A B C``):
one loaded model (the learned path's predictor is cached per process), a progress bar with
captures/s on stderr, one result or one error per capture, and a summary.

A folder is a *batch* when it is not itself a capture (no ``capture.toml``, no frames, no
``pose_*`` folders) and its sub-folders are: each sub-folder with a ``capture.toml`` or frames is
one capture, in name order.

SYNOPSIS

    from unwrap.batch import capture_folders, stream
    for item in stream(capture_folders(["captures/"]), decode, progress=True):
        item.folder, item.result, item.error, item.seconds
"""
from __future__ import annotations

import sys
import time
from dataclasses import dataclass
from pathlib import Path

from .errors import UnwrapError

_FRAME_SUFFIXES = {".png", ".bmp", ".tif", ".tiff", ".jpg", ".jpeg"}


def is_capture(folder: Path) -> bool:
    """Whether ``folder`` holds a capture itself (capture.toml, frames or pose folders)."""
    if (folder / "capture.toml").is_file():
        return True
    for p in folder.iterdir():
        if p.is_file() and p.suffix.lower() in _FRAME_SUFFIXES:
            return True
        if p.is_dir() and p.name.startswith("pose_"):
            return True
    return False


def capture_folders(paths) -> list[Path]:
    """The capture folders named by ``paths``: each path a capture, or a folder of captures
    (module docstring). Refuses (:class:`UnwrapError`) a missing path or a folder with neither."""
    out = []
    for p in map(Path, paths):
        if not p.is_dir():
            raise UnwrapError(f"capture folder not found: {p}")
        if is_capture(p):
            out.append(p)
            continue
        subs = sorted(q for q in p.iterdir() if q.is_dir() and is_capture(q))
        if not subs:
            raise UnwrapError(f"{p}: neither a capture (capture.toml, frames, pose_* folders) nor a folder of captures")
        out.extend(subs)
    return out


def output_names(folders) -> list[str]:
    """One distinct output sub-folder name per capture (its folder name, numbered on a clash)."""
    names, seen = [], {}
    for f in folders:
        base = Path(f).name or "capture"
        n = seen.get(base, 0)
        seen[base] = n + 1
        names.append(base if n == 0 else f"{base}_{n + 1}")
    return names


@dataclass
class Item:
    """One capture of a batch: its folder, the decode's result or the error (a ValueError /
    OSError of the toolkit), and the wall seconds it took."""
    folder: Path
    result: object
    error: Exception | None
    seconds: float


def stream(folders, decode, *, progress: bool = True, label: str = "unwrap"):
    """Yield an :class:`Item` per folder: ``decode(folder)`` in turn, errors caught per capture
    (``ValueError`` / ``OSError``: the toolkit's refusals; anything else is a bug and propagates).
    ``progress``: a tqdm bar (captures, captures/s) on stderr."""
    from tqdm import tqdm

    bar = tqdm(total=len(folders), unit="capture", desc=label, file=sys.stderr, disable=not progress,
               dynamic_ncols=True)
    try:
        for f in folders:
            t0 = time.perf_counter()
            try:
                res, err = decode(f), None
            except (ValueError, OSError) as exc:
                res, err = None, exc
            yield Item(Path(f), res, err, time.perf_counter() - t0)
            bar.update(1)
    finally:
        bar.close()


def summary(items, wall_s: float) -> str:
    """One paragraph: captures done / failed, wall time, captures/s, the failures named."""
    ok = [i for i in items if i.error is None]
    bad = [i for i in items if i.error is not None]
    rate = len(items) / wall_s if wall_s > 0 else float("nan")
    lines = [f"{len(ok)} of {len(items)} captures unwrapped in {wall_s:.2f} s ({rate:.2f} captures/s; "
             f"per capture min {min((i.seconds for i in items), default=0):.2f} s, "
             f"max {max((i.seconds for i in items), default=0):.2f} s)"]
    lines += [f"  failed: {i.folder}: {i.error}" for i in bad]
    return "\n".join(lines)
