"""The multi-seed learning benchmark aggregates seeds' fixed-episode evaluations correctly."""
import importlib
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture()
def bench(tmp_path, monkeypatch):
    module = importlib.import_module("benchmarks.learning.learning_seeds")
    monkeypatch.setattr(module, "RESULTS", tmp_path / "results")
    return module


def _fake_seed(root, seed, evals, finished=True, episodes=100, successes=None):
    run = root / "demo" / f"seed{seed}"
    run.mkdir(parents=True)
    config = {"train": {"env": "robosuite/Lift", "obs": "state", "eval_episodes": 20, "eval_seed": 2_000_000,
                        "threads": 1, "seed": seed}}
    (run / "config.json").write_text(json.dumps(config))
    (run / "eval.jsonl").write_text("".join(
        json.dumps({"episode": e, "success_rate_any_step": a, "success_rate": last, "return": 0.0}) + "\n"
        for e, a, last in evals) + '{"episode": 99, "succ')  # a torn last line is ignored
    rows = [{"episode": i + 1, "update_ms": 10.0} for i in range(episodes)]
    for row, success in zip(rows, successes or []):
        row.update(success)
    (run / "metrics.jsonl").write_text("".join(json.dumps(row) + "\n" for row in rows))
    if finished:
        split = {"act": 20.0, "update": 30.0, "evaluate": 10.0, "total": 60.0}
        (run / "summary.json").write_text(json.dumps({"wall_time_s": 60.0, "time_split_s": split}))


def test_summary_means_bests_and_thresholds_over_seeds(bench, tmp_path):
    _fake_seed(tmp_path, 0, [(50, 0.4, 0.2), (100, 0.9, 0.6)])
    _fake_seed(tmp_path, 1, [(50, 0.6, 0.4), (100, 0.5, 0.5), (150, 0.7, 0.7)], episodes=150)
    r = bench.summarize("demo", tmp_path)
    assert [c["episode"] for c in r["curve"]] == [50, 100]  # episodes every seed reached
    assert r["curve"][0]["success_any_step_mean"] == pytest.approx(0.5)
    assert r["curve"][0]["success_any_step_std"] == pytest.approx(0.1)
    assert r["curve"][1]["success_last_step_mean"] == pytest.approx(0.55)
    assert r["best_success_any_step"] == pytest.approx((0.9 + 0.7) / 2)  # each seed's best evaluation
    assert r["last_success_any_step"] == pytest.approx((0.9 + 0.7) / 2)  # each seed's final evaluation
    assert r["episodes_to_50"] == 50 and r["episodes_to_80"] is None
    assert r["episodes"] == [100, 150] and r["seeds"] == [0, 1] and r["all_finished"]
    assert (tmp_path / "results" / "demo.json").exists() and (tmp_path / "results" / "demo.png").exists()
    split = r["per_seed"][0]["time_split"]
    assert split["seconds"]["evaluate"] == 10.0 and split["share"]["evaluate"] == pytest.approx(1 / 6)


def test_time_split_sums_the_launches_of_a_resumed_seed(bench, tmp_path):
    _fake_seed(tmp_path, 0, [(50, 0.4, 0.2)])
    run = tmp_path / "demo" / "seed0"
    (run / "summary.part0.json").write_text(json.dumps(
        {"wall_time_s": 40.0, "time_split_s": {"act": 10.0, "update": 10.0, "evaluate": 20.0, "total": 40.0}}))
    r = bench.summarize("demo", tmp_path)
    split = r["per_seed"][0]["time_split"]
    assert split["seconds"] == {"act": 30.0, "update": 40.0, "evaluate": 30.0, "total": 100.0}
    assert split["share"]["evaluate"] == pytest.approx(0.3) and r["wall_time_s"] == [100.0]
    # a trainer that counts the run's launches itself is believed over the sum of the summaries it left
    (run / "summary.json").write_text(json.dumps({"wall_time_s": 60.0, "run_wall_time_s": 130.0}))
    assert bench.summarize("demo", tmp_path)["wall_time_s"] == [130.0]


