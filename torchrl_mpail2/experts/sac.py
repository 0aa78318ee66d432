"""Experts for the gymnasium MuJoCo tasks, trained with TorchRL's own SAC (:func:`fit_sac`, also used to train
SAC on MPAIL2's learned reward).

    python -m torchrl_mpail2.experts.sac --env Hopper-v5 --frames 150000 --out torchrl_mpail2/assets/experts/Hopper-v5.pt

The expert sees the task reward (it is the demonstrator, not the learner). Its weights file is small
(two 256-wide layers) and holds what :class:`SACExpert` needs to act; demonstrations are then rolled
out from it on demand (``torchrl_mpail2.demos record --env gym/Hopper-v5``). The whole run is checkpointed under
``--run-dir`` (default ``runs/experts/ENV-seedS``) every ``--save-every`` frames; the same command resumes it, and a
larger ``--frames`` trains it further.
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

from torchrl_mpail2.data.checkpoint import (CheckpointError, find_resumable, has_replay, load_replay,
                                             read_checkpoint, rng_state, set_rng_state, write_checkpoint)

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


#: The SAC settings an expert run keeps across resumes (a resumed run refuses others, naming the field).
SAC_SETTINGS = {"hidden": list(HIDDEN), "gamma": 0.99, "tau": 0.005, "lr": 3e-4, "alpha_init": 1.0,
                "num_qvalue_nets": 2, "frames_per_batch": 1000}


class SACRun:
    """TorchRL's ``SACLoss`` (two Q nets, auto alpha, UTD 1) with its optimiser, target update, replay buffer and
    counters: what :func:`fit_sac` trains and what an expert run's checkpoint holds.

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
        self.actor = make_actor(obs_dim, env.action_spec)
        qnet = MLP(in_features=obs_dim + env.action_spec.shape[-1], out_features=1, num_cells=list(HIDDEN),
                   activation_class=nn.ReLU)
        qvalue = ValueOperator(qnet, in_keys=["observation", "action"])
        with torch.no_grad():
            self.actor(env.reset())
        self.loss = SACLoss(self.actor, qvalue, num_qvalue_nets=SAC_SETTINGS["num_qvalue_nets"], loss_function="l2",
                            delay_qvalue=True, alpha_init=SAC_SETTINGS["alpha_init"])
        self.loss.set_keys(reward=reward_key)
        self.loss.make_value_estimator(gamma=SAC_SETTINGS["gamma"])
        self.target = SoftUpdate(self.loss, tau=SAC_SETTINGS["tau"])
        self.optim = torch.optim.Adam(self.loss.parameters(), lr=SAC_SETTINGS["lr"])
        self.replay = TensorDictReplayBuffer(storage=LazyTensorStorage(capacity), batch_size=batch_size)
        self.frames, self.episode_returns = 0, []

    def state_dict(self) -> dict:
        """Networks, targets, ``log_alpha``, optimiser, counters, episode returns and RNG states (the replay buffer
        is written beside it by :func:`~torchrl_mpail2.data.checkpoint.write_checkpoint`)."""
        return {"actor": self.actor.state_dict(), "loss": self.loss.state_dict(), "optim": self.optim.state_dict(),
                "counters": {"frames": self.frames, "episodes": len(self.episode_returns)},
                "episode_returns": list(self.episode_returns), "rng": rng_state()}

    def load_state_dict(self, state: dict) -> None:
        self.loss.load_state_dict(state["loss"])
        self.actor.load_state_dict(state["actor"])
        self.optim.load_state_dict(state["optim"])
        self.frames = int(state["counters"]["frames"])
        self.episode_returns = list(state["episode_returns"])
        set_rng_state(state["rng"])

    def fit(self, frames: int, *, progress: bool = True, desc: str = "SAC", on_frames=None) -> ProbabilisticActor:
        """Collects and trains until ``frames`` environment steps in all (counting those done before a resume);
        one update per collected step once ``warmup`` steps are stored.

        Keyword Args:
            on_frames (callable, optional): ``on_frames(self, recent_returns)`` after each collected batch
                (``recent_returns``: the last 10 finished episodes' summed task rewards).

        Returns:
            the trained actor (stochastic; act with ``ExplorationType.DETERMINISTIC`` for its mean).
        """
        left = frames - self.frames
        if left <= 0:
            return self.actor
        per_batch = min(SAC_SETTINGS["frames_per_batch"], left)
        collector = Collector(self.env, self.actor, frames_per_batch=per_batch, total_frames=left,
                              init_random_frames=max(0, self.warmup - self.frames))
        bar = tqdm(total=frames, initial=self.frames, disable=not progress, desc=desc)
        try:
            for batch in collector:
                self.replay.extend(batch.reshape(-1))
                self.frames += batch.numel()
                ended = batch["next", "done"].squeeze(-1)
                self.episode_returns += batch["next", "episode_task_return"][ended].flatten().tolist()
                if self.frames >= self.warmup:
                    for _ in range(batch.numel()):
                        self.update()
                bar.update(batch.numel())
                recent = self.episode_returns[-10:]
                if recent:
                    bar.set_postfix(ret=f"{sum(recent) / len(recent):.1f}")
                if on_frames is not None:
                    on_frames(self, recent)
        finally:
            bar.close()
            collector.shutdown()
        return self.actor

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
    hook = None if on_frames is None else (lambda r, recent: on_frames(r.actor, r.frames, recent))
    return run.fit(frames, progress=progress, desc=desc, on_frames=hook)


