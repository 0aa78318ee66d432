"""Experts for the gymnasium MuJoCo tasks, trained with TorchRL's own SAC (:func:`fit_sac`, also used to train
SAC on MPAIL2's learned reward).

    python -m torchrl_mpail2.experts.sac --env Hopper-v5 --frames 150000

The expert sees the task reward (it is the demonstrator, not the learner). Its weights file (``--out``, default
``RUN_DIR/expert.pt``) is small (two 256-wide layers) and holds what :class:`~.gym.GymExpert` needs to act; copied
over ``torchrl_mpail2/assets/experts/ENV.pt``, demonstrations are rolled out from it on demand
(``torchrl_mpail2.demos record --env gym/Hopper-v5``). The whole run, replay buffer included, is checkpointed under
``--run-dir`` (default ``runs/experts/sac-ENV-seedS``) every ``--save-every`` frames (:func:`~.gym.train_expert`);
the same command resumes it, and a larger ``--frames`` trains it further. One update per collected frame costs
about 30 ms on one thread here: :mod:`.ppo` trains experts for far less compute per frame.
"""
from __future__ import annotations

import argparse
from collections.abc import Sequence
from functools import partial
from pathlib import Path

import torch
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs.utils import ExplorationType
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import SACLoss, SoftUpdate

from torchrl_mpail2.experts.gym import ExpertRun, add_expert_arguments, expert_cli, train_expert

HIDDEN = (256, 256)


def make_actor(obs_dim: int, action_spec, hidden: Sequence[int] = HIDDEN) -> ProbabilisticActor:
    """Tanh-Gaussian actor ``observation -> action`` in ``[-1, 1]``."""
    action_dim = action_spec.shape[-1]
    net = nn.Sequential(MLP(in_features=obs_dim, out_features=2 * action_dim, num_cells=list(hidden),
                            activation_class=nn.ReLU), NormalParamExtractor())
    module = TensorDictModule(net, in_keys=["observation"], out_keys=["loc", "scale"])
    return ProbabilisticActor(module, in_keys=["loc", "scale"], spec=action_spec, distribution_class=TanhNormal,
                              distribution_kwargs={"low": -1.0, "high": 1.0}, default_interaction_type=ExplorationType.RANDOM)


#: The SAC settings an expert run keeps across resumes (a resumed run refuses others, naming the field).
SAC_SETTINGS = {"hidden": list(HIDDEN), "gamma": 0.99, "tau": 0.005, "lr": 3e-4, "alpha_init": 1.0,
                "num_qvalue_nets": 2, "frames_per_batch": 1000}