def test_a_seed_short_of_its_episodes_is_extended_only_when_asked(bench, tmp_path):
    _fake_seed(tmp_path, 0, [(50, 0.4, 0.2)], episodes=60)
    run = tmp_path / "demo" / "seed0"
    args = type("Args", (), {"episodes": 300, "extend_min": 0.0})()
    assert bench.seed_command(run, 0, args, []) is None
    args.extend_min = 30.0
    cmd = bench.seed_command(run, 0, args, [])
    assert cmd[-4:] == ["--resume", str(run), "train.total_episodes=300", "train.max_wall_s=1800.0"]
    assert not (run / "summary.json").exists() and (run / "summary.part0.json").exists()


def test_a_finished_seed_is_extended_to_more_episodes_and_an_interrupted_one_resumes_to_them(bench, tmp_path):
    _fake_seed(tmp_path, 0, [(50, 0.4, 0.2), (100, 0.8, 0.8)], episodes=100)
    run = tmp_path / "demo" / "seed0"
    args = type("Args", (), {"episodes": 300, "extend_min": 60.0})()
    cmd = bench.seed_command(run, 0, args, [])  # the earlier launch asked for 100: the resume must ask for 300
    assert "train.total_episodes=300" in cmd and "--resume" in cmd
    (run / "checkpoints" / "last").mkdir(parents=True)  # the extension was interrupted: no summary, a checkpoint
    assert bench.seed_command(run, 0, args, [])[-3:] == ["--resume", str(run), "train.total_episodes=300"]


def test_a_seed_a_stop_signal_ended_resumes_is_unfinished_and_is_not_scored_held_out(bench, tmp_path, monkeypatch):
    _fake_seed(tmp_path, 0, [(50, 0.0, 0.0)], episodes=79)
    run = tmp_path / "demo" / "seed0"
    (run / "checkpoints" / "last").mkdir(parents=True)
    (run / "summary.json").write_text(json.dumps({"wall_time_s": 60.0, "stopped_by": "SIGTERM"}))
    assert bench.summarize("demo", tmp_path)["per_seed"][0]["finished"] is False
    played = []
    monkeypatch.setattr(bench.subprocess, "Popen", lambda cmd, **kw: played.append(cmd))
    bench.score_held_out(type("Args", (), {"held_out": 50})(), [(0, run)])
    assert played == []  # half an hour a checkpoint on cameras, for a seed that is not done
    args = type("Args", (), {"episodes": 300, "extend_min": 0.0})()
    assert bench.seed_command(run, 0, args, [])[-3:] == ["--resume", str(run), "train.total_episodes=300"]
    assert not (run / "summary.json").exists() and (run / "summary.part0.json").exists()
    (run / "summary.json").write_text("{torn")
    with pytest.raises(SystemExit, match="summary.json is not valid JSON"):
        bench.seed_command(run, 0, args, [])


def test_finished_seeds_are_scored_held_out_parallel_at_a_time(bench, tmp_path, monkeypatch, capsys):
    """Scoring 50 held-out episodes takes a camera seed about 17 minutes on one thread: with --parallel 2, two seeds
    score side by side instead of one after the other, and a third waits for the first to end."""
    events = []

    class FakeScoring:
        def __init__(self, cmd, **kwargs):
            self.seed = Path(cmd[3]).name
            events.append(("start", self.seed))

        def wait(self):
            events.append(("end", self.seed))
            return 1 if self.seed == "seed2" else 0

    runs = []
    for seed in (0, 1, 2):
        _fake_seed(tmp_path, seed, [(50, 0.4, 0.2), (100, 0.8, 0.8)], episodes=100)
        run = tmp_path / "demo" / f"seed{seed}"
        (run / "checkpoints").mkdir(exist_ok=True)
        runs.append((seed, run))
    monkeypatch.setattr(bench.subprocess, "Popen", FakeScoring)
    bench.score_held_out(type("Args", (), {"held_out": 50, "parallel": 2})(), runs)
    assert events == [("start", "seed0"), ("start", "seed1"), ("end", "seed0"), ("start", "seed2"),
                      ("end", "seed1"), ("end", "seed2")]
    assert "seed 2: held-out scoring exited with 1" in capsys.readouterr().out
    events.clear()
    bench.score_held_out(type("Args", (), {"held_out": 50, "parallel": 1})(), runs)
    assert events == [("start", "seed0"), ("end", "seed0"), ("start", "seed1"), ("end", "seed1"),
                      ("start", "seed2"), ("end", "seed2")]


