"""Output paths of a command, checked before any work is done.

A command that renders for a minute and then finds that ``-o`` names a file where it needs a
folder (or a folder where it writes a file, or a path under a file) wastes the minute and, worse,
used to end in a traceback. Every command calls one of these first:

- :func:`output_file`: the path will be written as a file: it must not be a directory, and the
  first existing folder above it must be a writable folder (missing folders are created later);
- :func:`output_dir`: the path will be a folder: it must not be an existing file, and the first
  existing folder above it must be writable.

Both raise :class:`sltwin.errors.CommandError` naming the option, the path and the problem.

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
        raise CommandError(f"{option} {path}: exists and is not a regular file")
    _check_ancestor(path, option)
    return path


def output_dir(path, option: str = "-o") -> Path:
    """``path`` as a folder to be written into (see the module docstring); returns it as a ``Path``."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise CommandError(f"{option} {path}: exists and is a file; expected a folder (or a new path)")
    if not path.exists():
        _check_ancestor(path, option)
    elif not os.access(path, os.W_OK | os.X_OK):
        raise CommandError(f"{option} {path}: the folder is not writable")
    return path
