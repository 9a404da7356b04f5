"""``unwrap.h5`` written while the capture's later orientations are still being decoded.

:func:`unwrap.pipeline.write_results` compresses and writes every orientation once the whole capture
is decoded. :class:`StreamedWrite` takes each orientation's result as it is made
(:meth:`StreamedWrite.add`, the ``on_result`` hook of :func:`unwrap.learned.capture.unwrap_capture_learned`):
a writer thread puts its group into the in-memory HDF5 file (the chunks deflated on the
``h5-deflate`` pool, :func:`unwrap.phase_io.write_phase_group`) and encodes its PNG preview while the
next orientation's frames are fitted and its network runs; :meth:`StreamedWrite.close` then adds
nothing but the last group, and writes the file (temporary file, ``fsync``, rename:
:func:`unwrap.safe_output.write_bytes`) on a thread while the last preview is encoded. The file is
the one :func:`unwrap.pipeline.write_results` writes, group by group in the same order with the same
calls (every dataset bitwise the same, tests/test_streamed_write.py); the previews are written after
it, as there. Nothing is written to disk before :meth:`close`: a capture that fails half way
(:meth:`abandon`) leaves no file, as before.

SYNOPSIS (``results`` as :func:`unwrap.pipeline.write_results` takes them)::

    w = StreamedWrite(out_dir, attrs={"capture": "CAPTURE"})
    for o, r in results.items():
        w.add(o, r)
    path = w.close()
"""
from __future__ import annotations

import io
from pathlib import Path

__all__ = ["StreamedWrite"]


class StreamedWrite:
    """One capture's ``out_dir/unwrap.h5`` (and ``{o}_unwrap.png`` previews unless ``previews`` is
    False), built orientation by orientation on a writer thread (module docstring). ``attrs``: the
    file's attributes. Not for use from several threads."""

    def __init__(self, out_dir, *, previews: bool = True, attrs: dict | None = None, compression: str = "gzip"):
        import h5py

        self.out = Path(out_dir)
        self.previews = previews
        self.compression = compression
        self._buf = io.BytesIO()
        self._file = h5py.File(self._buf, "w")
        self._file.attrs.update(attrs or {})
        self._last = None           # the previous orientation's job: jobs run one after the other
        self._encoded: dict = {}
        self._orientations: dict = {}

    def add(self, orientation: str, result) -> None:
        """Queue ``result`` (:class:`unwrap.pipeline.OrientationResult`) as group ``orientation``."""
        from ._threads import pool

        if self._file is None:
            raise RuntimeError("StreamedWrite: add after close")
        self._orientations[orientation] = result
        self._last = pool("h5-writer").submit(self._write, self._last, orientation, result)

    def _write(self, before, orientation: str, result) -> None:
        from .phase_io import _codec, write_phase_group
        from .pipeline import result_group

        if before is not None:
            before.result()         # groups in the order they were added (a failed one stops the rest)
        kw = result_group(result)
        write_phase_group(self._file, orientation, kw.pop("phase"), compression=self.compression,
                          **_codec(self.compression), **kw)
        if self.previews:
            from .previews import encode_previews

            self._encoded.update(encode_previews({orientation: result}))

    def _wait(self) -> None:
        last, self._last = self._last, None
        if last is not None:
            last.result()

    def close(self) -> Path:
        """Wait for the groups, write ``unwrap.h5`` atomically, then the previews; returns its path.
        The last orientation's preview is encoded while the file is written and flushed."""
        from ._threads import pool
        from .previews import write_previews
        from .safe_output import write_bytes

        try:
            self._wait()
            self._file.close()
        except BaseException:
            self.abandon()
            raise
        self._file = None
        path = self.out / "unwrap.h5"
        written = pool("h5-writer").submit(write_bytes, path, self._buf.getbuffer())
        try:
            if self.previews:
                from .previews import encode_previews

                todo = {o: r for o, r in self._orientations.items() if o not in self._encoded}
                self._encoded.update(encode_previews(todo) if todo else {})
        finally:
            written.result()            # raises the write's error (a full disk, naming the path)
        self._buf = None
        if self.previews:
            write_previews(self._orientations, self.out, self._encoded)
        return path

    def abandon(self) -> None:
        """Drop what was queued (a later orientation failed): waits for the running job, writes nothing."""
        try:
            self._wait()
        except BaseException:       # the caller is already raising the error that stopped the capture
            pass
        if self._file is not None:
            try:
                self._file.close()
            except Exception:
                pass
        self._file = self._buf = None