def test_child_processes_import_the_checkout_first_and_keep_the_callers_path(bench, monkeypatch):
    # on a borrowed GPU machine torchrl and robosuite live outside the environment, on PYTHONPATH: a child that
    # replaced it could not import them
    monkeypatch.setenv("PYTHONPATH", "/opt/extra/site")
    env = bench.child_env(threads=1)
    assert env["PYTHONPATH"].split(":") == [str(ROOT), "/opt/extra/site"]
    assert env["OMP_NUM_THREADS"] == "1"
    monkeypatch.delenv("PYTHONPATH")
    assert bench.child_env()["PYTHONPATH"] == str(ROOT)
    # a caller (the campaign runner) that put the checkout first already does not get it twice
    monkeypatch.setenv("PYTHONPATH", f"{ROOT}:/opt/extra/site")
    assert bench.child_env()["PYTHONPATH"].split(":") == [str(ROOT), "/opt/extra/site"]


def test_training_success_is_windowed_after_the_warm_up_and_averaged_over_seeds(bench, tmp_path):
    warm = [{"success_any_step": 1.0, "random_actions": True}] * 5  # warm-up successes must not count
    acted = lambda hits, n: [{"success_any_step": float(i < hits), "random_actions": False} for i in range(n)]
    _fake_seed(tmp_path, 0, [(50, 0.0, 0.0)], successes=warm + acted(5, 25) + acted(25, 25) + acted(0, 10))
    _fake_seed(tmp_path, 1, [(50, 0.0, 0.0)], successes=warm + acted(15, 25) + acted(0, 25))
    r = bench.summarize("demo", tmp_path)
    assert [w["episode"] for w in r["per_seed"][0]["training_success"]] == [30, 55]  # the short window is left out
    assert [w["success_any_step"] for w in r["per_seed"][0]["training_success"]] == [0.2, 1.0]
    assert [c["episode"] for c in r["training_curve"]] == [30, 55]
    assert r["training_curve"][0]["success_any_step_mean"] == pytest.approx(0.4)
    assert r["training_curve"][1]["success_any_step_mean"] == pytest.approx(0.5)
    assert r["training_curve"][1]["success_any_step_std"] == pytest.approx(0.5)


def test_a_failed_seeds_log_tail_is_shown(bench, tmp_path):
    log = tmp_path / "seed0.log"
    log.write_text("".join(f"line {i}\n" for i in range(40)) + "ConfigError: unknown field 'train.bogus'\n")
    tail = bench.log_tail(log, lines=3)
    assert tail.splitlines() == ["line 38", "line 39", "ConfigError: unknown field 'train.bogus'"]
    assert "no log" in bench.log_tail(tmp_path / "missing.log")


