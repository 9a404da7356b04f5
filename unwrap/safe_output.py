"""Safe outputs: atomic writes, one writer per output, and no output that is also an input.

Every command of the toolkit writes through these (the lowest package that writes files holds
them, so that every package above may use them):

- :func:`atomic_path` / :func:`write_text` / :func:`write_bytes` / :func:`save_figure`: the file
  is written to a temporary file in the same folder, flushed to disk (``fsync``) and renamed over
  the target (``os.replace``, atomic on POSIX). An interrupted or failed write (Ctrl-C, a full
  disk) leaves the previous complete file, or nothing, never a truncated one; a full disk is
  reported as an ``OSError`` that names the target path.
- :class:`OutputLock`: an exclusive lock on an output file or folder, a lock file
  ``.NAME.lock`` beside it holding the owner's pid and host. A second writer is refused naming
  the holder; a lock whose process is dead (same host) is stale and taken over.
- :func:`check_not_input`: an output must not be one of the inputs (same path, same file by
  inode, a folder holding an input, or a path inside an input folder), checked before any work.

Errors: :class:`unwrap.errors.OutputError` (an ``UnwrapError``, so a ``ValueError``) naming the path and the
problem.

SYNOPSIS

    >>> import tempfile, pathlib
    >>> from unwrap.safe_output import OutputLock, check_not_input, write_text
    >>> root = pathlib.Path(tempfile.mkdtemp())
    >>> write_text(root / "a.txt", "first").read_text()
    'first'
    >>> with OutputLock(root / "out"):
    ...     OutputLock(root / "out").acquire()
    Traceback (most recent call last):
    ...
    unwrap.errors.OutputError: ...out: already being written by this process
    >>> check_not_input(root / "a.txt", [root / "a.txt"], "-o")
    Traceback (most recent call last):
    ...
    unwrap.errors.OutputError: -o ...a.txt: is also an input (...a.txt); writing it would destroy the input
"""
from __future__ import annotations

import contextlib
import errno
import os
import socket
import tempfile
from pathlib import Path

from .errors import OutputError

__all__ = ["OutputError", "OutputLock", "atomic_path", "check_not_input", "write_bytes", "write_text",
           "save_figure", "disk_error"]


def disk_error(exc: OSError, path) -> OSError:
    """``exc`` as an ``OSError`` whose message names ``path`` (a full disk says where)."""
    if exc.filename is not None and str(path) in str(exc.filename):
        return exc
    what = exc.strerror or str(exc)
    if exc.errno == errno.ENOSPC:
        what += " (the disk is full: free space and run the command again; the previous file, if any, is intact)"
    return OSError(exc.errno, what, str(path))


def _fsync_dir(folder: Path) -> None:
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextlib.contextmanager
def atomic_path(path):
    """A temporary path in ``path``'s folder to write; on success it is flushed to disk and
    renamed to ``path`` (atomic), on any error or interrupt it is removed and ``path`` is left as
    it was. A write error (``OSError``, e.g. a full disk) is raised naming ``path``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # the temporary name keeps the suffix: writers that choose the format by it (OpenCV, mrcal) still can
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
    os.close(fd)
    try:
        yield Path(tmp)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, 0o666 & ~_umask())
        os.replace(tmp, path)
        _fsync_dir(path.parent)
    except OSError as exc:
        _unlink(tmp)
        raise disk_error(exc, path) from exc
    except BaseException:
        _unlink(tmp)
        raise


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _unlink(path) -> None:
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass


def write_bytes(path, data: bytes) -> Path:
    """Write ``data`` to ``path`` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_bytes(data)
    return Path(path)


def write_text(path, text: str) -> Path:
    """Write ``text`` to ``path`` atomically; returns the path."""
    with atomic_path(path) as tmp:
        tmp.write_text(text)
    return Path(path)


def save_figure(fig, path, **kwargs) -> Path:
    """``fig.savefig(path, **kwargs)`` atomically (the format from ``path``'s suffix)."""
    path = Path(path)
    kwargs.setdefault("format", path.suffix.lstrip(".") or "png")
    with atomic_path(path) as tmp:
        fig.savefig(tmp, **kwargs)
    return path


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:   # alive, another user's
        return True
    return True


class OutputLock:
    """An exclusive lock on the output ``path`` (file or folder): the lock file ``.NAME.lock``
    beside it holds ``pid host``. ``acquire`` refuses (:class:`OutputError`) when another live
    process holds it, naming that process; a lock left by a dead process of this host is taken
    over. A context manager; ``release`` removes the lock file (only if it is still ours)."""

    def __init__(self, path):
        self.path = Path(os.path.abspath(path))
        self.lock_file = self.path.parent / f".{self.path.name}.lock"
        self.held = False

    def acquire(self) -> "OutputLock":
        me = f"{os.getpid()} {socket.gethostname()}\n"
        self.lock_file.parent.mkdir(parents=True, exist_ok=True)
        for _ in range(3):
            try:
                fd = os.open(self.lock_file, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
            except FileExistsError:
                holder = self._holder()
                if holder is None:          # stale (dead pid) or unreadable: take it over
                    _unlink(self.lock_file)
                    continue
                pid, host = holder
                if pid == os.getpid() and host == socket.gethostname():
                    raise OutputError(f"{self.path}: already being written by this process") from None
                raise OutputError(f"{self.path}: another process is writing it (pid {pid} on {host}, lock "
                                  f"{self.lock_file}); wait for it to finish, or remove the lock file if that "
                                  "process is gone") from None
            with os.fdopen(fd, "w") as fh:
                fh.write(me)
            self.held = True
            return self
        raise OutputError(f"{self.path}: could not take the lock {self.lock_file}")

    def _holder(self):
        """(pid, host) of a live holder, or None when the lock is stale or unreadable."""
        try:
            pid_s, host = self.lock_file.read_text().split()[:2]
            pid = int(pid_s)
        except (OSError, ValueError):
            return None
        if host == socket.gethostname() and not _pid_alive(pid):
            return None
        return pid, host

    def release(self) -> None:
        if not self.held:
            return
        self.held = False
        try:
            if self.lock_file.read_text().split()[0] == str(os.getpid()):
                _unlink(self.lock_file)
        except (OSError, IndexError):
            pass

    def __enter__(self):
        return self.acquire()

    def __exit__(self, *exc):
        self.release()


def _inside(child: Path, parent: Path) -> bool:
    return child == parent or parent in child.parents


def check_not_input(output, inputs, option: str = "-o") -> None:
    """Refuse (:class:`OutputError`) an ``output`` that is one of ``inputs`` (same resolved path
    or the same file by inode, a hard link), a folder holding one of them, or a path inside an
    input folder; inputs that do not exist are ignored (their own check names them)."""
    out = Path(os.path.realpath(output))
    for given in inputs:
        if given is None:
            continue
        src = Path(os.path.realpath(given))
        if not src.exists():
            continue
        same = out == src
        if not same and out.exists():
            try:
                same = os.path.samefile(out, src)
            except OSError:
                same = False
        if same:
            raise OutputError(f"{option} {output}: is also an input ({given}); writing it would destroy the input")
        if src.is_dir() and _inside(out, src):
            raise OutputError(f"{option} {output}: is inside the input folder {given}; write outputs elsewhere")
        if _inside(src, out):
            raise OutputError(f"{option} {output}: holds the input {given}; write outputs elsewhere")
