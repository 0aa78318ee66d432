"""Benchmark scripts that read finished runs: the point-mass check of a speed setting, the whole-loop table."""
import importlib
import json
import sys
from pathlib import Path

import pytest


@pytest.fixture()
def bench():
    return importlib.import_module("benchmarks.learning.setting_learning")


def _fake_run(folder: Path, successes, wall, act):
    folder.mkdir(parents=True)
    (folder / "summary.json").write_text(json.dumps(
        {"wall_time_s": wall, "best_eval_success": max(successes), "time_split_s": {"act": act, "evaluate": 1.0}}))
    (folder / "eval.jsonl").write_text("".join(
        json.dumps({"episode": 10 * (i + 1), "success_rate_any_step": s, "success_rate": s, "return": 0.0}) + "\n"
        for i, s in enumerate(successes)))


def test_compile_mode_summarises_each_seed(bench, tmp_path, monkeypatch):
    runs = tmp_path / "runs"
    _fake_run(runs / "seed0_eager", [0.0, 1.0], wall=100.0, act=20.0)
    _fake_run(runs / "seed0_compiled", [0.5, 1.0], wall=90.0, act=9.0)
    _fake_run(runs / "seed3_eager", [1.0, 1.0], wall=80.0, act=19.0)
    _fake_run(runs / "seed3_compiled", [0.0, 0.0], wall=70.0, act=8.0)
    out = tmp_path / "out"
    monkeypatch.setattr(sys, "argv", ["setting_learning.py", "--mode", "compile", "--seeds", "0", "3",
                                      "--runs-root", str(runs), "--out", str(out)])
    bench.main()
    result = json.loads((out / "planner_compile_learning.json").read_text())
    assert result["overrides"] == ["planner.compile=true"] and result["seeds"] == [0, 3]
    assert [e["success_rate_any_step"] for e in result["runs"][1]["compiled"]["evals"]] == [0.0, 0.0]
    table = (out / "planner_compile_learning.md").read_text()
    assert "after episodes 10 / 20" in table
    assert "| 0 | 0.0 / 1.0 | 0.5 / 1.0 | 100 | 90 | 21 | 10 |" in table
    assert "| 3 | 1.0 / 1.0 | 0.0 / 0.0 | 80 | 70 | 20 | 9 |" in table


def test_missing_run_file_is_named(bench, tmp_path, monkeypatch):
    _fake_run(tmp_path / "seed0_eager", [1.0], wall=1.0, act=1.0)
    monkeypatch.setattr(sys, "argv", ["setting_learning.py", "--mode", "compile", "--runs-root", str(tmp_path),
                                      "--out", str(tmp_path / "out")])
    with pytest.raises(SystemExit, match="seed0_compiled/summary.json is missing"):
        bench.main()


def test_loop_speed_tabulates_a_finished_run(tmp_path):
    loop_speed = importlib.import_module("benchmarks.speed.loop_speed")
    run = tmp_path / "lift_pair" / "seed0"
    run.mkdir(parents=True)
    (run / "config.json").write_text(json.dumps({"train": {"threads": 1}}))
    with pytest.raises(SystemExit, match="seed0/summary.json is missing"):
        loop_speed.read_run(run)
    split = {"act": 30.0, "env": 10.0, "update": 40.0, "evaluate": 15.0, "checkpoint": 5.0, "total": 100.0}
    (run / "summary.json").write_text(json.dumps({"time_split_s": split, "episodes": 4, "env_steps": 400,
                                                  "updates": 300}))
    row = loop_speed.read_run(run)
    assert row["preset"] == "lift_pair/seed0" and row["num_envs"] == 1
    assert row["env_steps_per_s"] == pytest.approx(4.0) and row["collect_steps_per_s"] == pytest.approx(10.0)
    assert row["split_share"]["evaluate"] == pytest.approx(0.15) and row["split_share"]["log"] == 0.0
    assert "| lift_pair/seed0 | 1 | 1 | 4.00 | 10.00 | 300 | 30 | 10 | 40 | 15 | 5 | 0 |" in loop_speed.table([row])