def test_run_seeds_reports_a_failing_seed_with_its_log(bench, tmp_path, monkeypatch, capsys):
    import sys

    def failing(run_dir, seed, args, overrides):
        run_dir.mkdir(parents=True, exist_ok=True)
        return [sys.executable, "-c", f"print('seed {seed} broke'); raise SystemExit(3)"]

    monkeypatch.setattr(bench, "seed_command", failing)
    monkeypatch.setattr(bench.time, "sleep", lambda s: None)
    args = type("Args", (), {"seeds": [0, 1], "runs_root": tmp_path, "name": "demo", "episodes": 10, "parallel": 2})()
    bench.run_seeds(args, [])
    out = capsys.readouterr().out
    assert "seed 0: training exited with 3" in out and "seed 0 broke" in out and "seed 1 broke" in out


def test_each_seed_is_scored_held_out_as_its_training_ends_in_the_slot_it_frees(bench, tmp_path, monkeypatch):
    """With one slot, seed 0's 50 held-out episodes (17 minutes on cameras) play before seed 2 trains, not after
    every seed has trained; a seed whose training failed is not scored, one trained already is (scores reused)."""
    import sys
    events = tmp_path / "events"

    def note(word, seed, code=0):
        return [sys.executable, "-c", f"open({str(events)!r}, 'a').write('{word} {seed}\\n'); raise SystemExit({code})"]

    def training(run_dir, seed, args, overrides):
        run_dir.mkdir(parents=True, exist_ok=True)
        return None if seed == 3 else note("train", seed, code=3 if seed == 1 else 0)

    monkeypatch.setattr(bench, "seed_command", training)
    monkeypatch.setattr(bench, "held_out_command", lambda run_dir, args: note("score", run_dir.name[-1]))
    monkeypatch.setattr(bench.time, "sleep", lambda s: None)
    args = type("Args", (), {"seeds": [0, 1, 2, 3], "runs_root": tmp_path, "name": "demo", "episodes": 10,
                             "parallel": 1, "held_out": 50})()
    bench.run_seeds(args, [])
    assert events.read_text().split("\n")[:-1] == ["train 0", "score 0", "train 1", "train 2", "score 2", "score 3"]


def _result_named(bench, tmp_path, name, seeds_evals, **config_changes):
    """Summarises fake seeds into ``RESULTS/<name>.json`` (the fake seeds' folder is always ``demo``)."""
    root = tmp_path / name
    for seed, evals in seeds_evals.items():
        _fake_seed(root, seed, evals)
        if config_changes:
            path = root / "demo" / f"seed{seed}" / "config.json"
            config = json.loads(path.read_text())
            config["train"].update(config_changes)
            path.write_text(json.dumps(config))
    bench.summarize("demo", root)
    (bench.RESULTS / "demo.json").rename(bench.RESULTS / f"{name}.json")


def test_merge_combines_the_seeds_of_results_of_one_configuration(bench, tmp_path):
    _result_named(bench, tmp_path, "first", {0: [(50, 0.2, 0.1), (100, 0.6, 0.5)], 1: [(50, 0.4, 0.3), (100, 0.8, 0.8)]})
    # a field the earlier result's config predates counts as its default; threads and budget may differ
    _result_named(bench, tmp_path, "later", {2: [(50, 0.0, 0.0), (100, 1.0, 0.9)]}, threads=2, max_wall_s=10.0,
                  eval_acting="deterministic")
    r = bench.merge("all", ["first", "later"])
    assert r["seeds"] == [0, 1, 2] and r["merged_from"] == ["first", "later"]
    assert r["curve"][1]["success_any_step_mean"] == pytest.approx(0.8)  # (0.6 + 0.8 + 1.0) / 3
    assert r["curve"][0]["seeds"] == 3 and r["best_success_any_step"] == pytest.approx(0.8)
    assert json.loads((bench.RESULTS / "all.json").read_text())["seeds"] == [0, 1, 2]
    assert (bench.RESULTS / "all.png").exists()


