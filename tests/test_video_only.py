"""Video-only demonstrations (the paper's Appendix "Video-only Demonstration Setup"): the demos hold the table
camera alone, the learner observes every key, the reward reads only the kept keys' latent blocks."""
import pytest
import torch
from tensordict import TensorDict
from torchrl.data import Bounded, Composite, Unbounded

from conftest import TINY
from torchrl_mpail2 import ModelConfig
from torchrl_mpail2.agents import MPAIL2Agent
from torchrl_mpail2.data import demos_from_arrays

KEYS = {"camera": 4, "proprio": 3}  # vector stand-ins for the table camera and the proprioception
A, B, T = 2, 6, TINY["horizon"]


def _specs():
    observation = Composite({key: Unbounded((dim,)) for key, dim in KEYS.items()})
    return observation, Bounded(-1.0, 1.0, (A,))


def _demos(keys=("camera",)):
    torch.manual_seed(0)
    return demos_from_arrays([{key: torch.randn(12, KEYS[key]) for key in keys} for _ in range(2)], env_id="toy")


def _model(**overrides):
    return ModelConfig(**{**TINY, "latent_dim": 16, "fuse_latent": False, "reward_latent_keys": ("camera",),
                          **overrides})


def _batch(expert_keys=("camera",)):
    data = {"action": torch.rand(B, T, A) * 2 - 1, ("next", "terminated"): torch.zeros(B, T, 1, dtype=torch.bool)}
    for key, dim in KEYS.items():
        seq = torch.randn(B, T + 1, dim)
        data[key], data[("next", key)] = seq[:, :-1], seq[:, 1:]
        if key in expert_keys:
            expert = torch.randn(B, T + 1, dim)
            data[("expert", key)], data[("expert", "next", key)] = expert[:, :-1], expert[:, 1:]
    return TensorDict(data, [B, T])


def test_the_learner_encodes_every_key_and_the_expert_only_the_reward_block():
    agent = MPAIL2Agent(*_specs(), _model(), demos=_demos())
    encoder = agent.modules.encoder
    assert set(encoder.in_keys) == set(KEYS)  # the learner observes what the demos lack too
    # the demos' key is normalised from them; the missing vector key keeps the identity
    assert not torch.equal(encoder.net.obs_std_camera, torch.ones(4))
    assert torch.equal(encoder.net.obs_mean_proprio, torch.zeros(3))
    batch = _batch()
    ze, _ = agent.loss.expert_latents(batch)
    blocks = encoder.net.latent_slices
    assert ze[..., blocks["proprio"]].abs().max() == 0 and ze[..., blocks["camera"]].abs().min() > 0
    # the expert's camera block is the block the full encoder gives for the same camera frames
    full = batch.clone()
    full["expert", "proprio"], full["expert", "next", "proprio"] = torch.randn(B, T, 3), torch.randn(B, T, 3)
    ze_full, _ = agent.loss.expert_latents(full)
    torch.testing.assert_close(ze[..., blocks["camera"]], ze_full[..., blocks["camera"]])
    # the critic reads only the camera block: what the expert lacks cannot change its score
    critic = agent.modules.reward.module
    torch.testing.assert_close(critic.critic(ze, ze), critic.critic(ze_full, ze_full))
    before = [p.clone() for p in agent.modules.reward.parameters()]
    metrics = agent.updater.update(batch)
    assert metrics is not None and torch.isfinite(metrics["loss_reward"])
    assert any(not torch.equal(p, q) for p, q in zip(before, agent.modules.reward.parameters()))


@pytest.mark.parametrize("model, message", [
    (dict(fuse_latent=True, reward_latent_keys=None), r"reads observation keys \['proprio'\]"),
    (dict(reward_latent_keys=None), r"reads observation keys \['proprio'\]"),
    (dict(reward_latent_keys=("camera", "proprio")), r"reads observation keys \['proprio'\]"),
])
def test_demos_lacking_a_key_the_reward_reads_are_refused_by_name(model, message):
    # a fused latent with partial demos encodes only the demos' keys: the learner would lose the others
    with pytest.raises(KeyError, match=message):
        MPAIL2Agent(*_specs(), _model(**model), demos=_demos(), observation_keys=list(KEYS))


def test_with_keys_keeps_the_episodes_and_names_unknown_keys():
    demos = _demos(("camera", "proprio"))
    kept = demos.with_keys(["camera"])
    assert kept.observation_keys == ["camera"] and kept.num_episodes == 2 and kept.num_steps == demos.num_steps
    assert torch.equal(kept.episode(1)["camera"], demos.episode(1)["camera"])
    with pytest.raises(KeyError, match=r"hold no observation keys \['wrist'\]; their keys: \['camera', 'proprio'\]"):
        demos.with_keys(["wrist"])


def test_the_video_only_preset_reads_only_the_table_camera():
    from torchrl_mpail2.config import preset

    cfg = preset("push_video_only")
    assert cfg.train.obs == "pixels" and cfg.train.demo_keys == ("external_image",)
    assert cfg.model.fuse_latent is False and cfg.model.reward_latent_keys == ("external_image",)


@pytest.mark.slow
def test_mpail2_learns_the_point_mass_from_picture_only_demonstrations(tmp_path):
    """The video-only path end to end (``point_mass_video_only``): demonstrations of the picture alone, the learner
    seeing the picture and the state, the reward reading the picture's latent block. Measured: any-step success 1.0
    at 30 on the 10 fixed episodes on seeds 0 and 1 (about 3.5 minutes a run on one thread)."""
    from conftest import QUIET_RUN
    from torchrl_mpail2.trainers import MPAIL2Trainer, apply_overrides, preset

    trainer = MPAIL2Trainer(apply_overrides(preset("point_mass_video_only"), [*QUIET_RUN, "train.total_episodes=30"]),
                            run_dir=tmp_path / "run")
    assert list(trainer.demos.observation_keys) == ["external_image"]  # the state stays out of the demonstrations
    summary = trainer.train()
    assert summary["last_eval"]["episode"] == 30 and summary["last_eval"]["success_rate_any_step"] >= 0.8, summary
