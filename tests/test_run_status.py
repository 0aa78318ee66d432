import fcntl
import json

import pytest

from benchmarks.learning.run_status import seed_status, status_table


def _seed(root, name, seed, episodes, budget, summary=None, evals=(), held=None, last=False):
    run = root / name / f"seed{seed}"
    (run / "checkpoints").mkdir(parents=True)
    if last:
        (run / "checkpoints" / "last").mkdir()
    (run / "config.json").write_text(json.dumps({"train": {"total_episodes": budget}}))
    (run / "metrics.jsonl").write_text("".join(json.dumps({"episode": i + 1}) + "\n" for i in range(episodes)))
    (run / "eval.jsonl").write_text("".join(json.dumps(e) + "\n" for e in evals))
    if summary is not None:
        (run / "summary.json").write_text(json.dumps(summary))
    if held is not None:
        (run / "checkpoint_evals.json").write_text(json.dumps(held))
    return run


def test_each_state_of_a_seed_folder_is_told_apart(tmp_path):
    ev = [{"episode": 50, "success_rate_any_step": 0.4}]
    held = {"held_out": {"checkpoint": "episode_000050", "success_rate_any_step": 0.38},
            "held_out_last": {"checkpoint": "episode_000100", "success_rate_any_step": 0.1}}
    finished = _seed(tmp_path, "a", 0, 100, 100, {"wall_time_s": 600, "run_wall_time_s": 1200}, ev, held)
    signalled = _seed(tmp_path, "a", 1, 40, 100, {"stopped_by": "SIGTERM", "wall_time_s": 60}, last=True)
    budget = _seed(tmp_path, "a", 2, 70, 100, {"wall_time_s": 6000})
    crashed = _seed(tmp_path, "a", 3, 20, 100, last=True)
    fresh = _seed(tmp_path, "a", 4, 0, 100)
    row = seed_status(finished)
    assert (row["state"], row["episodes"], row["last evaluation"]) == ("finished", "100 of 100", "0.40 at 50")
    assert row["held out: Best / last"] == "0.38 (50) / 0.10 (100)" and row["wall (min)"] == "20"
    assert seed_status(signalled)["state"] == "stopped by SIGTERM, resumable"
    assert seed_status(budget)["state"] == "stopped at its wall-clock budget"
    assert seed_status(crashed)["state"] == "stopped, resumable"
    assert seed_status(fresh)["state"] == "not started"
    # a training holding the folder's lock is running, whatever its files say
    with open(crashed / ".lock", "a+") as handle:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
        assert seed_status(crashed)["state"] == "running"
    assert seed_status(crashed)["state"] == "stopped, resumable"
    table = status_table(tmp_path)
    assert table.count("\n| a |") == 5


def test_training_successes_count_acted_episodes_and_name_the_first(tmp_path):
    run = _seed(tmp_path, "a", 0, 0, 100)
    rows = [{"episode": 1, "success_any_step": 1.0, "random_actions": True},  # the warm-up's luck does not count
            {"episode": 2, "success_any_step": 0.0, "random_actions": False},
            {"episode": 3, "success_any_step": 1.0, "random_actions": False},
            {"episode": 4, "success_any_step": 1.0, "random_actions": False}]
    (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))
    row = seed_status(run)
    assert row["training successes"] == "2 (first at 3)" and row["episodes"] == "4 of 100"
    (run / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows[:2]))
    assert seed_status(run)["training successes"] == "0"


def test_an_unknown_run_name_is_named(tmp_path):
    (tmp_path / "a").mkdir()
    with pytest.raises(SystemExit, match="nope"):
        status_table(tmp_path, ["nope"])
