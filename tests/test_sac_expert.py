import pytest
import torch

from torchrl_mpail2.envs import make_env
from torchrl_mpail2.experts.gym import GymExpert
from torchrl_mpail2.experts.sac import make_actor


def test_sac_expert_round_trips_weights_and_acts_deterministically(tmp_path):
    env = make_env("gym/Hopper-v5", seed=0)
    actor = make_actor(env.observation_spec["observation"].shape[-1], env.action_spec)
    td = env.reset()
    with torch.no_grad():
        actor(td.clone())
    path = tmp_path / "Hopper-v5.pt"
    # a file from before PPO experts: no "kind", read as SAC's
    torch.save({"env": "Hopper-v5", "obs_dim": 11, "hidden": (256, 256), "actor": actor.state_dict(),
                "summary": {"eval_mean_return": 1.0}}, path)
    expert = GymExpert(path, env.action_spec)
    assert expert.kind == "sac"
    a1, a2 = expert(td.clone())["action"], expert(td.clone())["action"]
    assert torch.equal(a1, a2) and a1.shape == (3,) and a1.abs().max() <= 1
    # the loaded actor's mean action equals the original's
    loc = actor.module[0](td.clone())["loc"]
    assert torch.allclose(a1, torch.tanh(loc), atol=1e-5)
    traj = env.rollout(20, expert, break_when_any_done=True)
    assert traj["action"].abs().max() <= 1


def test_sac_trainer_runs_saves_periodically_and_evaluates(tmp_path):
    import json

    from torchrl_mpail2.experts.gym import evaluate_saved
    from torchrl_mpail2.experts.sac import train_sac

    out = tmp_path / "Hopper-v5.pt"
    summary = train_sac("Hopper-v5", frames=300, out=out, warmup=200, batch_size=32, eval_episodes=1, progress=False,
                        save_every=200)
    assert summary["finished"] and summary["frames"] == 300 and len(summary["eval_returns"]) == 1
    on_disk = json.loads(out.with_suffix(".json").read_text())
    assert on_disk == json.loads(json.dumps(summary))
    assert not list(tmp_path.glob("*.tmp"))  # atomic writes leave no temporaries
    again = evaluate_saved("Hopper-v5", out, episodes=2)
    assert len(again["eval_returns"]) == 2 and again["frames"] == 300
    # deterministic policy, same evaluation seeds: the first episode's return is reproduced
    assert again["eval_returns"][0] == summary["eval_returns"][0]


def _committed_experts():
    from torchrl_mpail2.experts.gym import ASSET_DIR
    return sorted(p.stem for p in ASSET_DIR.glob("*.pt"))


@pytest.mark.parametrize("env_id", _committed_experts())
def test_committed_expert_demonstrates_its_recorded_level_without_actions(env_id, tmp_path):
    import json

    from torchrl_mpail2.data import load_demos, record_demos
    from torchrl_mpail2.experts import get_expert
    from torchrl_mpail2.experts.gym import ASSET_DIR

    recorded = json.loads((ASSET_DIR / f"{env_id}.json").read_text())
    assert "eval_mean_return" in recorded, f"{env_id}: the committed expert has no recorded evaluation"
    env = make_env(f"gym/{env_id}", seed=0)
    expert = get_expert(f"gym/{env_id}", env)
    demos = record_demos(env, expert, 1, out=tmp_path / "demos", seed=10_000, progress=False, env_id=f"gym/{env_id}")
    loaded = load_demos(tmp_path / "demos", env.observation_spec)
    assert loaded.num_episodes == 1 and "action" not in loaded.episode(0).keys()
    # every recorded evaluation episode scored >= 0.27 x its expert's mean (Ant 242 / 895); five random-action
    # episodes scored 5-54 (Hopper), -394 to -10 (Ant), 83-158 (Humanoid), below a quarter of each mean
    assert demos.header["episodes"][0]["task_return"] >= 0.25 * recorded["eval_mean_return"]


def test_sac_run_resumes_from_its_checkpoint_where_it_stopped(tmp_path):
    """A run stopped at 300 frames and resumed to 500 continues from the checkpoint's networks, optimiser, replay and
    counters; other settings are refused, naming the field."""
    from torchrl_mpail2.data.checkpoint import CheckpointError, read_checkpoint
    from torchrl_mpail2.experts.sac import train_sac

    out, run_dir = tmp_path / "Hopper-v5.pt", tmp_path / "run"
    kwargs = dict(warmup=200, batch_size=32, eval_episodes=1, progress=False, save_every=100, run_dir=run_dir)
    first = train_sac("Hopper-v5", frames=300, out=out, **kwargs)
    saved = read_checkpoint(run_dir / "checkpoints" / "last")
    assert saved["counters"]["frames"] == 300 and saved["launches"] == 1
    assert len(saved["optim"]["state"]) > 0  # Adam's moments are kept, not only the weights
    second = train_sac("Hopper-v5", frames=500, out=out, **kwargs)
    assert second["frames"] == 500 and second["launches"] == 2
    assert second["train_seconds"] > first["train_seconds"]  # the first launch's time is counted
    resumed = read_checkpoint(run_dir / "checkpoints" / "last")
    assert resumed["counters"]["frames"] == 500
    # the resumed run kept training the saved networks: its parameters moved from the checkpoint's, and its
    # episode returns extend the first launch's
    assert resumed["episode_returns"][:len(saved["episode_returns"])] == saved["episode_returns"]
    assert any(not torch.equal(resumed["loss"][k], v) for k, v in saved["loss"].items() if "qvalue" in k)
    from torchrl_mpail2.data.checkpoint import load_replay
    from torchrl_mpail2.experts.sac import SACRun
    run = SACRun(make_env("gym/Hopper-v5", seed=0), 600, warmup=200)
    load_replay(run.replay, run_dir / "checkpoints" / "last")
    assert len(run.replay) == 500  # both launches' steps are in the stored buffer
    with pytest.raises(CheckpointError, match="batch_size"):
        train_sac("Hopper-v5", frames=600, out=out, **{**kwargs, "batch_size": 64})
