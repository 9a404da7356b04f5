"""Gray-code-only capture layouts: sessions with no phase shifting (Moreno & Taubin's calibration,
OpenCV's ``structured_light.GrayCodePattern``, kamino410/procam-calibration).

The projected frames, for each orientation, are the bits of the reflected Gray code of the block
index ``c = floor(x / block_px)`` (``x`` the projector column for ``v``, row for ``h``), MSB first,
each frame white where its bit is 1 and black elsewhere, optionally followed by its inverse;
a white and a black frame give the shadow mask (and the board image). Column bits:
``ceil(log2(ceil(W / block_px)))``, row bits the same with H (OpenCV's count).

Layouts (DESIGN.md terms):

- ``design`` with ``[pattern] kind = "graycode"``: ``capture.toml`` at the top, one folder per
  pose (``pose_00``, ...; or ``[capture] poses``) holding ``white.png``, ``black.png`` and
  ``{v|h}_gray_b{BB}.png`` (bit BB, 00 = MSB) with ``{v|h}_gray_b{BB}_inv.png`` (the frame names
  ``calib render-board --pattern graycode`` writes)::

      [pattern]
      kind = "graycode"     # Gray code only (the default kind is phase shifting: steps, frequencies)
      block_px = 1          # projector pixels per code step (procam-calibration's graycode_step)
      inverse = true        # each bit frame has its inverse; false: bits against (white + black) / 2

      [projector]
      size = [1024, 768]

- ``procam-graycode`` (kamino410/procam-calibration): pose folders ``capture_*/`` holding
  ``graycode_00.png ...`` in OpenCV's order: column bits as (pattern, inverse) pairs, then row
  bits, then white, then black (42 frames for a 1024 x 768 projector). The frame count alone
  does not say how many bits are columns: the ``capture.toml`` (``--capture-toml``) gives
  ``[projector] size`` and, where the session used one, ``[pattern] block_px``.

The decoder (``unwrap.pipeline``, method ``gray``) turns the bits into the block index and the
projector coordinate of the block centre (:func:`unwrap.graycode.gray_code_unwrap`): a map
quantised to ``block_px``, which the projector-pixel fit of ``calib`` models as such.
"""
from __future__ import annotations

import math
from pathlib import Path

from .errors import UnwrapError

GRAY_KIND = "graycode"
"""``[pattern] kind`` of a Gray-code-only DESIGN.md session."""


