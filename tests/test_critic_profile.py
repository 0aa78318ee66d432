"""The critic profile along demonstrations: per-window means, the end-effector distance, and refusals by name."""
import json

import pytest
import torch
from tensordict import TensorDict

from conftest import QUIET_RUN
from torchrl_mpail2.data import demos_from_arrays, save_demos
from torchrl_mpail2.diagnostics.critic_profile import critic_along_episodes, main, profile_checkpoint
from torchrl_mpail2.trainers import MPAIL2Trainer, apply_overrides, preset


class _StepEncoder:
    """z = the observation's step index (first entry of "proprio")."""

    def encode(self, td):
        return td["proprio"][..., :1]


class _NextStepCritic:
    def critic(self, z, z_next):
        return 10.0 * z_next


def _episode(length, offset=0.0):
    steps = torch.arange(length + 1, dtype=torch.float32)
    obj = torch.zeros(length + 1, 10)
    obj[:, 7] = 0.3 - 0.01 * steps  # the hand closes in on the cube by 1 cm per step
    return TensorDict({"proprio": torch.stack([steps + offset, steps], -1), "object": obj}, [length + 1])


def test_the_profile_averages_each_window_over_episodes():
    rows = critic_along_episodes(_StepEncoder(), _NextStepCritic(), [_episode(10), _episode(6, offset=2.0)], window=5,
                                 eef_to_cube=slice(7, 10))
    assert [r["step"] for r in rows] == [0, 5]  # pairs at steps 0-9 and 0-5
    assert [r["pairs"] for r in rows] == [10, 6]
    # window 0-4: z' = 1..5 in the first episode, 3..7 in the second -> mean 10 * 4
    assert rows[0]["critic_mean"] == pytest.approx(40.0)
    assert rows[0]["eef_to_cube_m"] == pytest.approx(0.3 - 0.01 * 2)
    assert "eef_to_cube_m" not in critic_along_episodes(_StepEncoder(), _NextStepCritic(), [_episode(3)], window=5)[0]


def test_bad_windows_and_episodes_are_refused():
    with pytest.raises(ValueError, match="window"):
        critic_along_episodes(_StepEncoder(), _NextStepCritic(), [_episode(3)], window=0)
    with pytest.raises(ValueError, match="no episodes"):
        critic_along_episodes(_StepEncoder(), _NextStepCritic(), [], window=2)
    with pytest.raises(ValueError, match="fewer than two"):
        critic_along_episodes(_StepEncoder(), _NextStepCritic(), [_episode(0)], window=2)


def test_a_checkpoint_is_profiled_on_demonstrations_and_foreign_ones_are_named(tmp_path):
    cfg = apply_overrides(preset("point_mass"), [*QUIET_RUN, "train.num_demos=3", "train.total_episodes=1",
                                                  "train.warmup_episodes=0", "train.utd=0.05", "train.eval_every=0",
                                                  "planner.num_candidates=32", "planner.num_elites=4"])
    MPAIL2Trainer(cfg, run_dir=tmp_path / "run").train()
    demos = next((tmp_path / "demos").glob("point_mass*"))
    ckpt = tmp_path / "run" / "checkpoints" / "last"
    result = profile_checkpoint(ckpt, demos, window=10)
    assert result["profile"] and sum(r["pairs"] for r in result["profile"]) > 0
    assert all(torch.isfinite(torch.tensor(r["critic_mean"])) for r in result["profile"])
    assert "eef_to_cube_m" not in result["profile"][0]  # the point mass has no cube
    assert all(torch.isfinite(torch.tensor(r["q_mean"])) for r in result["profile"])
    assert "agent_profile" not in result
    out = tmp_path / "profile.json"
    main([str(ckpt), "--demos", str(demos), "--out", str(out), "--plot", str(tmp_path / "profile.png"),
          "--agent-episodes", "2"])
    assert out.exists() and (tmp_path / "profile.png").stat().st_size > 0
    written = json.loads(out.read_text())[0]
    assert written["agent_episodes"] == 2
    agent_rows = written["agent_profile"]  # both episodes play at least the first window (5 steps)
    assert agent_rows[0]["step"] == 0 and agent_rows[0]["pairs"] == 2 * written["window"] == 2 * 5
    assert all(torch.isfinite(torch.tensor([r["critic_mean"], r["q_mean"]])).all() for r in agent_rows)
    with pytest.raises(SystemExit):
        main([str(ckpt), "--demos", str(demos), "--agent-episodes", "-1"])
    with pytest.raises(Exception, match="nothere"):
        profile_checkpoint(ckpt, tmp_path / "nothere")
    foreign = save_demos(demos_from_arrays([torch.zeros(4, 2)], key="elsewhere"), tmp_path / "foreign")
    with pytest.raises(KeyError, match="lack the run's observation key"):
        profile_checkpoint(ckpt, foreign)
