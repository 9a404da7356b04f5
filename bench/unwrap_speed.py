"""Speed of wrapped phase + temporal unwrapping against the memory-bandwidth floor, and what accuracy costs.

Run: ``python -m bench.unwrap_speed`` (add ``--quick`` for fewer repetitions).

Part 1: one orientation of the paper's set (3 frequencies x 12 steps, 640 x 480, uint8): time of
the fused kernel (``unwrap.fused_mf.mf_unwrap_stacks``: one pass, numba, all threads) and of the
readable reference (``wrapped_phase`` on each frequency + ``mf_unwrap``), in ms and GB/s of image
data read, against plain numpy passes over the same bytes measured in the same run (``sum``: the
step-axis sum into uint16, a read-only pass that touches every frame pixel once, the floor the
target refers to; ``copy``: read + write every byte). Every timing is the minimum over
``rounds x repeat`` calls, the rounds interleaving floor and kernels so that both see the same
machine load (the machine may be shared). The JIT cost (first call in the process: compile, or
load from numba's on-disk cache) is reported separately, and the agreement with the reference.

Part 2: each method at N = 3, 4, 6, 12 steps on 8-bit frames with Gaussian noise (stated in the
table header): phase error RMS (rad, pixels with the right k), k error rate, and time.

Precision: the least-squares sums run in float64 (reference: ``accumulate="float64"``, default;
the kernel: exact integer sums of frames sharing a weight, then float64); phase, A, B and
unwrapping are float64 throughout.
"""
from __future__ import annotations

import argparse
import math
import os
import time

import numpy as np

from unwrap import (complementary_gray_unwrap, mf_unwrap, mw_unwrap, nt_unwrap, wrapped_phase)
from unwrap.fused_mf import fast_available, mf_unwrap_stacks
from unwrap.patterns import absolute_phase, fringe_intensity

H, W = 480, 640
W_P = 912


def _best_ms(fn, repeat, before=None):
    """Minimum wall time (ms) of ``repeat`` calls; ``before`` runs untimed before each call."""
    times = []
    for _ in range(repeat):
        if before is not None:
            before()
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


def _set_threads(n):
    import numba
    numba.set_num_threads(n)


def _compile_from_scratch_s():
    """Seconds to compile the kernel in a fresh process with an empty numba cache (or None)."""
    import subprocess
    import sys
    import tempfile
    code = ("import time, numpy as np; from unwrap.fused_mf import mf_unwrap_stacks; "
            "s = [np.zeros((12, 8, 8), np.uint8) for _ in range(3)]; t = time.perf_counter(); "
            "mf_unwrap_stacks(s, (1, 8, 48), width=912, fast=True); "
            "print(time.perf_counter() - t)")
    with tempfile.TemporaryDirectory() as cache:
        env = dict(os.environ, NUMBA_CACHE_DIR=cache)
        r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True,
                           cwd=os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    try:
        return float(r.stdout.strip().splitlines()[-1])
    except (ValueError, IndexError):
        return None


def _table(title, cases, best, nbytes, floor_names):
    print(title)
    heads = " | ".join(f"x {n}" for n in floor_names)
    print(f"| step | ms | GB/s of frames | {heads} |")
    print("|---|---:|---:|" + "---:|" * len(floor_names))
    for name in cases:
        t = best[name]
        ratios = " | ".join(f"{t / best[f]:.2f}" for f in floor_names.values())
        print(f"| {name} | {t:.2f} | {nbytes / t / 1e6:.2f} | {ratios} |")


SUM = "floor: numpy step-axis sum into uint16 (the target's floor)"
MAX = "floor: numpy step-axis max (uint8)"
FLAT = "floor: numpy sum of the bytes viewed as uint64 (fastest read)"
COPY = "floor: numpy copy of the frames (read + write)"


