"""Experts for the gymnasium MuJoCo tasks, trained with TorchRL's own SAC (:func:`fit_sac`, also used to train
SAC on MPAIL2's learned reward).

    python -m torchrl_mpail2.experts.sac --env Hopper-v5 --frames 150000 --out torchrl_mpail2/assets/experts/Hopper-v5.pt

The expert sees the task reward (it is the demonstrator, not the learner). Its weights file is small
(two 256-wide layers) and holds what :class:`SACExpert` needs to act; demonstrations are then rolled
out from it on demand (``torchrl_mpail2.demos record --env gym/Hopper-v5``).
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch
from tensordict import TensorDictBase
from tensordict.nn import NormalParamExtractor, TensorDictModule
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import MLP, ProbabilisticActor, TanhNormal, ValueOperator
from torchrl.objectives import SACLoss, SoftUpdate
from tqdm.auto import tqdm

ASSET_DIR = Path(__file__).resolve().parents[1] / "assets" / "experts"
HIDDEN = (256, 256)


def make_actor(obs_dim: int, action_spec) -> ProbabilisticActor:
    """Tanh-Gaussian actor ``observation -> action`` in ``[-1, 1]``."""
    action_dim = action_spec.shape[-1]
    net = nn.Sequential(MLP(in_features=obs_dim, out_features=2 * action_dim, num_cells=list(HIDDEN),
                            activation_class=nn.ReLU), NormalParamExtractor())
    module = TensorDictModule(net, in_keys=["observation"], out_keys=["loc", "scale"])
    return ProbabilisticActor(module, in_keys=["loc", "scale"], spec=action_spec, distribution_class=TanhNormal,
                              distribution_kwargs={"low": -1.0, "high": 1.0}, default_interaction_type=ExplorationType.RANDOM)


def evaluate(env, actor, episodes: int) -> list[float]:
    """Task returns of deterministic (mean) episodes."""
    returns = []
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        for _ in range(episodes):
            traj = env.rollout(10_000, actor, break_when_any_done=True)
            returns.append(float(traj["next", "task_reward"].sum()))
    return returns


def _save(out: Path, env_id: str, obs_dim: int, actor, summary: dict) -> None:
    """Writes the actor and its summary atomically (temporary file, then rename)."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".pt.tmp")
    torch.save({"env": env_id, "obs_dim": obs_dim, "hidden": HIDDEN, "actor": actor.state_dict(), "summary": summary}, tmp)
    tmp.replace(out)
    tmp_json = out.with_suffix(".json.tmp")
    tmp_json.write_text(json.dumps(summary, indent=2))
    tmp_json.replace(out.with_suffix(".json"))


def fit_sac(env, frames: int, *, reward_key: str = "task_reward", warmup: int = 5000, batch_size: int = 256,
            progress: bool = True, desc: str = "SAC", on_frames=None) -> ProbabilisticActor:
    """TorchRL's ``SACLoss`` (two Q nets, auto alpha, UTD 1) on ``env``, learning from ``("next", reward_key)``.

    Args:
        env (EnvBase): an env with an ``"observation"`` vector and a bounded ``[A]`` action; it must write
            ``reward_key`` (the task reward, or e.g. :class:`~torchrl_mpail2.agents.LearnedRewardTransform`'s).
        frames (int): environment steps, the first ``warmup`` of them with random actions.

    Keyword Args:
        on_frames (callable, optional): ``on_frames(actor, frames_done, recent_returns)`` after each collected
            batch (``recent_returns``: the last 10 finished episodes' summed task rewards).

    Returns:
        the trained actor (stochastic; act with ``ExplorationType.DETERMINISTIC`` for its mean).
    """
    if reward_key not in env.full_reward_spec.keys(True, True):
        raise KeyError(f"fit_sac: the env has no reward {reward_key!r}; its rewards: {list(env.reward_keys)}")
    obs_dim = env.observation_spec["observation"].shape[-1]
    actor = make_actor(obs_dim, env.action_spec)
    qnet = MLP(in_features=obs_dim + env.action_spec.shape[-1], out_features=1, num_cells=list(HIDDEN), activation_class=nn.ReLU)
    qvalue = ValueOperator(qnet, in_keys=["observation", "action"])
    with torch.no_grad():
        actor(env.reset())
    loss = SACLoss(actor, qvalue, num_qvalue_nets=2, loss_function="l2", delay_qvalue=True, alpha_init=1.0)
    loss.set_keys(reward=reward_key)
    loss.make_value_estimator(gamma=0.99)
    target = SoftUpdate(loss, tau=0.005)
    optim = torch.optim.Adam(loss.parameters(), lr=3e-4)
    replay = TensorDictReplayBuffer(storage=LazyTensorStorage(frames), batch_size=batch_size)
    collector = Collector(env, actor, frames_per_batch=min(1000, frames), total_frames=frames, init_random_frames=warmup)
    done_frames, episode_returns = 0, []
    bar = tqdm(total=frames, disable=not progress, desc=desc)
    try:
        for batch in collector:
            replay.extend(batch.reshape(-1))
            done_frames += batch.numel()
            ended = batch["next", "done"].squeeze(-1)
            episode_returns += batch["next", "episode_task_return"][ended].flatten().tolist()
            if done_frames >= warmup:
                for _ in range(batch.numel()):
                    losses = loss(replay.sample())
                    total = losses["loss_actor"] + losses["loss_qvalue"] + losses["loss_alpha"]
                    optim.zero_grad()
                    total.backward()
                    optim.step()
                    target.step()
            bar.update(batch.numel())
            recent = episode_returns[-10:]
            if recent:
                bar.set_postfix(ret=f"{sum(recent) / len(recent):.1f}")
            if on_frames is not None:
                on_frames(actor, done_frames, recent)
    finally:
        bar.close()
        collector.shutdown()
    return actor


