"""Experts for the gymnasium MuJoCo tasks trained with TorchRL's PPO (``ClipPPOLoss`` on ``GAE`` advantages), the
kind of demonstrator the paper's gymnasium demonstrations came from.

    python -m torchrl_mpail2.experts.ppo --env Hopper-v5 --frames 1000000

PPO updates on minibatches of 64 for 10 epochs of each 2048-step batch: about 0.3 gradient steps of a 64-wide
network per frame, where :mod:`.sac` takes one step of three 256-wide networks at batch 256 per frame (about 30 ms
on one thread here). It is on-policy, so a run's checkpoint holds no replay buffer: networks, normalisers,
optimiser, counters and RNG states, a few hundred kB. The settings are those of CleanRL's continuous-action PPO
for MuJoCo (:data:`PPO_SETTINGS`): observations normalised by running statistics and clipped to +-10, rewards
divided by the running standard deviation of the discounted return and clipped to +-10, advantages normalised
per minibatch, gradients clipped to norm 0.5, the learning rate annealed linearly to 0 over ``--frames``. Two
departures: the policy is a tanh-squashed Gaussian (TorchRL's ``TanhNormal``) with a state-independent scale, so
that actions stay in the env's bounds without clipping outside the policy; and each batch is 8 envs x 256 steps
(a ``SerialEnv``) instead of 1 x 2048, which collects about twice as fast here (TorchRL's per-step overhead,
not the simulator, dominates a single Hopper env: about 2.9 ms a step against 1.3).
"""
from __future__ import annotations

import argparse
import math
from functools import partial
from pathlib import Path

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import nn
from torchrl.collectors import Collector
from torchrl.envs import SerialEnv, TransformedEnv
from torchrl.envs.utils import ExplorationType
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import ClipPPOLoss
from torchrl.objectives.value import GAE

from torchrl_mpail2.envs.gym_env import make_gym_env
from torchrl_mpail2.envs.keys import with_bookkeeping
from torchrl_mpail2.experts.gym import ExpertRun, add_expert_arguments, expert_cli, train_expert

#: Settings a PPO expert run keeps across resumes (a resumed run refuses others, naming the field).
PPO_SETTINGS = {"hidden": [64, 64], "gamma": 0.99, "lmbda": 0.95, "clip_epsilon": 0.2, "lr": 3e-4,
                "frames_per_batch": 2048, "epochs": 10, "minibatch_size": 64, "critic_coeff": 0.5,
                "max_grad_norm": 0.5, "obs_clip": 10.0, "reward_clip": 10.0, "init_log_std": 0.0, "num_envs": 8}
NORMALIZED_OBS_KEY = "observation_norm"
SCALED_REWARD_KEY = "scaled_reward"


class RunningMeanStd(nn.Module):
    """Mean and variance of everything seen so far (Chan et al.'s parallel update, in float64), kept as buffers
    so that they travel with the policy's state dict."""

    def __init__(self, dim: int):
        super().__init__()
        self.register_buffer("mean", torch.zeros(dim, dtype=torch.float64))
        self.register_buffer("var", torch.ones(dim, dtype=torch.float64))
        self.register_buffer("count", torch.tensor(1e-4, dtype=torch.float64))

    @torch.no_grad()
    def update(self, x: torch.Tensor) -> None:
        """x (Tensor): ``[N, dim]``."""
        x = x.to(torch.float64).reshape(-1, self.mean.numel())
        n = x.shape[0]
        batch_mean, batch_var = x.mean(0), x.var(0, unbiased=False)
        total = self.count + n
        delta = batch_mean - self.mean
        m2 = self.var * self.count + batch_var * n + delta.pow(2) * self.count * n / total
        self.mean += delta * n / total
        self.var.copy_(m2 / total)
        self.count.copy_(total)


class ObservationNormalizer(nn.Module):
    """``clip((o - mean) / sqrt(var + 1e-8), -c, c)`` with the running statistics of :class:`RunningMeanStd`."""

    def __init__(self, dim: int, clip: float):
        super().__init__()
        self.stats, self.clip = RunningMeanStd(dim), clip

    def forward(self, observation: torch.Tensor) -> torch.Tensor:
        z = (observation - self.stats.mean) / torch.sqrt(self.stats.var + 1e-8)
        return z.clamp(-self.clip, self.clip).to(observation.dtype)


