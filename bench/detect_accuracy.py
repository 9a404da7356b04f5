"""Measured accuracy of the circle centres on rendered boards: ``python -m bench.detect_accuracy``.

For each setup (the paper's twin: 640x480 camera at ~850 mm; a closer camera; a board with
larger circles) and each tilt, the board is rendered by ``synth`` (white frame, analytic
anti-aliasing, the camera's distortion), detected with each centre estimator, with and without
the perspective-bias correction, and compared with the true projections of the circle centres
(``DeviceModel.project`` of the board points at the true pose). Prints a Markdown table (px) and
writes a figure of the errors (``--figure PATH``).
"""
from __future__ import annotations

import argparse
import sys
import time

import numpy as np

TILTS_DEG = [(0, 0), (10, 20), (-10, -20), (20, 0), (0, -20), (40, 0), (0, 40), (30, 30)]


def close_system(distance_mm: float = 400.0, f_px: float = 1000.0):
    """The paper's projector with a 640x480, f = ``f_px`` camera looking straight at the board
    from ``distance_mm`` (board frame = world; camera R = diag(1, -1, -1), image y down)."""
    from calib.device import DeviceModel
    from calib.system import SystemModel, default_system

    base = default_system()
    cam = DeviceModel(size=(640, 480), K=np.array([[f_px, 0, 319.5], [0, f_px, 239.5], [0, 0, 1.0]]),
                      R=np.diag([1.0, -1.0, -1.0]), t=np.array([0.0, 0.0, distance_mm]), kind="camera")
    return SystemModel(cam, base.projector, dict(base.meta))


def render_white(system, spec, tilt_deg, noise_seed=None):
    """(H, W) uint8 white frame of board ``spec`` (``synth.BoardTexture`` or ``calib.board.Board``) tilted by (rx, ry) degrees
    about the world origin, and the board -> world rotation."""
    from synth import Board, Effects, Noise, PatternSpec, Scene, render
    from synth.scenes.poses import rotation_xyz_deg

    R_wb = rotation_xyz_deg([tilt_deg[0], tilt_deg[1], tilt_deg[2] if len(tilt_deg) > 2 else 0.0])
    noise = None if noise_seed is None else Noise(seed=int(noise_seed))
    scene = Scene(system, [Board("board", R_wb, np.zeros(3), spec)], [PatternSpec("white", "white")],
                  Effects(noise=noise))
    return render(scene).images[0].numpy(), R_wb


def centre_errors(image, system, spec, R_wb, *, centre_method="moments", correct_bias=True):
    """(errors (N, 2) px detected - true, detection) for one rendered image of board ``spec``
    (``synth.BoardTexture`` or ``calib.board.Board``)."""
    from calib.detect.circles import detect_circles
    from calib.detect.result import image_as_float

    board = getattr(spec, "board", spec)
    det = detect_circles(image_as_float(image), board, centre_method=centre_method, correct_bias=correct_bias)
    true = system.camera.project(board.points_board(det.ids) @ R_wb.T)
    return det.q - true, det


def _stats(e):
    n = np.linalg.norm(e, axis=1)
    return float(np.sqrt(np.mean(n ** 2))), float(n.max())


def setups():
    from calib.board import paper_board
    from calib.system import default_system

    paper = paper_board()
    big = paper_board(small_diameter_mm=8.0, large_diameter_mm=14.0)
    return [("paper twin (f 2592 px, 850 mm), paper board", default_system(), paper),
            ("close (f 1000 px, 400 mm), paper board", close_system(), paper),
            ("close (f 1000 px, 400 mm), 8/14 mm circles", close_system(), big)]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--figure", help="PNG of the per-circle bias and errors")
    ap.add_argument("--setup", type=int, nargs="+", help="indices of the setups to run (default all)")
    ap.add_argument("--quick", action="store_true", help="three tilts only")
    args = ap.parse_args(argv)
    tilts = TILTS_DEG[:1] + TILTS_DEG[5:7] if args.quick else TILTS_DEG
    print("| setup | tilt (deg) | noise | circles | size px (min-max) | bias max px | "
          "moments raw RMS / max | moments corrected RMS / max | edge raw RMS / max | edge corrected RMS / max |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    fig_rows = []
    chosen = setups()
    if args.setup is not None:
        chosen = [chosen[i] for i in args.setup]
    for name, system, spec in chosen:
        for tilt in tilts:
            for noise in (None, 1):
                t0 = time.perf_counter()
                img, R_wb = render_white(system, spec, tilt, noise)
                cells = []
                for method in ("moments", "edge"):
                    for corr in (False, True):
                        e, det = centre_errors(img, system, spec, R_wb, centre_method=method, correct_bias=corr)
                        cells.append("%.4f / %.4f" % _stats(e))
                        if method == "moments" and corr:
                            e_raw, _ = centre_errors(img, system, spec, R_wb, centre_method=method, correct_bias=False)
                            fig_rows.append((name, tilt, noise, e_raw, e))
                            bias = np.linalg.norm(e_raw - e, axis=1).max()
                            size = det.feature_px
                print(f"| {name} | {tilt[0]:+d}, {tilt[1]:+d} | {'yes' if noise else 'no'} | {len(det)} | "
                      f"{size.min():.1f}-{size.max():.1f} | {bias:.4f} | " + " | ".join(cells) + " |", flush=True)
                print(f"  ({time.perf_counter() - t0:.1f} s)", file=sys.stderr)
    if args.figure:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        names = list(dict.fromkeys(r[0] for r in fig_rows))
        fig, axes = plt.subplots(1, len(names), figsize=(5 * len(names), 4.2), squeeze=False)
        for ax, nm in zip(axes[0], names):
            raw = [np.linalg.norm(r[3], axis=1) for r in fig_rows if r[0] == nm and r[2] is None]
            cor = [np.linalg.norm(r[4], axis=1) for r in fig_rows if r[0] == nm and r[2] is None]
            labels = [f"{r[1][0]},{r[1][1]}" for r in fig_rows if r[0] == nm and r[2] is None]
            x = np.arange(len(raw))
            ax.bar(x - 0.2, [np.sqrt(np.mean(v ** 2)) for v in raw], 0.4, label="ellipse centre (raw)")
            ax.bar(x + 0.2, [np.sqrt(np.mean(v ** 2)) for v in cor], 0.4, label="bias corrected")
            ax.set_xticks(x, labels, rotation=45)
            ax.set_title(nm, fontsize=8)
            ax.set_ylabel("centre RMS error (px), noise-free")
            ax.set_xlabel("tilt rx, ry (deg)")
            ax.legend(fontsize=7)
        fig.tight_layout()
        fig.savefig(args.figure, dpi=110)
        print(f"figure: {args.figure}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