def test_a_merged_result_merges_again_keeping_each_seeds_commit(bench, tmp_path):
    for name, seed, commit in (("a", 0, "c0"), ("b", 1, "c1"), ("c", 2, "c2")):
        _result_named(bench, tmp_path, name, {seed: [(50, 0.2, 0.1)]})
        path = bench.RESULTS / f"{name}.json"
        path.write_text(json.dumps({**json.loads(path.read_text()), "commit": commit}))
    bench.merge("ab", ["a", "b"])
    assert json.loads((bench.RESULTS / "ab.json").read_text())["commit"] == {"0": "c0", "1": "c1"}
    r = bench.merge("abc", ["ab", "c"])
    assert r["seeds"] == [0, 1, 2]
    assert {int(k): v for k, v in r["commit"].items()} == {0: "c0", 1: "c1", 2: "c2"}


def test_merge_refuses_other_configurations_repeated_seeds_and_missing_results(bench, tmp_path):
    _result_named(bench, tmp_path, "first", {0: [(50, 0.2, 0.1)]})
    _result_named(bench, tmp_path, "other", {1: [(50, 0.4, 0.3)]}, eval_episodes=50)
    _result_named(bench, tmp_path, "again", {0: [(50, 0.4, 0.3)]})
    with pytest.raises(SystemExit, match="differ in train.eval_episodes"):
        bench.merge("all", ["first", "other"])
    with pytest.raises(SystemExit, match="seed 0 is in again"):
        bench.merge("all", ["first", "again"])
    with pytest.raises(SystemExit, match="no results file .*absent.json"):
        bench.merge("all", ["first", "absent"])
    assert not (bench.RESULTS / "all.json").exists()


def test_summarize_can_leave_out_a_seed_that_has_not_evaluated_yet(bench, tmp_path):
    _fake_seed(tmp_path, 0, [(50, 0.4, 0.2), (100, 0.9, 0.6)])
    _fake_seed(tmp_path, 1, [(50, 0.6, 0.4), (100, 0.5, 0.5)])
    _fake_seed(tmp_path, 2, [], finished=False, episodes=3)
    assert bench.summarize("demo", tmp_path)["curve"] == []  # no episode every seed was evaluated at
    r = bench.summarize("demo", tmp_path, only=[0, 1])
    assert r["seeds"] == [0, 1] and [c["episode"] for c in r["curve"]] == [50, 100]
    with pytest.raises(SystemExit, match=r"seed\(s\) \[5\]"):
        bench.summarize("demo", tmp_path, only=[0, 5])


def _checkpoint_evals(run, rows, held_out=None, episodes=20, acting="deterministic"):
    """A ``checkpoint_evals.json`` as ``benchmarks/learning/evaluate_checkpoints.py`` writes it: ``rows`` of (episode, any step)."""
    checkpoints = [{"episode": e, "checkpoint": f"episode_{e:06d}", "success_rate_any_step": a, "success_rate": a}
                   for e, a in rows]
    best = max(checkpoints, key=lambda r: r["success_rate_any_step"])
    evals = {"acting": acting, "episodes_per_checkpoint": episodes, "first_eval_seed": 2_000_000,
             "checkpoints": checkpoints, "best_success_rate_any_step": best["success_rate_any_step"],
             "best_checkpoint": best["checkpoint"], "best_episode": best["episode"]}
    if held_out is not None:
        evals["held_out"] = {"checkpoint": best["checkpoint"], "first_seed": 2_100_000, "episodes": 50,
                             "success_rate_any_step": held_out, "success_rate": held_out}
    (run / "checkpoint_evals.json").write_text(json.dumps(evals))