def _part1_cases(stacks, freqs, repeat, threads, fast):
    """(name, callable, repetitions) of part 1: the numpy floors, the fused kernel (when numba
    is there) and the reference; and the reference itself (a callable)."""
    def reference(acc="float64"):
        phases = [wrapped_phase(s, accumulate=acc).phase for s in stacks]
        return mf_unwrap(phases, freqs, width=W_P)

    phases = [wrapped_phase(s).phase for s in stacks]
    held = {}

    def fused_reuse():
        held["r"] = mf_unwrap_stacks(stacks, freqs, width=W_P, fast=True, out=held.get("r"))

    def fused_one_thread():
        _set_threads(1)
        try:
            mf_unwrap_stacks(stacks, freqs, width=W_P, fast=True)
        finally:
            _set_threads(threads)

    short = repeat if repeat < 3 else max(1, repeat // 3)
    cases = [
        (SUM, lambda: [s.sum(axis=0, dtype=np.uint16) for s in stacks], repeat),
        (MAX, lambda: [s.max(axis=0) for s in stacks], repeat),
        (FLAT, lambda: [s.reshape(-1).view(np.uint64).sum() for s in stacks], repeat),
        (COPY, lambda: [s.copy() for s in stacks], repeat),
    ]
    if fast:
        cases += [
            (_fused_name(threads), lambda: mf_unwrap_stacks(stacks, freqs, width=W_P, fast=True), 3 * repeat),
            (f"fused kernel, {threads} threads, outputs reused (out=)", fused_reuse, 3 * repeat),
            ("fused kernel, 1 thread, fresh outputs", fused_one_thread, repeat),
        ]
    cases += [
        ("reference: wrapped_phase x3 + mf_unwrap (float64 sums)", reference, short),
        ("reference: same, float32 sums", lambda: reference("float32"), short),
        ("  of which wrapped_phase x3", lambda: [wrapped_phase(s) for s in stacks], short),
        ("  of which mf_unwrap (1, 8, 48)", lambda: mf_unwrap(phases, freqs, width=W_P), short),
    ]
    return cases, reference


def _fused_name(threads):
    return f"**fused kernel, {threads} threads, fresh outputs**"


def _agreement(stacks, freqs, reference, jit_s, scratch_compile):
    """Print the JIT cost and the fused kernel's agreement with the reference."""
    print(f"\nJIT: first call in this process {jit_s:.2f} s (loading numba's on-disk cache, or "
          "compiling when no earlier run did; not in the times above).")
    if scratch_compile:
        c = _compile_from_scratch_s()
        print(f"JIT from scratch (fresh process, empty cache): "
              f"{'failed' if c is None else f'{c:.1f} s'}.")
    ref = reference()
    r = mf_unwrap_stacks(stacks, freqs, width=W_P, fast=True).result
    same_valid = bool(np.array_equal(r.valid, ref.valid))
    dphi = float(np.nanmax(np.abs(r.phase - ref.phase)))
    ties = int(np.sum(r.order != ref.order))
    print(f"Agreement with the reference: valid identical: {same_valid}; max |phase "
          f"difference| {dphi:.1e} rad; k differs at {ties} of {r.order.size} pixels (only "
          "possible at ties on the wrapped phase's +-pi cut; see docs/unwrap.md).")


def part1(repeat, rounds, scratch_compile=False):
    rng = np.random.default_rng(0)
    freqs = (1, 8, 48)
    stacks = _stacks(freqs, 12, 2.0, rng, B=90.0)
    nbytes = sum(s.nbytes for s in stacks)
    threads = 1
    jit_s = None
    fast = fast_available()
    if fast:
        import numba
        threads = numba.config.NUMBA_NUM_THREADS
        t = time.perf_counter()
        mf_unwrap_stacks(stacks, freqs, width=W_P, fast=True)  # compile or load the cache
        jit_s = time.perf_counter() - t
    cases, reference = _part1_cases(stacks, freqs, repeat, threads, fast)
    # cold: reading 64 MB (twice the 32 MB L3 of the benchmark machine) evicts the frames first
    evict = np.ones((64 << 20) // 8, np.uint64)
    flush = lambda: evict.sum()  # noqa: E731
    cold_names = [SUM, MAX, COPY] + ([_fused_name(threads)] if fast else []) + [cases[-4][0]]
    best = {name: math.inf for name, _, _ in cases}
    cold = {name: math.inf for name in cold_names}
    for _ in range(rounds):
        for name, fn, rep in cases:
            best[name] = min(best[name], _best_ms(fn, rep))
            if name in cold:
                cold[name] = min(cold[name], _best_ms(fn, max(1, rep // 3), before=flush))
    head = (f"3 x 12 frames, {W}x{H} uint8 ({nbytes / 1e6:.1f} MB), {os.cpu_count()} cores, "
            f"minimum of {rounds} interleaved rounds (the machine was shared)")
    _table(f"\n## Wrapped phase + MF, one orientation, frames in cache (warm): {head}\n",
           [n for n, _, _ in cases], best, nbytes, {"sum floor": SUM, "max floor": MAX})
    _table(f"\n## The same with the last-level cache flushed before each call (cold: frames "
           f"come from DRAM)\n", cold_names, cold, nbytes, {"sum floor": SUM, "max floor": MAX})
    if fast:
        _agreement(stacks, freqs, reference, jit_s, scratch_compile)
    return best, cold


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
    methods = [("mf", (1, 8, 48), False), ("mf", (1, 8, 48), True), ("mf", (1, 4, 16, 64), False),
               ("mf", (1, 4, 16, 64), True), ("mw", (70, 64, 59), False), ("nt", (47, 48), False),
               ("cgray", (48,), False)]
    if not fast_available():
        methods = [m for m in methods if not m[2]]
    print(f"\n## Accuracy vs time, {W}x{H} uint8, A = 120, B = {B:g}, Gaussian noise sigma = "
          f"{sigma:g} grey levels per frame; camera sees projector columns 91-821 "
          f"(interior: no base-phase cut); Gray-code bits taken as correct\n")
    print("| method | frequencies | N | images | phase error RMS [rad] | k error rate | ms |")
    print("|---|---|---:|---:|---:|---:|---:|")
    u = _u_cam()
    for method, freqs, fused in methods:
        for N in (3, 4, 6, 12):
            # the same frames for a method with and without the fused kernel
            rng = np.random.default_rng([N, len(freqs)] + [int(round(f)) for f in freqs])
            stacks = _stacks(freqs, N, sigma, rng, B=B)

            def run():
                if fused:
                    return mf_unwrap_stacks(stacks, freqs, width=W_P, fast=True).result
                phis = [wrapped_phase(s).phase for s in stacks]
                return _unwrap(method, phis, freqs)

            r = run()  # also compiles / loads the kernel of a new ladder length
            t = _best_ms(run, repeat)
            f_hi = max(freqs)
            Phi = absolute_phase(u, f_hi, W_P)
            err = r.phase - Phi
            wrong = ~r.valid | (np.abs(err) > math.pi)
            rms = float(np.sqrt(np.mean(err[~wrong] ** 2)))
            images = N * len(freqs) if method != "cgray" else N + int(math.log2(f_hi)) + 2
            name = method + (" fused" if fused else "")
            print(f"| {name} | {','.join(str(v) for v in freqs)} | {N} | {images} | {rms:.4f} | "
                  f"{np.mean(wrong):.2e} | {t:.1f} |")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer repetitions")
    args = ap.parse_args(argv)
    repeat, rounds = (3, 2) if args.quick else (9, 5)
    part1(repeat, rounds, scratch_compile=not args.quick)
    part2(max(1, repeat // 3))


if __name__ == "__main__":
    main()
