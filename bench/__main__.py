"""Every benchmark, in its quick mode: ``python -m bench`` (``make bench``).

Each benchmark prints its own Markdown tables; run one alone, in full, with
``python -m bench.NAME`` (see its docstring). Quick modes cut repetitions and cases, so their
numbers are for checking that the benchmarks run, not for quoting.
"""
from __future__ import annotations

import sys
import time

from . import (ba_scale, beat_wrap, calib_accuracy, calib_captures, calib_speed, cycles_testset, decision_error_fit,
               defocus_bias, deploy_speed, detect_accuracy, export_speed, export_thin_lens, finetune_real, frame_jitter,
               gi_bias,
               global_bias, learned_deploy, learned_gpu, learned_speed, lens_gi_bias, lens_indirect, outlier_rule,
               prefetch_gray, retrain_compare, skull_parity, spatial_edge_odds, spatial_unwrap, synth_speed, unwrap_speed)

#: (name, main(argv) of the benchmark, arguments of its quick mode)
BENCHMARKS = [
    ("unwrap_speed", unwrap_speed.main, ["--quick"]),
    ("synth_speed", synth_speed.main, ["--quick"]),
    ("decision_error_fit", decision_error_fit.main, ["--quick"]),
    ("gi_bias", gi_bias.main, ["--quick", "-q"]),
    ("defocus_bias", defocus_bias.main, ["--quick", "-q"]),
    ("lens_gi_bias", lens_gi_bias.main, ["--quick", "-q"]),
    ("detect_accuracy", detect_accuracy.main, ["--quick", "--setup", "0"]),
    ("calib_accuracy", calib_accuracy.main, ["--quick"]),
    ("ba_scale", ba_scale.main, ["--quick"]),
    ("calib_captures", calib_captures.main, ["--quick"]),
    ("outlier_rule", outlier_rule.main, ["--quick"]),
    ("export_speed", export_speed.main, ["--quick"]),
    ("export_thin_lens", export_thin_lens.main, ["--quick"]),
    ("lens_indirect", lens_indirect.main, ["--quick"]),
    ("learned_speed", learned_speed.main, ["--quick"]),
    ("spatial_unwrap", spatial_unwrap.main, ["--quick"]),
    ("spatial_edge_odds", spatial_edge_odds.main, ["--quick", "-q"]),
    ("global_bias", global_bias.main, ["--quick"]),
    ("deploy_speed", deploy_speed.main, ["--quick"]),
    ("calib_speed", calib_speed.main, ["--quick"]),
    ("learned_deploy", learned_deploy.main, ["--quick"]),
    ("finetune_real", finetune_real.main, ["--quick"]),
    ("retrain_compare", retrain_compare.main, ["--quick"]),
    ("cycles_testset", cycles_testset.main, ["--quick"]),
    ("beat_wrap", beat_wrap.main, ["--quick", "-q"]),
    ("learned_gpu", learned_gpu.main, ["--quick", "--skip", "onnx"]),
    ("skull_parity", skull_parity.main, ["--quick"]),
    ("prefetch_gray", prefetch_gray.main, ["--quick"]),
    ("frame_jitter", frame_jitter.main, ["--quick", "--no-correction", "-q"]),
]


def main(argv=None) -> int:
    names = argv if argv is not None else sys.argv[1:]
    unknown = [n for n in names if n not in dict((b[0], b) for b in BENCHMARKS)]
    if unknown:
        print(f"unknown benchmark(s) {unknown}; known: {[b[0] for b in BENCHMARKS]}", file=sys.stderr)
        return 2
    for name, run, args in BENCHMARKS:
        if names and name not in names:
            continue
        t0 = time.perf_counter()
        print(f"\n# bench.{name} {' '.join(args)}\n", flush=True)
        rc = run(args) or 0
        print(f"\n(bench.{name}: {time.perf_counter() - t0:.0f} s)", flush=True)
        if rc:
            return rc
    return 0


if __name__ == "__main__":
    sys.exit(main())
