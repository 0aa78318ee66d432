"""The run folder's figures: curves.png and the learner diagnostics of learner.png."""
import json
import math

from torchrl_mpail2.trainers.plots import LEARNER_PANELS, learner_series, plot_run


def _write_run(run_dir):
    run_dir.mkdir()
    records = [{"episode": 1, "success": 0.0, "success_any_step": 0.0, "random_actions": True}]  # warm-up: no update
    for episode in range(2, 6):
        records.append({"episode": episode, "success": 0.0, "success_any_step": float(episode > 3),
                        "policy_influence": 0.01 * episode, "reward_gap": 10.0 + episode, "grad_penalty": 0.5,
                        "q_mean": -float(episode), "q_target_mean": -float(episode) - 0.5, "alpha": 1e-3 * episode,
                        "entropy": -15.0 + episode, "target_entropy": -4.0, "elite_ess": 31.5})
    records[-1]["q_mean"] = math.nan  # a non-finite value is left out, not drawn
    (run_dir / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in records))
    (run_dir / "eval.jsonl").write_text(json.dumps({"episode": 5, "success_rate": 0.0, "success_rate_any_step": 0.5}) + "\n")
    return records


def test_learner_series_skips_warm_up_and_non_finite_values(tmp_path):
    records = _write_run(tmp_path / "run")
    series = learner_series(records)
    assert set(series) == {key for panel in LEARNER_PANELS for key in panel[2]}
    assert series["alpha"] == ([2, 3, 4, 5], [2e-3, 3e-3, 4e-3, 5e-3])
    assert series["q_mean"] == ([2, 3, 4], [-2.0, -3.0, -4.0])
    assert series["target_entropy"][1] == [-4.0] * 4
    assert learner_series([{"episode": 1, "success": 1.0}]) == {}


def test_plot_run_writes_the_curves_and_the_learner_diagnostics(tmp_path):
    _write_run(tmp_path / "run")
    out = plot_run(tmp_path / "run", window=2)
    assert out == tmp_path / "run" / "curves.png"
    for name in ("curves.png", "learner.png"):
        assert (tmp_path / "run" / name).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n", name
