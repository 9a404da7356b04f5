"""A synthetic fringe capture in the DESIGN.md layout, for timing ``calib unwrap`` (bench.deploy_speed)
and for the learned-inference tests: a tilted plane with a spherical bump and a shadow, 8-bit
frames with sensor noise, vertical and horizontal fringes at 1, 8 and 48 periods, 12 steps.

    python -m bench.fringe_capture OUT [--size 900 700] [--seed 0]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

TOML = """[pattern]
steps = [{steps}, {steps}, {steps}]
frequencies = [1, 8, 48]

[camera]
size = [{W}, {H}]

[projector]
size = [912, 1140]
"""


def write_capture(root, size=(900, 700), seed: int = 0, steps: int = 12, noise_grey: float = 2.0) -> Path:
    """Write the capture into ``root`` (created) and return it. ``size``: camera (W, H) px."""
    import cv2

    from unwrap.patterns import absolute_phase, fringe_intensity

    W, H = (int(s) for s in size)
    root = Path(root)
    pose = root / "pose_00"
    pose.mkdir(parents=True, exist_ok=True)
    (root / "capture.toml").write_text(TOML.format(steps=steps, W=W, H=H))
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:H, 0:W].astype(np.float64)
    r2 = ((x - 0.55 * W) ** 2 + (y - 0.45 * H) ** 2) / (0.25 * min(W, H)) ** 2
    bump = np.where(r2 < 1, np.sqrt(np.clip(1 - r2, 0, 1)), 0.0)             # a sphere's cap: depth
    shadow = (x > 0.55 * W + 0.25 * min(W, H)) & (x < 0.55 * W + 0.32 * min(W, H)) & (np.abs(y - 0.45 * H) < 0.2 * H)
    albedo = np.where(shadow, 0.03, 0.75 + 0.2 * np.sin(x / 37.0) * np.cos(y / 53.0))
    coords = {"v": (20.0 + 870.0 * x / W + 0.05 * y + 25.0 * bump, 912),
              "h": (30.0 + 1080.0 * y / H + 0.04 * x - 30.0 * bump, 1140)}
    for o, (c, extent) in coords.items():
        for f in (1, 8, 48):
            for n in range(steps):
                I = 255 * albedo * fringe_intensity(absolute_phase(c, f, extent), n, steps, 0.5, 0.4)
                I = np.clip(np.rint(I + rng.normal(0, noise_grey, I.shape)), 0, 255).astype(np.uint8)
                cv2.imwrite(str(pose / f"{o}_f{f:03d}_n{n:02d}.png"), I)
    return root


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("output")
    p.add_argument("--size", type=int, nargs=2, default=(900, 700), metavar=("W", "H"))
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args(argv)
    print(write_capture(a.output, a.size, a.seed))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
