"""The speed benchmarks' stage tables (bench.deploy_speed, bench.calib_speed) report the wall time
and the stage profile of the same run, the fastest: a row never pairs one run's wall with
another run's stages."""
import json
from argparse import Namespace
from pathlib import Path

import bench.deploy_speed as D


def _fake_runs(monkeypatch, walls):
    """run_cli stand-in: run i takes walls[i % len] s and writes a calibration.json whose solve
    and stage times are those of run i."""
    calls = []

    def run_cli(args, root, repeats):          # as the real one: min wall over repeats, files of the last
        out = Path(args[args.index("-o") + 1])
        out.mkdir(parents=True, exist_ok=True)
        for _ in range(repeats):
            w = walls[len(calls) % len(walls)]
            calls.append(w)
            (out / "calibration.json").write_text(json.dumps({
                "timings_s": {"solve_s": w / 4}, "run": {"stages_s": {"solve": w / 2, "read": w / 8}}}))
        return {"wall_s": min(calls[-repeats:]), "peak_mb": 100.0 + max(calls[-repeats:]), "error": None}

    monkeypatch.setattr(D, "run_cli", run_cli)
    return calls


def test_every_command_row_takes_wall_and_stages_from_its_fastest_run(monkeypatch, tmp_path):
    walls = [3.0, 1.0, 2.0]           # the fastest run is not the last
    calls = _fake_runs(monkeypatch, walls)
    args = Namespace(views=5, size=(64, 48), repeats=3)
    rows = D.cli_rows(args, [("after", D.ROOT)], tmp_path, tmp_path / "obs.json", tmp_path / "cap", tmp_path / "m.onnx")
    assert len(rows) >= 4 and len(calls) == 3 * len(rows)
    for name, wall, peak, solve, err, stages in rows:
        assert (wall, solve, stages) == (1.0, 0.25, {"solve": 0.5, "read": 0.125}), name
        assert peak == 103.0 and err is None      # the largest peak of the row's runs


def test_calib_speed_measures_through_the_same_function(monkeypatch, tmp_path):
    from bench import calib_speed

    _fake_runs(monkeypatch, [2.0, 0.5, 4.0])
    assert calib_speed.measure is D.measure
    r = D.measure(["run"], D.ROOT, tmp_path / "out", 3)
    assert r["walls"] == [2.0, 0.5, 4.0] and r["stages"] == {"solve": 0.25, "read": 0.0625} and r["solve_s"] == 0.125


def test_timed_commands_run_with_pythons_default_bytecode_cache(monkeypatch, tmp_path):
    monkeypatch.setenv("PYTHONDONTWRITEBYTECODE", "1")
    env = D.command_env(tmp_path)
    assert "PYTHONDONTWRITEBYTECODE" not in env and env["PYTHONPATH"] == str(tmp_path)
    assert "dropped" in D.bytecode_note()
    monkeypatch.delenv("PYTHONDONTWRITEBYTECODE")
    assert "dropped" not in D.bytecode_note()
