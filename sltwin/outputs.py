"""Output paths of a command, checked before any work is done.

A command that renders for a minute and then finds that ``-o`` names a file where it needs a
folder (or a folder where it writes a file, or a path under a file) wastes the minute and, worse,
used to end in a traceback. Every command calls one of these first:

- :func:`output_file`: the path will be written as a file: it must not be a directory, and the
  first existing folder above it must be a writable folder (missing folders are created later);
- :func:`output_dir`: the path will be a folder: it must not be an existing file, and the first
  existing folder above it must be writable.

Both raise :class:`sltwin.errors.CommandError` naming the option, the path and the problem.
A command calls them through :func:`claim`, which also refuses an output that is one of the
command's inputs and locks the output for this process (:mod:`unwrap.safe_output`; the locks are
released by :func:`release_all` when ``calib`` ends the command); a command that fills a folder
wholly (a render) also calls :func:`fresh_dir`, which refuses a folder holding anything unless
``--overwrite`` (docs/outputs.md).

SYNOPSIS

    >>> import tempfile, pathlib
    >>> from sltwin.outputs import output_dir, output_file
    >>> root = pathlib.Path(tempfile.mkdtemp())
    >>> (root / "report.txt").write_text("x")
    1
    >>> output_dir(root / "report.txt", "-o")
    Traceback (most recent call last):
    ...
    sltwin.errors.CommandError: -o ...report.txt: exists and is a file; expected a folder (or a new path)
    >>> output_file(root / "new" / "twin.json", "-o").name
    'twin.json'
"""
from __future__ import annotations

import os
from pathlib import Path

from .errors import CommandError


def _check_ancestor(path: Path, option: str) -> None:
    """The first existing folder above ``path`` must be a folder we may write into."""
    ancestor = path.parent
    while not ancestor.exists() and ancestor != ancestor.parent:
        ancestor = ancestor.parent
    if not ancestor.is_dir():
        raise CommandError(f"{option} {path}: {ancestor} is a file, so nothing can be written below it")
    if not os.access(ancestor, os.W_OK | os.X_OK):
        raise CommandError(f"{option} {path}: the folder {ancestor} is not writable")


def output_file(path, option: str = "-o") -> Path:
    """``path`` as a file to be written (see the module docstring); returns it as a ``Path``."""
    path = Path(path)
    if path.is_dir():
        raise CommandError(f"{option} {path}: is a folder; expected a file name")
    if path.exists() and not path.is_file():
        raise CommandError(f"{option} {path}: exists and is not a regular file (a device or a pipe?); name a "
                           "file to write")
    _check_ancestor(path, option)
    return path


def output_dir(path, option: str = "-o") -> Path:
    """``path`` as a folder to be written into (see the module docstring); returns it as a ``Path``."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        what = "a file" if path.is_file() else "not a regular file or folder (a device?)"
        raise CommandError(f"{option} {path}: exists and is {what}; expected a folder (or a new path)")
    if not path.exists():
        _check_ancestor(path, option)
    elif not os.access(path, os.W_OK | os.X_OK):
        raise CommandError(f"{option} {path}: the folder is not writable")
    return path


#: Locks this process holds on its outputs, released by :func:`release_all` (``calib`` does it
#: when a command ends, however it ends).
_HELD: list = []


def claim(path, kind: str = "file", inputs=(), option: str = "-o") -> Path:
    """Check ``path`` as an output ``kind`` ("file" or "dir") before any work: the checks of
    :func:`output_file` / :func:`output_dir`, not one of ``inputs`` (nor a folder holding one,
    nor inside an input folder: :func:`unwrap.safe_output.check_not_input`), and lock it for this
    process (:class:`unwrap.safe_output.OutputLock`: a second writer is refused naming the holder,
    a stale lock of a dead process taken over). Returns ``path`` as a ``Path``."""
    from unwrap.safe_output import OutputError, OutputLock, check_not_input

    path = output_file(path, option) if kind == "file" else output_dir(path, option)
    try:
        check_not_input(path, [p for p in inputs if p], option)
        lock = OutputLock(path).acquire()
    except OutputError as exc:
        raise CommandError(str(exc)) from None
    _HELD.append(lock)
    return path


def release_all() -> None:
    """Release every output lock :func:`claim` took."""
    while _HELD:
        _HELD.pop().release()


def fresh_dir(path, kind: str, overwrite: bool, own=("capture.toml", "truth.json", "truth.h5", "pose_*", "*.png"),
              option: str = "-o") -> Path:
    """An output folder that a command fills wholly (a render, a rendered session): new or empty;
    one that holds files is refused naming what is there, unless ``overwrite``, which first removes
    every entry matching ``own`` (what such a command writes), so that nothing stale (a pose of an
    earlier, larger session) survives. ``kind`` names the command's output in the message."""
    import shutil

    path = Path(path)
    if not path.is_dir():
        return path
    entries = sorted(p.name for p in path.iterdir() if not p.name.startswith("."))
    if not entries:
        return path
    if not overwrite:
        what = _describe_folder(path, entries)
        raise CommandError(f"{option} {path}: holds {what}; writing {kind} there would mix the two. Choose a new "
                           "folder, or give --overwrite to replace it wholly")
    for pattern in own:
        for p in path.glob(pattern):
            shutil.rmtree(p) if p.is_dir() else p.unlink()
    return path


def _describe_folder(path: Path, entries: list) -> str:
    """What an existing output folder holds, in words (a rendered session, a render, files)."""
    poses = [e for e in entries if e.startswith("pose_")]
    toml = path / "capture.toml"
    if poses and toml.is_file() and "[board]" in toml.read_text(errors="replace"):
        return f"a calibration session of {len(poses)} pose(s) (calib render-board: capture.toml with [board])"
    if poses:
        return f"a capture of {len(poses)} pose(s) ({', '.join(poses[:3])}{', ...' if len(poses) > 3 else ''})"
    if "truth.h5" in entries or toml.is_file():
        return "a render (calib render: images, capture.toml, truth.h5)"
    return f"{len(entries)} file(s) ({', '.join(entries[:4])}{', ...' if len(entries) > 4 else ''})"