def gray_bits(extent: int, block_px: int) -> int:
    """Bits of the Gray code of ``ceil(extent / block_px)`` blocks (OpenCV's count, at least 1)."""
    blocks = -(-int(extent) // int(block_px))
    return max(1, math.ceil(math.log2(blocks)))


def gray_frame_stem(orientation: str, bit: int, inverse: bool = False) -> str:
    """File name (no extension) of a Gray-code frame of the DESIGN.md layout, e.g. ``v_gray_b03_inv``."""
    return f"{orientation}_gray_b{bit:02d}" + ("_inv" if inverse else "")


def read_gray_pattern(meta: dict, source) -> dict:
    """``[pattern]`` and ``[projector]`` of a Gray-code session: ``{"block_px", "inverse", "size"
    (W, H), "bits": {"v": n, "h": n}}``; UnwrapError names a missing or bad key."""
    pattern = meta.get("pattern", {})
    size = meta.get("projector", {}).get("size")
    try:
        W, H = (int(v) for v in size)
    except (TypeError, ValueError):
        raise UnwrapError(f"{source}: a Gray-code session needs [projector] size = [width, height] (the number "
                          f"of code bits follows from it), got {size!r}") from None
    block = pattern.get("block_px", 1)
    inverse = pattern.get("inverse", True)
    if isinstance(block, bool) or not isinstance(block, int) or block < 1:
        raise UnwrapError(f"{source}: [pattern] block_px must be an integer >= 1 (projector px per code step), "
                          f"got {block!r}")
    if not isinstance(inverse, bool):
        raise UnwrapError(f"{source}: [pattern] inverse must be true or false, got {inverse!r}")
    if W <= 0 or H <= 0:
        raise UnwrapError(f"{source}: [projector] size must be positive, got {size!r}")
    unknown = sorted(set(pattern) - {"kind", "block_px", "inverse"})
    if unknown:
        raise UnwrapError(f"{source}: [pattern] key(s) {unknown} do not apply to kind = \"graycode\" "
                          "(keys: block_px, inverse)")
    return {"block_px": block, "inverse": inverse, "size": (W, H),
            "bits": {"v": gray_bits(W, block), "h": gray_bits(H, block)}}


def _one(frames_dir: Path, stem: str):
    hits = sorted(frames_dir.glob(f"{stem}.*"))
    return hits[0] if hits else None


def design_gray_orientations(frames_dir: Path, spec: dict) -> dict:
    """``{orientation: {"width", "gray", "white", "black"}}`` of a DESIGN.md Gray-code pose folder
    (module docstring); an orientation with no frames is left out, a partial one refused."""
    frames_dir = Path(frames_dir)
    white, black = _one(frames_dir, "white"), _one(frames_dir, "black")
    if not spec["inverse"] and (white is None or black is None):
        raise UnwrapError(f"{frames_dir}: [pattern] inverse = false thresholds the bits at (white + black) / 2: "
                          f"white.png and black.png are needed, found {[p.name for p in (white, black) if p]}")
    out = {}
    for o, width in (("v", spec["size"][0]), ("h", spec["size"][1])):
        n = spec["bits"][o]
        stems = [gray_frame_stem(o, b, inv) for inv in ((False, True) if spec["inverse"] else (False,))
                 for b in range(n)]
        found = {s: _one(frames_dir, s) for s in stems}
        missing = [s for s, p in found.items() if p is None]
        if len(missing) == len(stems):
            continue
        if missing:
            raise UnwrapError(f"{frames_dir}: orientation {o}: {n} Gray-code bits for {width} px in blocks of "
                              f"{spec['block_px']} px; missing {missing[:4]}{' ...' if len(missing) > 4 else ''}")
        extra = sorted(p.name for p in frames_dir.glob(f"{o}_gray_b*.*") if p.stem not in found)
        if extra:
            raise UnwrapError(f"{frames_dir}: frame(s) {extra[:4]} are not among the {n} bits of a {width} px "
                              f"pattern in blocks of {spec['block_px']} px: wrong [projector] size or block_px?")
        files = [found[s] for s in stems]
        out[o] = {"width": float(width), "white": white, "black": black,
                  "gray": {"kind": "opencv", "files": files[:n], "inverse": files[n:] or None,
                           "block_px": spec["block_px"], "n_bits": n}}
    if not out:
        raise UnwrapError(f"{frames_dir}: no Gray-code frames named like {gray_frame_stem('v', 0)}.png")
    return out


def procam_orientations(frames_dir: Path, spec: dict) -> dict:
    """``{orientation: {...}}`` of a procam-calibration pose folder (``graycode_NN.png`` in OpenCV's
    order, module docstring)."""
    frames_dir = Path(frames_dir)
    nv, nh = spec["bits"]["v"], spec["bits"]["h"]
    expected = 2 * (nv + nh) + 2
    files = sorted(frames_dir.glob("graycode_*.*"))
    if len(files) != expected:
        raise UnwrapError(f"{frames_dir}: procam-graycode layout for a {spec['size'][0]}x{spec['size'][1]} "
                          f"projector in blocks of {spec['block_px']} px needs {expected} frames graycode_00.. "
                          f"({nv} column + {nh} row bits with inverses, white, black); found {len(files)}")
    by_index = {}
    for p in files:
        try:
            by_index[int(p.stem.split("_")[-1])] = p
        except ValueError:
            raise UnwrapError(f"{frames_dir}: {p.name} is not numbered like graycode_NN") from None
    if sorted(by_index) != list(range(expected)):
        raise UnwrapError(f"{frames_dir}: frames must be numbered graycode_00 .. graycode_{expected - 1:02d}")
    seq = [by_index[i] for i in range(expected)]
    out = {}
    for o, width, first, n in (("v", spec["size"][0], 0, nv), ("h", spec["size"][1], 2 * nv, nh)):
        pairs = seq[first:first + 2 * n]
        out[o] = {"width": float(width), "white": seq[-2], "black": seq[-1],
                  "gray": {"kind": "opencv", "files": pairs[0::2], "inverse": pairs[1::2],
                           "block_px": spec["block_px"], "n_bits": n}}
    return out
