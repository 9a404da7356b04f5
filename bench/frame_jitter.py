"""Per-frame intensity fluctuation of the real captures, and the estimator's bound on the twin:
``python -m bench.frame_jitter [--quick] [--no-correction] [-q]``.

Rows, one per fringe set of every real capture in ../shared/data with >= 4 steps (the pyramid,
vertical / horizontal at f = 1, 4, 16; slmaster, f = 32): the identification used for the first
harmonic (unwrap.frame_jitter: the spatial low-pass at a high frequency, the 1 -> 4 -> 16 ladder's
phase as a reference at f = 1 and 4), the per-frame offsets o_n (% of the background, mean 0)
and gains g_n - 1 (%), the fluctuation's RMS sigma, the first harmonic |z_o| (the part that biases
the phase), and the phase bias predicted on the capture's own pixels (those the ladder trusts; B
>= 5 grey elsewhere): RMS / p99 from the identified part (0 where the first harmonic is not
identified) and the RMS expected from sigma alone. 3-step captures (kamino, the SLStudio skull):
per-frame fluctuation is not identifiable (N = 3); the ratio of the sets' mean backgrounds (over
pixels valid in every set) is printed instead.

The pyramid's MF 1 -> 16 decision against its own ladder reference, raw and with the frames
corrected (gains and the identified first harmonic; at f = 1 and 4 estimated on one half of the
image and scored on the other, so the ladder that scores is not the one that estimated).

Peer / bound in the same run: the twin (the default system, a wall, 8 steps at f = 16, noise at
10000 e-) rendered with synth.effects.frame_jitter at the pyramid's measured level (its vertical
f = 16 set's sigma and gain RMS; 3 % / 1 % without the capture) and without:
the estimator must recover what was put in (RMS error of the offsets / gains) and read about 0
without it. ``--quick``: the pyramid's vertical orientation and the twin only.
"""
from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
#: (offset std, gain std) measured on the pyramid's vertical f = 16 set (fractions), set by _pyramid
MEASURED = None
SHARED = ROOT.parent / "shared" / "data"


def _pct(x):
    return " ".join(f"{100 * v:+.2f}" for v in np.asarray(x).reshape(-1))


def _bias_stats(j, A, B, phi, pix):
    from unwrap.frame_jitter import expected_bias_rms, predicted_bias

    b = predicted_bias(A[pix], B[pix], phi[pix], j)
    return float(np.sqrt(np.mean(b ** 2))), float(np.percentile(np.abs(b), 99)), expected_bias_rms(B[pix], j)


def _row(name, f, j, bias):
    from unwrap.frame_jitter import FrameJitter

    if not isinstance(j, FrameJitter):
        return f"| {name} | {f:g} | {j} |" + " |" * 7
    z = "n/a" if j.first_harmonic is None else f"{100 * abs(j.first_harmonic) / j.background:.2f}"
    return (f"| {name} | {f:g} | {j.shifts.size} | {j.pixels} | {j.how} | {_pct(j.offsets_rel)} | "
            f"{_pct(j.gains - 1)} | {100 * j.sigma_rel:.2f} | {z} | {bias[0]:.4f} / {bias[1]:.4f} | {bias[2]:.4f} |")


HEADER = ("| capture | f | N | pixels | first harmonic | offsets o_n (% of A) | gains g_n - 1 (%) | sigma (%) | "
          "abs(z_o) (%) | bias RMS / p99 (rad) | expected RMS (rad) |\n|---|---|---|---|---|---|---|---|---|---|---|")