def _run_settings(env_id: str, seed: int, warmup: int, batch_size: int) -> dict:
    return {"env": env_id, "seed": seed, "warmup": warmup, "batch_size": batch_size, **SAC_SETTINGS}


def _check_settings(saved: dict, current: dict, checkpoint: Path) -> None:
    """Refuses to resume ``checkpoint`` with other settings than it was trained with, naming each field."""
    differ = [f"{key}: {saved.get(key)!r} in the checkpoint, {value!r} now" for key, value in current.items()
              if saved.get(key) != value]
    if differ:
        raise CheckpointError(f"cannot resume {checkpoint} with other SAC settings (" + "; ".join(differ) +
                              "): use another --run-dir, or the checkpoint's settings")


def train_sac(env_id: str, frames: int, out: Path, seed: int = 0, warmup: int = 5000, batch_size: int = 256,
              eval_episodes: int = 10, progress: bool = True, save_every: int = 25_000,
              run_dir: Path | None = None) -> dict:
    """Trains a SAC expert on ``gym/<env_id>`` with the task reward and saves its actor to ``out``; returns a
    summary (also written as JSON beside ``out``).

    Every ``save_every`` frames the current actor is saved to ``out`` (marked ``"finished": false``, with the mean
    of the last 10 training episodes' returns), so a run that is stopped early still leaves usable weights. With
    ``run_dir``, the whole run (networks, targets, ``log_alpha``, optimiser, replay buffer, counters, RNG states)
    is checkpointed there too, at the same frames, and a later call with the same ``run_dir`` resumes from it: a
    resumed run starts a fresh episode (the interrupted one is not in the buffer's trajectory count) with the env
    reseeded, and ``frames`` may be raised to train further. ``train_seconds`` adds up over resumes.

    Raises:
        CheckpointError: ``run_dir`` holds a checkpoint trained with other settings (the message names them),
            or a damaged one.
    """
    from torchrl_mpail2.envs import make_env

    settings = _run_settings(env_id, seed, warmup, batch_size)
    torch.manual_seed(seed)
    env = make_env(f"gym/{env_id}", seed=seed)
    obs_dim = env.observation_spec["observation"].shape[-1]
    earlier_s, launches, state = 0.0, 1, None
    checkpoints = Path(run_dir) / "checkpoints" if run_dir is not None else None
    resumable = find_resumable(checkpoints) if checkpoints is not None else None
    if resumable is not None:
        state = read_checkpoint(resumable)
        _check_settings(state["settings"], settings, resumable)
    run = SACRun(env, max(frames, state["counters"]["frames"] if state else 0), batch_size=batch_size, warmup=warmup)
    if state is not None:
        run.load_state_dict(state)
        if has_replay(resumable):
            load_replay(run.replay, resumable)
        earlier_s, launches = state["train_seconds"], state["launches"] + 1
        env.set_seed(seed + run.frames)  # not the episodes the first launch played again
        print(f"resuming {resumable} at frame {run.frames} of {frames}", flush=True)
    start = time.perf_counter()

    def seconds() -> float:
        return earlier_s + time.perf_counter() - start

    def save_now(r: SACRun, recent):
        due = r.frames % save_every < SAC_SETTINGS["frames_per_batch"] or r.frames >= frames if save_every else False
        if due and recent:
            _save(out, env_id, obs_dim, r.actor, {"env": env_id, "frames": r.frames, "seed": seed, "finished": False,
                                                  "train_seconds": seconds(),
                                                  "train_mean_return_last10": sum(recent) / len(recent)})
            if checkpoints is not None:
                write_checkpoint(checkpoints / "last", {**r.state_dict(), "settings": settings,
                                                        "train_seconds": seconds(), "launches": launches}, r.replay)

    actor = run.fit(frames, progress=progress, desc=f"SAC {env_id}", on_frames=save_now)
    returns = evaluate(make_env(f"gym/{env_id}", seed=seed + 10_000), actor, eval_episodes)
    summary = {"env": env_id, "frames": run.frames, "seed": seed, "finished": True, "train_seconds": seconds(),
               "launches": launches, "threads": torch.get_num_threads(), "settings": settings,
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
    p.add_argument("--out", type=Path, default=None, help="the actor's weights file (default: the package's asset)")
    p.add_argument("--run-dir", type=Path, default=None,
                   help="checkpoint folder of the whole run, resumed when it holds one (default: runs/experts/ENV-seedS)")
    p.add_argument("--save-every", type=int, default=25_000, help="frames between saves of the actor and checkpoints")
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
        run_dir = args.run_dir or Path("runs") / "experts" / f"{args.env}-seed{args.seed}"
        summary = train_sac(args.env, args.frames, out, seed=args.seed, warmup=args.warmup, eval_episodes=args.episodes,
                            save_every=args.save_every, run_dir=run_dir)
    print(json.dumps(summary, indent=2))
    return summary


if __name__ == "__main__":
    main()
