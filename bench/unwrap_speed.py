"""Speed of wrapped phase + temporal unwrapping against the memory-bandwidth floor, and what accuracy costs.

Run: ``python -m bench.unwrap_speed`` (add ``--quick`` for fewer repetitions).

Part 1: one orientation of the paper's set (3 frequencies x 12 steps, 640 x 480, uint8): time of
``wrapped_phase`` on each frequency + ``mf_unwrap``, in ms and GB/s of image data read, against
plain numpy passes over the same bytes measured in the same run (``copy``: read + write every
byte; ``sum``: the step-axis sum in uint16, the cheapest pass that touches every frame pixel).

Part 2: each method at N = 3, 4, 6, 12 steps on 8-bit frames with Gaussian noise (stated in the
table header): phase error RMS (rad, pixels with the right k), k error rate, and time.

Precision: the least-squares sums run in float64 (``accumulate="float64"``, default; the
float32 option is measured too); phase, A, B and unwrapping are float64 throughout.
"""
from __future__ import annotations

import argparse
import math
import os
import time

import numpy as np

from unwrap import (complementary_gray_unwrap, mf_unwrap, mw_unwrap, nt_unwrap, wrapped_phase)
from unwrap.patterns import absolute_phase, fringe_intensity

H, W = 480, 640
W_P = 912


def _best_ms(fn, repeat):
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return 1e3 * min(times)


def _u_cam():
    return np.linspace(0.1 * W_P, 0.9 * W_P, W)[None, :].repeat(H, 0)  # projector columns 91..821


def _stacks(freqs, steps, sigma, rng, A=120.0, B=60.0):
    u = _u_cam()
    out = []
    for f in freqs:
        Phi = absolute_phase(u, f, W_P)
        st = np.stack([fringe_intensity(Phi, n, steps, A=A, B=B) for n in range(steps)])
        st += rng.normal(0.0, sigma, st.shape)
        out.append(np.clip(np.round(st), 0, 255).astype(np.uint8))
    return out


def part1(repeat):
    rng = np.random.default_rng(0)
    stacks = _stacks((1, 8, 48), 12, 2.0, rng, B=90.0)
    nbytes = sum(s.nbytes for s in stacks)
    rows = []
    t_copy = _best_ms(lambda: [s.copy() for s in stacks], repeat)
    t_sum = _best_ms(lambda: [s.sum(axis=0, dtype=np.uint16) for s in stacks], repeat)
    rows.append(("floor: numpy copy of the frames", t_copy))
    rows.append(("floor: numpy step-axis sum (uint16)", t_sum))

    def pipeline(acc):
        phases = [wrapped_phase(s, accumulate=acc).phase for s in stacks]
        return mf_unwrap(phases, (1, 8, 48), width=W_P)

    t64 = _best_ms(lambda: pipeline("float64"), repeat)
    t32 = _best_ms(lambda: pipeline("float32"), repeat)
    phases = [wrapped_phase(s).phase for s in stacks]
    t_wp = _best_ms(lambda: [wrapped_phase(s) for s in stacks], repeat)
    t_mf = _best_ms(lambda: mf_unwrap(phases, (1, 8, 48), width=W_P), repeat)
    t_atan = _best_ms(lambda: [np.arctan2(p, p) for p in phases], repeat)
    rows += [("wrapped phase x3 (float64 sums)", t_wp), ("mf_unwrap (1, 8, 48)", t_mf),
             ("  of which: np.arctan2 alone x3 (float64)", t_atan),
             ("wrapped phase + MF, float64 sums", t64), ("wrapped phase + MF, float32 sums", t32)]
    print(f"\n## Wrapped phase + MF, one orientation: 3 x 12 frames, {W}x{H} uint8 "
          f"({nbytes / 1e6:.1f} MB), {os.cpu_count()} cores\n")
    print("| step | ms | GB/s of frames | x copy floor | x sum floor |")
    print("|---|---:|---:|---:|---:|")
    for name, t in rows:
        print(f"| {name} | {t:.2f} | {nbytes / t / 1e6:.2f} | {t / t_copy:.1f} | {t / t_sum:.1f} |")
    return rows


def _unwrap(method, phis, freqs):
    if method == "mf":
        return mf_unwrap(phis, freqs, width=W_P, on_unreliable="ignore")
    if method == "mw":
        return mw_unwrap(phis, freqs, width=W_P, on_unreliable="ignore")
    if method == "nt":
        return nt_unwrap(phis, freqs, width=W_P, on_unreliable="ignore")
    u = _u_cam()
    f = freqs[0]
    K1 = np.floor(u * f / W_P)
    K2 = np.floor(u * f / W_P + 0.5)
    return complementary_gray_unwrap(phis[0], K1, K2, f)


def part2(repeat, sigma=4.0, B=40.0):
    methods = [("mf", (1, 8, 48)), ("mf", (1, 4, 16, 64)), ("mw", (70, 64, 59)),
               ("nt", (47, 48)), ("cgray", (48,))]
    print(f"\n## Accuracy vs time, {W}x{H} uint8, A = 120, B = {B:g}, Gaussian noise sigma = "
          f"{sigma:g} grey levels per frame; camera sees projector columns 91-821 "
          f"(interior: no base-phase cut); Gray-code bits taken as correct\n")
    print("| method | frequencies | N | images | phase error RMS [rad] | k error rate | ms |")
    print("|---|---|---:|---:|---:|---:|---:|")
    rng = np.random.default_rng(1)
    u = _u_cam()
    for method, freqs in methods:
        for N in (3, 4, 6, 12):
            stacks = _stacks(freqs, N, sigma, rng, B=B)

            def run():
                phis = [wrapped_phase(s).phase for s in stacks]
                return _unwrap(method, phis, freqs)

            t = _best_ms(run, repeat)
            r = run()
            f_hi = max(freqs)
            Phi = absolute_phase(u, f_hi, W_P)
            err = r.phase - Phi
            wrong = ~r.valid | (np.abs(err) > math.pi)
            rms = float(np.sqrt(np.mean(err[~wrong] ** 2)))
            images = N * len(freqs) if method != "cgray" else N + int(math.log2(f_hi)) + 2
            print(f"| {method} | {','.join(str(v) for v in freqs)} | {N} | {images} | {rms:.4f} | "
                  f"{np.mean(wrong):.2e} | {t:.1f} |")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repetitions")
    args = ap.parse_args(argv)
    repeat = 3 if args.quick else 9
    part1(repeat)
    part2(max(1, repeat // 3))


if __name__ == "__main__":
    main()