def _pyramid(orientations, correction, log):
    from bench.spatial_unwrap import PYRAMID, PYRAMID_ORIENTATIONS, PYRAMID_SHIFTS, pyramid_stacks
    from unwrap.frame_jitter import FrameJitterError, correct_frames, estimate_frame_jitter
    from unwrap.ladder_reference import ladder_reference
    from unwrap.phase_shift import wrapped_phase
    from unwrap.temporal import mf_unwrap

    if not PYRAMID.is_dir():
        return [], []
    rows, mf = [], []
    global MEASURED
    shifts = PYRAMID_SHIFTS
    for o, name, width in PYRAMID_ORIENTATIONS:
        if o not in orientations:
            continue
        st = {f: a.astype(np.float64) for f, a in pyramid_stacks(name).items()}
        ws = {f: wrapped_phase(st[f], shifts, min_modulation=0.02 * 255, saturation=250) for f in st}
        ref = ladder_reference([ws[f].phase for f in (1, 4, 16)], (1, 4, 16), [ws[f].B / 255 for f in (1, 4, 16)],
                               width=width)
        log(f"pyramid {o}: ladder trusts {int(ref.trusted.sum())} px")
        H, W = ref.trusted.shape
        left = np.zeros((H, W), bool)
        left[:, : W // 2] = True
        est = {}
        for f in (1, 4, 16):
            rp = ref.per_period * f if f < 16 else None
            try:
                j = estimate_frame_jitter(st[f], shifts, saturation=250, reference_phase=rp)
            except FrameJitterError as e:
                rows.append(_row(f"pyramid {o}", f, f"refused: {e}", None))
                continue
            w = ws[f]
            pix = ref.trusted
            if f == 16 and MEASURED is None:          # the twin's level: the first f = 16 set's
                MEASURED = (j.sigma_rel, float(np.sqrt(np.mean((j.gains - 1) ** 2))))
            rows.append(_row(f"pyramid {o}", f, j, _bias_stats(j, w.A, w.B, np.nan_to_num(w.phase), pix)))
            if correction:
                est[f] = (j if f == 16 else
                          [estimate_frame_jitter(st[f], shifts, saturation=250, reference_phase=rp, valid=half)
                           for half in (left, ~left)])
        if not correction or len(est) < 3:
            continue
        # MF 1 -> 16 against the ladder: raw, and corrected with estimates from the other half
        def wrong(ph1, ph16, where):
            r = mf_unwrap([np.nan_to_num(ph1), np.nan_to_num(ph16)], (1, 16), width=width, valid=where)
            return int((where & (np.asarray(r.order) != ref.order)).sum())

        pix = ref.trusted
        n = int(pix.sum())
        raw = wrong(ws[1].phase, ws[16].phase, pix)
        ph16 = wrapped_phase(correct_frames(st[16], est[16]), shifts, saturation=None).phase
        corr, corr_g = 0, 0
        for k, half in enumerate((~left, left)):     # estimated on the other half
            ph1 = wrapped_phase(correct_frames(st[1], est[1][k]), shifts, saturation=None).phase
            corr += wrong(ph1, ph16, pix & half)
            # gains only (the first harmonic left in)
            g_only = [dataclasses.replace(e, offsets=e.offsets * 0) for e in (est[1][k], est[16])]
            ph1g = wrapped_phase(correct_frames(st[1], g_only[0]), shifts, saturation=None).phase
            ph16g = wrapped_phase(correct_frames(st[16], g_only[1]), shifts, saturation=None).phase
            corr_g += wrong(ph1g, ph16g, pix & half)
        mf.append(f"| pyramid {o} | {n} | {100 * raw / n:.2f} % | {100 * corr_g / n:.2f} % | {100 * corr / n:.2f} % |")
    return rows, mf


def _slmaster(log):
    from unwrap.capture import load_capture, read_stack
    from unwrap.frame_jitter import FrameJitterError, estimate_frame_jitter
    from unwrap.phase_shift import wrapped_phase

    folder = SHARED / "slmaster-monocular-12step-cgc" / "L"
    if not folder.is_dir():
        return []
    rows = []
    cap = load_capture(folder)
    for o, oc in cap.orientations.items():
        for s in oc.sets:
            I = read_stack(s.files).astype(np.float64)
            I = I.mean(-1) if I.ndim == 4 else I
            try:
                j = estimate_frame_jitter(I, s.shifts, saturation=250)
            except FrameJitterError as e:
                rows.append(_row(f"slmaster {o}", s.frequency, f"refused: {e}", None))
                continue
            w = wrapped_phase(I, s.shifts, min_modulation=5, saturation=250)
            bias = _bias_stats(j, w.A, w.B, np.nan_to_num(w.phase), w.valid)
            rows.append(_row(f"slmaster {o}", s.frequency, j, bias))
    log("slmaster done")
    return rows


def _three_step():
    """3-step captures: per-set median background ratios (per frame: not identifiable)."""
    from unwrap.capture import load_capture, read_stack
    from unwrap.phase_shift import wrapped_phase

    out = []
    for label, folder in (("kamino", SHARED / "kamino-phaseshift-graycode-object"),
                          ("slstudio skull", SHARED / "slstudio-ps2x3-calib" / "skull_2x3")):
        if not folder.is_dir():
            continue
        cap = load_capture(folder)
        for o, oc in cap.orientations.items():
            ws = []
            for s in oc.sets:
                I = read_stack(s.files).astype(np.float64)
                ws.append((s.frequency, wrapped_phase(I.mean(-1) if I.ndim == 4 else I, s.shifts, min_modulation=5,
                                                      saturation=250)))
            both = np.all([w.valid for _, w in ws], 0)
            if both.sum() < 1000 or len(ws) < 2:
                out.append(f"| {label} {o} | N = 3: per-frame not identifiable; too few pixels for a set ratio | |")
                continue
            r = [np.mean(w.A[both]) for _, w in ws]
            ratio = " / ".join(f"f = {f:g}: {v / r[0]:.4f}" for (f, _), v in zip(ws, r))
            out.append(f"| {label} {o} | N = 3: per-frame not identifiable | mean A relative to the first set: "
                       f"{ratio} ({int(both.sum())} px) |")
    return out


def _twin(offset, gain, log):
    """Estimator on the twin with the effect at (offset, gain) and off: rows of the bound."""
    import torch

    from calib import default_system
    from synth import Plane, Scene, phase_sequence, render
    from synth.effects.frame_jitter import background, frame_factors
    from synth.effects.spec import Effects, FrameJitter, Noise
    from unwrap.frame_jitter import estimate_frame_jitter
    from unwrap.phase_shift import equal_shifts

    seq = phase_sequence(("v",), (16,), 8)
    rows = []
    for label, fj in (("on", FrameJitter(offset, gain, seed=7)), ("off", None)):
        eff = Effects(noise=Noise(10000.0, 5.0, seed=3), frame_jitter=fj)
        res = render(Scene(default_system(), [Plane("wall", np.eye(3), [0, 0, 0])], seq, eff), keep_linear=True)
        I = res.images.numpy().astype(np.float64)
        j = estimate_frame_jitter(I, equal_shifts(8), saturation=250)
        if fj is not None:
            o, g = frame_factors(fj, 8)
            lin = res.linear if res.linear is not None else None
            ref = background(torch.as_tensor(lin)) * 255 if lin is not None else j.background
            o_true = o * ref
            o_true = o_true - o_true.mean()
            g_true = g / g.mean()
        else:
            o_true, g_true = np.zeros(8), np.ones(8)
        err_o = float(np.sqrt(np.mean((j.offsets - o_true) ** 2)) / j.background)
        err_g = float(np.sqrt(np.mean((j.gains - g_true) ** 2)))
        rows.append(f"| twin {label} | {100 * offset if fj else 0:.2f} / {100 * gain if fj else 0:.2f} | "
                    f"{_pct(o_true / j.background)} | {_pct(j.offsets_rel)} | {100 * err_o:.3f} | "
                    f"{_pct(g_true - 1)} | {_pct(j.gains - 1)} | {100 * err_g:.3f} | {j.how} |")
        log(f"twin {label} done")
    return rows


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.frame_jitter", description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="the pyramid's vertical orientation and the twin only")
    ap.add_argument("--no-correction", action="store_true", help="skip the MF correction experiment")
    ap.add_argument("-q", "--quiet", action="store_true")
    a = ap.parse_args(argv)

    def log(msg):
        if not a.quiet:
            print(msg, file=sys.stderr, flush=True)

    rows, mf = _pyramid(("v",) if a.quick else ("v", "h"), not a.no_correction, log)
    if not a.quick:
        rows += _slmaster(log)
    print("## Per-frame fluctuation of the real captures (unwrap.frame_jitter)\n")
    print(HEADER)
    print("\n".join(rows) if rows else "| (no real capture in ../shared/data) |")
    if not a.quick:
        print("\n## 3-step captures\n\n| capture | per frame | per set |\n|---|---|---|")
        print("\n".join(_three_step()))
    if mf:
        print("\n## Pyramid MF 1 -> 16 against its 1 -> 4 -> 16 ladder (wrong, % of trusted pixels)\n")
        print("| orientation | trusted px | raw | gains corrected | gains + first harmonic corrected |")
        print("|---|---|---|---|---|")
        print("\n".join(mf))
    # the twin at the measured level: the pyramid's vertical f = 16 set (else 3 % / 1 %)
    offset, gain = MEASURED or (0.03, 0.01)
    print("\n## Bound: the estimator on the twin (wall, f = 16, 8 steps, noise 10000 e-)\n")
    print("| twin | effect offset / gain std (%) | true o_n (% of A) | estimated | RMS error (% of A) | "
          "true g_n - 1 (%) | estimated | RMS error (%) | first harmonic |\n|---|---|---|---|---|---|---|---|---|")
    print("\n".join(_twin(offset, gain, log)))
    return 0


if __name__ == "__main__":
    sys.exit(main())
