"""Whether the traditional ``calib unwrap``'s prefetch delays the Gray-code reads (session 11).

    python -m bench.prefetch_gray [--repeats 5] [--quick] [FOLDER ...]

:func:`unwrap.pipeline.unwrap_capture` starts decoding the next orientation's phase-shift frames on
the ``read-frames`` pool (:func:`unwrap.capture.prefetch`) as soon as this orientation's are read;
this orientation's Gray-code frames go through the same pool later, after its wrapped phases, and
would queue behind whatever of the prefetch is not done. For each Gray-code capture with a next
orientation (default: ``../shared/data/kamino-phaseshift-graycode-object``; the SLMaster capture has
one orientation, so nothing is prefetched, and the SLStudio one has no Gray code), per call:

- prefetch done: ms from the prefetch to its last frame decoded (the bound);
- Gray read start: ms from the prefetch to the first Gray-code stack read; the margin (start -
  done) > 0 means the Gray reads found the pool free;
- queued: prefetched frames not yet decoded when a Gray-code read started (summed over the call);
- whole capture: wall s of ``unwrap_capture`` with the prefetch, and without it (the anchor),
  interleaved call by call in this process.
"""
from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
DEFAULT = (ROOT.parent / "shared" / "data" / "kamino-phaseshift-graycode-object",)


def measure(folder, repeats: int) -> list:
    """Per call: (prefetch done ms, Gray read start ms, frames queued, wall s with, wall s without)."""
    from unwrap import capture as C
    from unwrap import pipeline as P

    cap = C.load_capture(folder)
    gray = {f for oc in cap.orientations.values() if oc.gray
            for f in [*oc.gray["files"], *(oc.gray.get("inverse") or [])]}
    ev: dict = {}
    real_prefetch, real_stack = P.prefetch, C.FrameReader.stack

    def prefetch(files):
        files = list(files)
        real_prefetch(files)
        if not files or "t0" in ev:
            return
        ev["t0"], futs = time.perf_counter(), [C._AHEAD[f] for f in files if f in C._AHEAD]
        left = [len(futs)]

        def done(_):
            left[0] -= 1
            if not left[0]:
                ev["done"] = time.perf_counter()
        for f in futs:
            f.add_done_callback(done)

    def stack(self, files):
        files = list(files)
        if "t0" in ev and any(f in gray for f in files):
            ev.setdefault("gray", time.perf_counter())
            ev["queued"] = ev.get("queued", 0) + sum(not f.done() for f in C._AHEAD.values())
        return real_stack(self, files)

    rows = []
    P.prefetch, C.FrameReader.stack = prefetch, stack
    try:
        P.unwrap_capture(folder)                                 # imports, kernels, file cache
        for _ in range(repeats):
            ev.clear()
            t = time.perf_counter()
            P.unwrap_capture(folder)
            with_s = time.perf_counter() - t
            P.prefetch = lambda files: None
            t = time.perf_counter()
            P.unwrap_capture(folder)
            without_s = time.perf_counter() - t
            P.prefetch = prefetch
            if "gray" not in ev:
                raise SystemExit(f"{folder}: no Gray-code read after a prefetch (one orientation, or no Gray code)")
            rows.append((1e3 * (ev["done"] - ev["t0"]), 1e3 * (ev["gray"] - ev["t0"]), ev.get("queued", 0),
                         with_s, without_s))
    finally:
        P.prefetch, C.FrameReader.stack = real_prefetch, real_stack
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("folders", nargs="*", type=Path)
    ap.add_argument("--repeats", type=int, default=5)
    ap.add_argument("--quick", action="store_true", help="2 calls per capture")
    a = ap.parse_args(argv)
    folders = a.folders or [f for f in DEFAULT if f.is_dir()]
    if not folders:
        print("no Gray-code capture found (../shared/data/kamino-phaseshift-graycode-object): nothing to measure")
        return 0
    print("| capture | call | prefetch done ms | Gray read start ms | margin ms | queued | with prefetch s | "
          "without s |")
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for folder in folders:
        rows = measure(folder, 2 if a.quick else a.repeats)
        for i, (done, start, queued, w, wo) in enumerate(rows, 1):
            print(f"| {folder.name} | {i} | {done:.0f} | {start:.0f} | {start - done:+.0f} | {queued} | {w:.2f} | "
                  f"{wo:.2f} |")
        print(f"| {folder.name} | median | {statistics.median(r[0] for r in rows):.0f} | "
              f"{statistics.median(r[1] for r in rows):.0f} | {statistics.median(r[1] - r[0] for r in rows):+.0f} | "
              f"{sum(r[2] for r in rows)} | {statistics.median(r[3] for r in rows):.2f} | "
              f"{statistics.median(r[4] for r in rows):.2f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