class _LocAndScale(nn.Module):
    """``loc = mlp(x)``, ``scale = exp(log_std)``: a Gaussian whose spread does not depend on the state."""

    def __init__(self, obs_dim: int, action_dim: int, hidden: list[int], init_log_std: float):
        super().__init__()
        self.mlp = _mlp(obs_dim, action_dim, hidden, last_gain=0.01)
        self.log_std = nn.Parameter(torch.full((action_dim,), float(init_log_std)))

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        loc = self.mlp(x)
        return loc, self.log_std.exp().expand_as(loc)


def _mlp(in_dim: int, out_dim: int, hidden: list[int], last_gain: float) -> MLP:
    """Tanh MLP with orthogonal weights (gain sqrt(2), ``last_gain`` on the output layer) and zero biases."""
    net = MLP(in_features=in_dim, out_features=out_dim, num_cells=list(hidden), activation_class=nn.Tanh)
    linears = [m for m in net.modules() if isinstance(m, nn.Linear)]
    for i, layer in enumerate(linears):
        nn.init.orthogonal_(layer.weight, last_gain if i == len(linears) - 1 else math.sqrt(2))
        nn.init.zeros_(layer.bias)
    return net


def make_policy(obs_dim: int, action_spec, settings: dict = PPO_SETTINGS) -> TensorDictSequential:
    """``"observation"`` -> ``"observation_norm"`` -> tanh-Gaussian ``"action"`` in ``[-1, 1]`` (and its log-prob)."""
    normalizer = TensorDictModule(ObservationNormalizer(obs_dim, settings["obs_clip"]), in_keys=["observation"],
                                  out_keys=[NORMALIZED_OBS_KEY])
    head = TensorDictModule(_LocAndScale(obs_dim, action_spec.shape[-1], settings["hidden"], settings["init_log_std"]),
                            in_keys=[NORMALIZED_OBS_KEY], out_keys=["loc", "scale"])
    actor = ProbabilisticActor(head, in_keys=["loc", "scale"], spec=action_spec, distribution_class=TanhNormal,
                               distribution_kwargs={"low": -1.0, "high": 1.0}, return_log_prob=True,
                               default_interaction_type=ExplorationType.RANDOM)
    return TensorDictSequential(normalizer, actor)