def train_sac(env_id: str, frames: int, out: Path, seed: int = 0, warmup: int = 5000, batch_size: int = 256,
              eval_episodes: int = 10, progress: bool = True, save_every: int = 25_000) -> dict:
    """Trains a SAC expert on ``gym/<env_id>`` with the task reward and saves its actor; returns a summary (also
    written as JSON).

    Every ``save_every`` frames the current actor is saved (marked ``"finished": false``, with the mean of the
    last 10 training episodes' returns), so a run that is stopped early still leaves usable weights.
    """
    from torchrl_mpail2.envs import make_env

    torch.manual_seed(seed)
    env = make_env(f"gym/{env_id}", seed=seed)
    obs_dim = env.observation_spec["observation"].shape[-1]
    start = time.perf_counter()

    def save_now(actor, done_frames, recent):
        if save_every and done_frames % save_every < min(1000, frames) and recent:
            _save(out, env_id, obs_dim, actor, {"env": env_id, "frames": done_frames, "seed": seed, "finished": False,
                                                 "train_seconds": time.perf_counter() - start,
                                                 "train_mean_return_last10": sum(recent) / len(recent)})

    actor = fit_sac(env, frames, warmup=warmup, batch_size=batch_size, progress=progress, desc=f"SAC {env_id}",
                    on_frames=save_now)
    returns = evaluate(make_env(f"gym/{env_id}", seed=seed + 10_000), actor, eval_episodes)
    summary = {"env": env_id, "frames": frames, "seed": seed, "finished": True,
               "train_seconds": time.perf_counter() - start, "threads": torch.get_num_threads(),
               "eval_returns": returns, "eval_mean_return": sum(returns) / len(returns)}
    _save(out, env_id, obs_dim, actor, summary)
    return summary


def evaluate_saved(env_id: str, path: Path, episodes: int = 10, seed: int = 0) -> dict:
    """Evaluates a saved expert (e.g. one whose training was stopped early) and records its returns in the file."""
    from torchrl_mpail2.envs import make_env

    env = make_env(f"gym/{env_id}", seed=seed + 10_000)
    expert = SACExpert(path, env.action_spec)
    returns = evaluate(env, expert.actor, episodes)
    summary = {**expert.summary, "eval_returns": returns, "eval_mean_return": sum(returns) / len(returns),
               "eval_episodes": episodes}
    _save(path, env_id, expert.obs_dim, expert.actor, summary)
    return summary


class SACExpert:
    """Deterministic (mean) action of a trained SAC actor; reads ``"observation"``, writes ``"action"``.

    Args:
        path (str or Path): a weights file written by :func:`train_sac`.
        action_spec: the env's action spec.
    """

    def __init__(self, path: str | Path, action_spec):
        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(f"no expert weights at {path}; train them with "
                                    f"`python -m torchrl_mpail2.experts.sac --env {path.stem} --out {path}`")
        state = torch.load(path, map_location="cpu", weights_only=False)
        self.obs_dim = state["obs_dim"]
        self.actor = make_actor(self.obs_dim, action_spec)
        self.actor.load_state_dict(state["actor"])
        self.summary = state["summary"]

    @torch.no_grad()
    def __call__(self, tensordict: TensorDictBase) -> TensorDictBase:
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            return self.actor(tensordict)


def main(argv: list[str] | None = None) -> dict:
    p = argparse.ArgumentParser(description="Train a SAC expert for a gymnasium MuJoCo task.")
    p.add_argument("--env", required=True, choices=["Hopper-v5", "Ant-v5", "Humanoid-v5"])
    p.add_argument("--frames", type=int, default=150_000)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--warmup", type=int, default=5000)
    p.add_argument("--out", type=Path, default=None)
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    p.add_argument("--evaluate", action="store_true",
                   help="do not train: evaluate the saved expert at --out and record its returns there")
    p.add_argument("--episodes", type=int, default=10, help="evaluation episodes")
    args = p.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    out = args.out or ASSET_DIR / f"{args.env}.pt"
    if args.evaluate:
        summary = evaluate_saved(args.env, out, args.episodes, seed=args.seed)
    else:
        summary = train_sac(args.env, args.frames, out, seed=args.seed, warmup=args.warmup, eval_episodes=args.episodes)
    print(json.dumps(summary, indent=2))
    return summary


if __name__ == "__main__":
    main()