class SACRun(ExpertRun):
    """TorchRL's ``SACLoss`` (two Q nets, auto alpha, UTD 1) with its optimiser, target update, replay buffer and
    counters: what :func:`fit_sac` trains and what an expert run's checkpoint holds (``policy`` is the actor).

    Args:
        env (EnvBase): an env with an ``"observation"`` vector and a bounded ``[A]`` action; it must write
            ``reward_key`` (the task reward, or e.g. :class:`~torchrl_mpail2.agents.LearnedRewardTransform`'s).
        capacity (int): replay capacity (the run's whole frame budget: SAC keeps every step).

    Keyword Args:
        reward_key (str): the reward SAC learns from.
        batch_size (int): transitions per update.
        warmup (int): the first ``warmup`` frames act at random and train nothing.
    """

    def __init__(self, env, capacity: int, *, reward_key: str = "task_reward", batch_size: int = 256,
                 warmup: int = 5000):
        if reward_key not in env.full_reward_spec.keys(True, True):
            raise KeyError(f"fit_sac: the env has no reward {reward_key!r}; its rewards: {list(env.reward_keys)}")
        self.env, self.warmup = env, warmup
        obs_dim = env.observation_spec["observation"].shape[-1]
        self.policy = make_actor(obs_dim, env.action_spec)
        qnet = MLP(in_features=obs_dim + env.action_spec.shape[-1], out_features=1, num_cells=list(HIDDEN),
                   activation_class=nn.ReLU)
        qvalue = ValueOperator(qnet, in_keys=["observation", "action"])
        with torch.no_grad():
            self.policy(env.reset())
        self.loss = SACLoss(self.policy, qvalue, num_qvalue_nets=SAC_SETTINGS["num_qvalue_nets"], loss_function="l2",
                            delay_qvalue=True, alpha_init=SAC_SETTINGS["alpha_init"])
        self.loss.set_keys(reward=reward_key)
        self.loss.make_value_estimator(gamma=SAC_SETTINGS["gamma"])
        self.target = SoftUpdate(self.loss, tau=SAC_SETTINGS["tau"])
        self.optim = torch.optim.Adam(self.loss.parameters(), lr=SAC_SETTINGS["lr"])
        self.replay = TensorDictReplayBuffer(storage=LazyTensorStorage(capacity), batch_size=batch_size)
        self.frames, self.episode_returns = 0, []

    def make_collector(self, frames: int) -> Collector:
        """Batches of up to ``frames_per_batch`` steps, at random until ``warmup`` steps are stored."""
        return Collector(self.env, self.policy, frames_per_batch=min(SAC_SETTINGS["frames_per_batch"], frames),
                         total_frames=frames, init_random_frames=max(0, self.warmup - self.frames))

    def train_on(self, batch) -> None:
        """Stores the batch, then one update per collected step once ``warmup`` steps are stored."""
        self.replay.extend(batch.reshape(-1))
        self.frames += batch.numel()
        if self.frames >= self.warmup:
            for _ in range(batch.numel()):
                self.update()

    def update(self) -> None:
        losses = self.loss(self.replay.sample())
        total = losses["loss_actor"] + losses["loss_qvalue"] + losses["loss_alpha"]
        self.optim.zero_grad()
        total.backward()
        self.optim.step()
        self.target.step()


def fit_sac(env, frames: int, *, reward_key: str = "task_reward", warmup: int = 5000, batch_size: int = 256,
            progress: bool = True, desc: str = "SAC", on_frames=None) -> ProbabilisticActor:
    """Trains a fresh :class:`SACRun` for ``frames`` environment steps and returns its actor (no checkpoints:
    :func:`train_sac` is the resumable expert run).

    Keyword Args:
        on_frames (callable, optional): ``on_frames(actor, frames_done, recent_returns)`` after each collected
            batch (``recent_returns``: the last 10 finished episodes' summed task rewards).
    """
    run = SACRun(env, frames, reward_key=reward_key, batch_size=batch_size, warmup=warmup)
    hook = None if on_frames is None else (lambda r, recent: on_frames(r.policy, r.frames, recent))
    return run.fit(frames, progress=progress, desc=desc, on_frames=hook)


def train_sac(env_id: str, frames: int, out: Path, *, seed: int = 0, warmup: int = 5000, batch_size: int = 256,
              **kwargs) -> dict:
    """A resumable SAC expert run (:func:`~.gym.train_expert`; ``kwargs`` go there: ``eval_episodes``,
    ``progress``, ``save_every``, ``run_dir``)."""
    def make_run(env_id, seed, capacity):
        from torchrl_mpail2.envs import make_env
        return SACRun(make_env(f"gym/{env_id}", seed=seed), capacity, batch_size=batch_size, warmup=warmup)

    settings = {"warmup": warmup, "batch_size": batch_size, **SAC_SETTINGS}
    return train_expert("sac", env_id, frames, out, make_run, settings, seed=seed, **kwargs)


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description="Train a SAC expert for a gymnasium MuJoCo task.")
    add_expert_arguments(p, default_frames=150_000)
    p.add_argument("--warmup", type=int, default=5000, help="random-action frames before the first update")
    p.add_argument("--batch-size", type=int, default=256)
    args = p.parse_args(argv)
    return expert_cli("sac", args, partial(train_sac, warmup=args.warmup, batch_size=args.batch_size))


if __name__ == "__main__":
    main()