class PPORun(ExpertRun):
    """TorchRL's ``ClipPPOLoss`` and ``GAE`` with the normalisers, optimiser and counters of an expert run.

    Args:
        env (EnvBase): a ``[num_envs]`` batch of envs (:func:`make_batched_env`) with an ``"observation"`` vector,
            a bounded ``[A]`` action, ``"task_reward"`` and ``"episode_task_return"``.
        total_frames (int): the frames over which the learning rate is annealed to 0.

    Keyword Args:
        settings (dict): :data:`PPO_SETTINGS` or a variant of it.
    """

    def __init__(self, env, total_frames: int, *, settings: dict = PPO_SETTINGS):
        self.env, self.settings, self.total_frames = env, dict(settings), total_frames
        obs_dim = env.observation_spec["observation"].shape[-1]
        self.policy = make_policy(obs_dim, env.action_spec_unbatched, self.settings)
        self.normalizer = self.policy[0].module
        critic = ValueOperator(_mlp(obs_dim, 1, self.settings["hidden"], last_gain=1.0), in_keys=[NORMALIZED_OBS_KEY])
        self.loss = ClipPPOLoss(self.policy[1], critic, clip_epsilon=self.settings["clip_epsilon"],
                                entropy_bonus=False, critic_coeff=self.settings["critic_coeff"],
                                loss_critic_type="l2", normalize_advantage=True)
        self.gae = GAE(gamma=self.settings["gamma"], lmbda=self.settings["lmbda"], value_network=critic)
        self.gae.set_keys(reward=SCALED_REWARD_KEY)
        self.optim = torch.optim.Adam(self.loss.parameters(), lr=self.settings["lr"], eps=1e-5)
        self.returns_stats = RunningMeanStd(1)
        self.discounted_return = torch.zeros(env.batch_size.numel(), dtype=torch.float64)  # episodes under way
        self.replay = None  # on-policy: nothing to keep between batches
        self.frames, self.episode_returns = 0, []

    def state_dict(self) -> dict:
        return {**super().state_dict(), "returns_stats": self.returns_stats.state_dict(),
                "discounted_return": self.discounted_return.clone()}

    def load_state_dict(self, state: dict) -> None:
        super().load_state_dict(state)
        self.returns_stats.load_state_dict(state["returns_stats"])
        self.discounted_return.copy_(state["discounted_return"])

    def make_collector(self, frames: int) -> Collector:
        """Whole batches of ``frames_per_batch`` steps (the last may overshoot ``frames``)."""
        per_batch = self.settings["frames_per_batch"]
        return Collector(self.env, self.policy, frames_per_batch=per_batch,
                         total_frames=per_batch * math.ceil(frames / per_batch))

    def scale_rewards(self, reward: torch.Tensor, done: torch.Tensor) -> torch.Tensor:
        """Divides ``reward [E, T, 1]`` by the running standard deviation of the discounted return (updated with
        this batch's returns first) and clips it to +-``reward_clip``."""
        r, d = reward.squeeze(-1).to(torch.float64), done.squeeze(-1)
        returns, g = torch.empty_like(r), self.discounted_return
        for t in range(r.shape[-1]):
            g = g * self.settings["gamma"] + r[:, t]
            returns[:, t] = g
            g = g.masked_fill(d[:, t], 0.0)
        self.discounted_return = g
        self.returns_stats.update(returns.reshape(-1, 1))
        scale = torch.sqrt(self.returns_stats.var + 1e-8).to(reward.dtype)
        return (reward / scale).clamp(-self.settings["reward_clip"], self.settings["reward_clip"])

    def train_on(self, batch: TensorDictBase) -> None:
        """``epochs`` passes of clipped-surrogate minibatch steps over one collected ``[E, T]`` batch; the
        observation statistics take in the batch afterwards, so that every step of it is scored with the
        statistics it was collected with."""
        s = self.settings
        with torch.no_grad():
            batch["next", NORMALIZED_OBS_KEY] = self.normalizer(batch["next", "observation"])
            batch["next", SCALED_REWARD_KEY] = self.scale_rewards(batch["next", "task_reward"], batch["next", "done"])
            self.gae(batch)  # along the last (time) dimension
        batch = batch.reshape(-1)
        for group in self.optim.param_groups:
            group["lr"] = s["lr"] * max(0.0, 1.0 - self.frames / self.total_frames)
        for _ in range(s["epochs"]):
            for idx in torch.randperm(batch.numel()).split(s["minibatch_size"]):
                losses = self.loss(batch[idx])
                total = losses["loss_objective"] + losses["loss_critic"]
                self.optim.zero_grad()
                total.backward()
                nn.utils.clip_grad_norm_(self.loss.parameters(), s["max_grad_norm"])
                self.optim.step()
        self.normalizer.stats.update(batch["observation"].reshape(batch.numel(), -1))
        self.frames += batch.numel()


def make_batched_env(env_id: str, seed: int, num_envs: int) -> TransformedEnv:
    """``num_envs`` copies of ``gym/<env_id>`` (seeds ``seed, seed + 1, ...``) stepped in turn in one process, with
    the bookkeeping transforms applied once to the batch."""
    return with_bookkeeping(SerialEnv(num_envs, [partial(make_gym_env, env_id, seed=seed + i, bookkeeping=False)
                                                 for i in range(num_envs)]))


def train_ppo(env_id: str, frames: int, out: Path, *, seed: int = 0, settings: dict = PPO_SETTINGS, **kwargs) -> dict:
    """A resumable PPO expert run (:func:`~.gym.train_expert`; ``kwargs`` go there: ``eval_episodes``,
    ``progress``, ``save_every``, ``run_dir``). The learning rate anneals over ``frames`` of this call."""
    return train_expert("ppo", env_id, frames, out, partial(_make_run, settings=settings), dict(settings), seed=seed,
                        **kwargs)


def _make_run(env_id: str, seed: int, frames: int, settings: dict) -> PPORun:
    return PPORun(make_batched_env(env_id, seed, settings["num_envs"]), frames, settings=settings)


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description="Train a PPO expert for a gymnasium MuJoCo task.")
    add_expert_arguments(p, default_frames=1_000_000)
    args = p.parse_args(argv)
    return expert_cli("ppo", args, train_ppo)


if __name__ == "__main__":
    main()