def test_the_best_of_every_checkpoint_and_its_held_out_score_join_the_summary(bench, tmp_path):
    _fake_seed(tmp_path, 0, [(50, 0.4, 0.2), (100, 0.6, 0.6)])
    _fake_seed(tmp_path, 1, [(50, 0.6, 0.4), (100, 0.5, 0.5)])
    r = bench.summarize("demo", tmp_path)
    assert r["best_all_checkpoints_success_any_step"] is None  # no seed has them
    _checkpoint_evals(tmp_path / "demo" / "seed0", [(90, 0.85), (100, 0.6)], held_out=0.62)
    r = bench.summarize("demo", tmp_path)
    assert r["per_seed"][0]["all_checkpoints"]["best_episode"] == 90 and r["per_seed"][1]["all_checkpoints"] is None
    assert r["best_all_checkpoints_success_any_step"] is None  # seed 1 has none: no mean over part of the seeds
    _checkpoint_evals(tmp_path / "demo" / "seed1", [(60, 0.75), (100, 0.5)], held_out=0.58)
    r = bench.summarize("demo", tmp_path)
    assert r["best_all_checkpoints_success_any_step"] == pytest.approx(0.8)
    assert r["best_checkpoint_held_out_success_any_step"] == pytest.approx(0.6)
    assert r["best_success_any_step"] == pytest.approx(0.6)  # the evaluations' own Best is kept beside it
    _checkpoint_evals(tmp_path / "demo" / "seed1", [(60, 0.75)], episodes=10)  # another episode set: not used
    assert bench.summarize("demo", tmp_path)["per_seed"][1]["all_checkpoints"] is None


def test_merge_allows_another_checkpoint_spacing(bench, tmp_path):
    _result_named(bench, tmp_path, "first", {0: [(50, 0.2, 0.1)]}, checkpoint_every=50)
    _result_named(bench, tmp_path, "dense", {1: [(50, 0.4, 0.3)]}, checkpoint_every=10)
    assert bench.merge("all", ["first", "dense"])["seeds"] == [0, 1]


def test_checkpoints_are_saved_at_each_evaluation_unless_asked_otherwise(bench, tmp_path):
    run = tmp_path / "demo" / "seed0"
    args = type("Args", (), {"episodes": 300, "extend_min": 0.0, "preset": "lift_state", "budget_min": 10.0,
                             "eval_every": 50, "eval_episodes": 20, "checkpoint_every": None})()
    assert "train.checkpoint_every=50" in bench.seed_command(run, 0, args, [])
    args.checkpoint_every = 10
    assert "train.checkpoint_every=10" in bench.seed_command(run, 0, args, [])
    (run / "checkpoints" / "last").mkdir(parents=True)  # resumed: the spacing may change, nothing else
    assert bench.seed_command(run, 0, args, [])[-2:] == ["train.total_episodes=300", "train.checkpoint_every=10"]


def _held_out_last(run, outcomes):
    """Adds a ``held_out_last`` score with per-episode outcomes to the run's ``checkpoint_evals.json``."""
    path = run / "checkpoint_evals.json"
    evals = json.loads(path.read_text())
    evals["held_out_last"] = {"checkpoint": "episode_000100", "first_seed": 2_100_000, "episodes": len(outcomes),
                              "success_rate_any_step": sum(outcomes) / len(outcomes), "success_rate": 0.0,
                              "success_any_step_per_episode": outcomes}
    path.write_text(json.dumps(evals))


def test_the_held_out_headline_has_a_bootstrap_interval_and_the_iqm_from_three_seeds(bench, tmp_path):
    outcomes = {0: [1.0] * 40 + [0.0] * 10, 1: [1.0] * 30 + [0.0] * 20, 2: [1.0] * 45 + [0.0] * 5}
    for seed, seed_outcomes in outcomes.items():
        _fake_seed(tmp_path, seed, [(50, 0.4, 0.2), (100, 0.6, 0.6)])
        _checkpoint_evals(tmp_path / "demo" / f"seed{seed}", [(50, 0.4), (100, 0.6)])
        if seed < 2:
            _held_out_last(tmp_path / "demo" / f"seed{seed}", seed_outcomes)
    assert bench.summarize("demo", tmp_path)["held_out_last"] is None  # seed 2 has no held-out score yet
    _held_out_last(tmp_path / "demo" / "seed2", outcomes[2])
    headline = bench.summarize("demo", tmp_path)["held_out_last"]
    assert headline["per_seed"] == pytest.approx([0.8, 0.6, 0.9]) and headline["mean"] == pytest.approx(0.7667, abs=1e-3)
    low, high = headline["ci95"]
    assert low < headline["mean"] < high and 0.5 < low and high < 0.95  # seeds and episodes both vary
    assert headline["iqm"] == pytest.approx(headline["mean"])  # 3 seeds: a quarter of 3 rounds down to no cut
    assert headline["episodes"] == [50, 50, 50]


def test_bootstrap_interval_and_iqm_by_hand():
    from torchrl_mpail2.trainers.intervals import bootstrap_ci, iqm

    assert bootstrap_ci([[1.0] * 20]) == (1.0, 1.0)  # nothing varies
    low, high = bootstrap_ci([[1.0] * 25 + [0.0] * 25])  # one seed: a binomial mean of 0.5 over 50 episodes
    assert 0.34 < low < 0.40 and 0.60 < high < 0.66  # the normal approximation gives 0.5 -+ 0.139
    lo2, hi2 = bootstrap_ci([[1.0] * 10, [0.0] * 10])
    assert lo2 == 0.0 and hi2 == 1.0  # two seeds that disagree completely: resampling seeds spans everything
    assert iqm([0.0, 1.0, 2.0, 3.0]) == pytest.approx(1.5) and iqm([5.0, 0.0, 100.0, 1.0, 2.0]) == pytest.approx(8 / 3)
    assert iqm([0.3, 0.9]) is None
    with pytest.raises(ValueError, match="at least one seed"):
        bootstrap_ci([[1.0], []])


def test_the_summary_keeps_no_absolute_paths_of_this_machine(bench, tmp_path):
    runs = tmp_path / "worktree" / "runs" / "learning"
    _fake_seed(runs, 0, [(50, 0.4, 0.2)])
    config_file = runs / "demo" / "seed0" / "config.json"
    config = json.loads(config_file.read_text())
    config["train"].update(run_dir=str(runs / "demo" / "seed0"), demos="/somewhere/else/demos_pm")
    config_file.write_text(json.dumps(config))
    r = bench.summarize("demo", runs)
    assert r["config"]["train"]["run_dir"] == "runs/learning/demo/seed0"
    assert r["config"]["train"]["demos"] == "<elsewhere>/demos_pm"
    assert str(tmp_path) not in (tmp_path / "results" / "demo.json").read_text()


def test_a_transfer_seed_starts_from_its_own_source_seed_and_resumes_from_its_own_checkpoint(bench, tmp_path):
    source = tmp_path / "push" / "seed{seed}" / "checkpoints" / "last"
    (tmp_path / "push" / "seed1" / "checkpoints" / "last").mkdir(parents=True)
    run = tmp_path / "mirrored" / "seed1"
    args = type("Args", (), {"episodes": 150, "extend_min": 0.0, "preset": "push_state", "budget_min": 10.0,
                             "eval_every": 10, "eval_episodes": 20, "checkpoint_every": None,
                             "init_from": str(source), "transfer": "world-model"})()
    cmd = bench.seed_command(run, 1, args, ["train.env=robosuite/PushMirrored"])
    at = cmd.index("--init-from")
    assert cmd[at + 1:at + 4] == [str(tmp_path / "push" / "seed1" / "checkpoints" / "last"), "--transfer", "world-model"]
    assert cmd[-1] == "train.env=robosuite/PushMirrored"
    with pytest.raises(SystemExit, match=r"seed 2's source checkpoint .*seed2"):
        bench.seed_command(tmp_path / "mirrored" / "seed2", 2, args, [])
    (run / "checkpoints" / "last").mkdir(parents=True)  # interrupted: it resumes from its own weights, not the source's
    assert "--init-from" not in bench.seed_command(run, 1, args, [])
