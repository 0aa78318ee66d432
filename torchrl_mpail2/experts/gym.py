"""Gymnasium MuJoCo experts: where their weights live, how a training run of either kind (:mod:`.sac`,
:mod:`.ppo`) is checkpointed, resumed, saved and evaluated, and how a saved expert acts.

An expert file (``torchrl_mpail2/assets/experts/<env>.pt``) holds ``{"env", "kind", "obs_dim", "settings",
"actor", "summary"}``: ``kind`` (``"sac"`` or ``"ppo"``; files without it are SAC's) says which policy to
rebuild, ``settings`` the run's settings it is rebuilt with (network sizes; files without them were trained with
the defaults), ``actor`` is that policy's state dict (a PPO policy's includes its observation normaliser). A JSON
twin beside it holds the summary.
"""
from __future__ import annotations

import hashlib
import json
import time
from pathlib import Path
from typing import Callable

import torch
from tensordict import TensorDictBase
from torchrl.envs.utils import ExplorationType, set_exploration_type
from tqdm.auto import tqdm

from torchrl_mpail2.data.checkpoint import (CheckpointError, find_resumable, has_replay, load_replay,
                                             read_checkpoint, rng_state, set_rng_state, write_checkpoint)

ASSET_DIR = Path(__file__).resolve().parents[1] / "assets" / "experts"
#: The kinds of expert and whether a run of each keeps a replay buffer in its checkpoints.
KEEPS_REPLAY = {"sac": True, "ppo": False}
#: The gymnasium tasks that have experts.
GYM_EXPERT_ENVS = ("Hopper-v5", "Ant-v5", "Humanoid-v5")


def make_policy(kind: str, obs_dim: int, action_spec, settings: dict | None = None):
    """The acting module of an expert of ``kind`` (untrained): reads ``"observation"``, writes ``"action"``;
    ``settings`` are the run's (only the network's fields are read; None or missing fields: the kind's defaults)."""
    settings = settings or {}
    if kind == "sac":
        from torchrl_mpail2.experts.sac import SAC_SETTINGS, make_actor
        return make_actor(obs_dim, action_spec, hidden=settings.get("hidden", SAC_SETTINGS["hidden"]))
    if kind == "ppo":
        from torchrl_mpail2.experts.ppo import PPO_SETTINGS
        from torchrl_mpail2.experts.ppo import make_policy as make_ppo_policy
        return make_ppo_policy(obs_dim, action_spec, {**PPO_SETTINGS, **settings})
    raise ValueError(f"unknown expert kind {kind!r}; valid: {', '.join(KEEPS_REPLAY)}")


def expert_fingerprint(env_id: str) -> str:
    """The first 8 hex digits of the sha256 of ``env_id``'s committed expert file (cached demonstrations carry it,
    so that a new expert never reuses an old one's), or ``"none"`` when there is no file."""
    path = ASSET_DIR / f"{env_id}.pt"
    return hashlib.sha256(path.read_bytes()).hexdigest()[:8] if path.exists() else "none"


def evaluate(env, policy, episodes: int) -> list[float]:
    """Task returns of deterministic (mean-action) episodes."""
    returns = []
    with set_exploration_type(ExplorationType.DETERMINISTIC), torch.no_grad():
        for _ in range(episodes):
            traj = env.rollout(10_000, policy, break_when_any_done=True)
            returns.append(float(traj["next", "task_reward"].sum()))
    return returns


def save_expert(out: Path, env_id: str, kind: str, obs_dim: int, policy, summary: dict, settings: dict) -> None:
    """Writes the policy, the settings that rebuild it and its summary atomically (temporary file, then rename), the
    summary also as JSON."""
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".pt.tmp")
    torch.save({"env": env_id, "kind": kind, "obs_dim": obs_dim, "settings": settings, "actor": policy.state_dict(),
                "summary": summary}, tmp)
    tmp.replace(out)
    tmp_json = out.with_suffix(".json.tmp")
    tmp_json.write_text(json.dumps(summary, indent=2))
    tmp_json.replace(out.with_suffix(".json"))


class GymExpert:
    """Deterministic (mean) action of a saved expert; reads ``"observation"``, writes ``"action"``.

    Args:
        path (str or Path): a weights file written by :func:`train_expert` (SAC or PPO).
        action_spec: the env's action spec.

    Raises:
        FileNotFoundError: no file at ``path`` (the message gives the command that trains one).
        ValueError: the file names an unknown expert kind.
    """

    def __init__(self, path: str | Path, action_spec):
        path = Path(path)
        if not path.exists():
            raise FileNotFoundError(f"no expert weights at {path}; train them with "
                                    f"`python -m torchrl_mpail2.experts.ppo --env {path.stem} --out {path}` "
                                    f"(or `python -m torchrl_mpail2.experts.sac --env {path.stem} --out {path}`)")
        state = torch.load(path, map_location="cpu", weights_only=False)
        self.kind = state.get("kind", "sac")  # files from before PPO experts hold SAC actors
        self.obs_dim = state["obs_dim"]
        self.settings = state.get("settings", {})  # files from before they were recorded: the defaults
        self.actor = make_policy(self.kind, self.obs_dim, action_spec, self.settings)
        self.actor.load_state_dict(state["actor"])
        self.summary = state["summary"]

    @torch.no_grad()
    def __call__(self, tensordict: TensorDictBase) -> TensorDictBase:
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            return self.actor(tensordict)


def evaluate_saved(env_id: str, path: Path, episodes: int = 10, seed: int = 0) -> dict:
    """Evaluates a saved expert (e.g. one whose training was stopped early) and records its returns in the file."""
    from torchrl_mpail2.envs import make_env

    env = make_env(f"gym/{env_id}", seed=seed + 10_000)
    expert = GymExpert(path, env.action_spec)
    returns = evaluate(env, expert.actor, episodes)
    summary = {**expert.summary, "eval_returns": returns, "eval_mean_return": sum(returns) / len(returns),
               "eval_episodes": episodes}
    save_expert(path, env_id, expert.kind, expert.obs_dim, expert.actor, summary, expert.settings)
    return summary


class ExpertRun:
    """What a SAC and a PPO expert run share: ``env``, ``policy``, ``loss``, ``optim``, ``replay`` (or ``None``),
    the frame counter and finished episodes' returns, their state dict and the collection loop. Subclasses set
    those in ``__init__`` and define :meth:`make_collector` and :meth:`train_on`."""

    env = policy = loss = optim = replay = None
    frames: int = 0
    episode_returns: list[float]

    def make_collector(self, frames: int):
        """A TorchRL collector over at least ``frames`` more env steps."""
        raise NotImplementedError

    def train_on(self, batch: TensorDictBase) -> None:
        """Takes in one collected batch (and counts its frames)."""
        raise NotImplementedError

    def state_dict(self) -> dict:
        """Policy, loss (networks, targets), optimiser, counters, episode returns and RNG states (a replay buffer
        is written beside it by :func:`~torchrl_mpail2.data.checkpoint.write_checkpoint`)."""
        return {"policy": self.policy.state_dict(), "loss": self.loss.state_dict(), "optim": self.optim.state_dict(),
                "counters": {"frames": self.frames, "episodes": len(self.episode_returns)},
                "episode_returns": list(self.episode_returns), "rng": rng_state()}

    def load_state_dict(self, state: dict) -> None:
        self.loss.load_state_dict(state["loss"])
        self.policy.load_state_dict(state["policy"] if "policy" in state else state["actor"])  # "actor": older SAC runs
        self.optim.load_state_dict(state["optim"])
        self.frames = int(state["counters"]["frames"])
        self.episode_returns = list(state["episode_returns"])
        set_rng_state(state["rng"])

    def fit(self, frames: int, *, progress: bool = True, desc: str = "expert", on_frames=None):
        """Collects and trains until ``frames`` env steps in all (counting those before a resume).

        Keyword Args:
            on_frames (callable, optional): ``on_frames(self, recent_returns)`` after each collected batch
                (``recent_returns``: the last 10 finished episodes' summed task rewards).

        Returns:
            the trained policy (stochastic; act with ``ExplorationType.DETERMINISTIC`` for its mean).
        """
        left = frames - self.frames
        if left <= 0:
            return self.policy
        collector = self.make_collector(left)
        bar = tqdm(total=frames, initial=self.frames, disable=not progress, desc=desc)
        try:
            for batch in collector:
                self.train_on(batch)
                ended = batch["next", "done"].squeeze(-1)
                self.episode_returns += batch["next", "episode_task_return"][ended].flatten().tolist()
                bar.update(batch.numel())
                recent = self.episode_returns[-10:]
                if recent:
                    bar.set_postfix(ret=f"{sum(recent) / len(recent):.1f}")
                if on_frames is not None:
                    on_frames(self, recent)
        finally:
            bar.close()
            collector.shutdown()
        return self.policy


def check_settings(saved: dict, current: dict, checkpoint: Path) -> None:
    """Refuses to resume ``checkpoint`` with other settings than it was trained with, naming each field."""
    differ = [f"{key}: {saved.get(key)!r} in the checkpoint, {value!r} now" for key, value in current.items()
              if saved.get(key) != value]
    if differ:
        raise CheckpointError(f"cannot resume {checkpoint} with other settings (" + "; ".join(differ) +
                              "): use another --run-dir, or the checkpoint's settings")


def train_expert(kind: str, env_id: str, frames: int, out: Path, make_run: Callable, settings: dict, *,
                 seed: int = 0, eval_episodes: int = 10, progress: bool = True, save_every: int = 25_000,
                 run_dir: Path | None = None) -> dict:
    """Trains an expert on ``gym/<env_id>`` with the task reward and saves its policy to ``out``; returns a
    summary (also written as JSON beside ``out``).

    ``make_run(env_id, seed, frames)`` builds the run (:class:`~.sac.SACRun` or :class:`~.ppo.PPORun`) with its
    env (an :class:`ExpertRun`). Every ``save_every`` frames the current policy is saved to ``out`` (marked
    ``"finished": false``, with the mean of the last 10 training episodes' returns), so a run that is stopped
    early still leaves usable weights. With ``run_dir``, the whole run is checkpointed there too,
    at the same frames, and a later call with the same ``run_dir`` resumes from it: a resumed run starts a fresh
    episode with the env reseeded, and ``frames`` may be raised to train further. ``train_seconds`` adds up
    over resumes.

    Raises:
        CheckpointError: ``run_dir`` holds a checkpoint trained with other settings (the message names them),
            or a damaged one.
    """
    from torchrl_mpail2.envs import make_env

    settings = {"kind": kind, "env": env_id, "seed": seed, **settings}
    torch.manual_seed(seed)
    earlier_s, launches, state = 0.0, 1, None
    checkpoints = Path(run_dir) / "checkpoints" if run_dir is not None else None
    resumable = find_resumable(checkpoints, replay=KEEPS_REPLAY[kind]) if checkpoints is not None else None
    if resumable is not None:
        state = read_checkpoint(resumable)
        check_settings(state["settings"], settings, resumable)
    run = make_run(env_id, seed, max(frames, state["counters"]["frames"] if state else 0))
    obs_dim = run.env.observation_spec["observation"].shape[-1]
    if state is not None:
        run.load_state_dict(state)
        if run.replay is not None and has_replay(resumable):
            load_replay(run.replay, resumable)
        earlier_s, launches = state["train_seconds"], state["launches"] + 1
        run.env.set_seed(seed + run.frames)  # not the episodes the first launch played again
        print(f"resuming {resumable} at frame {run.frames} of {frames}", flush=True)
    start = time.perf_counter()
    last_saved = run.frames

    def seconds() -> float:
        return earlier_s + time.perf_counter() - start

    def save_now(r, recent):
        nonlocal last_saved
        due = r.frames - last_saved >= save_every or r.frames >= frames if save_every else False
        if due and recent:
            last_saved = r.frames
            save_expert(out, env_id, kind, obs_dim, r.policy, {"env": env_id, "kind": kind, "frames": r.frames,
                                                               "seed": seed, "finished": False,
                                                               "train_seconds": seconds(),
                                                               "train_mean_return_last10": sum(recent) / len(recent)},
                        settings)
            if checkpoints is not None:
                write_checkpoint(checkpoints / "last", {**r.state_dict(), "settings": settings,
                                                        "train_seconds": seconds(), "launches": launches}, r.replay)

    run.fit(frames, progress=progress, desc=f"{kind.upper()} {env_id}", on_frames=save_now)
    returns = evaluate(make_env(f"gym/{env_id}", seed=seed + 10_000), run.policy, eval_episodes)
    summary = {"env": env_id, "kind": kind, "frames": run.frames, "seed": seed, "finished": True,
               "train_seconds": seconds(), "launches": launches, "threads": torch.get_num_threads(),
               "settings": settings, "eval_returns": returns, "eval_mean_return": sum(returns) / len(returns)}
    save_expert(out, env_id, kind, obs_dim, run.policy, summary, settings)
    return summary


def add_expert_arguments(p, default_frames: int) -> None:
    """The command-line arguments both expert trainers take."""
    p.add_argument("--env", required=True, choices=list(GYM_EXPERT_ENVS))
    p.add_argument("--frames", type=int, default=default_frames)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--run-dir", type=Path, default=None,
                   help="checkpoint folder of the whole run, resumed when it holds one "
                        "(default: runs/experts/KIND-ENV-seedS)")
    p.add_argument("--out", type=Path, default=None,
                   help="the policy's weights file (default: RUN_DIR/expert.pt; copy it over the package's asset, "
                        "torchrl_mpail2/assets/experts/ENV.pt, to make demonstrations from it)")
    p.add_argument("--save-every", type=int, default=25_000, help="frames between saves of the policy and checkpoints")
    p.add_argument("--threads", type=int, default=None, help="torch CPU threads (default: torch's choice)")
    p.add_argument("--evaluate", action="store_true",
                   help="do not train: evaluate the saved expert at --out and record its returns there")
    p.add_argument("--episodes", type=int, default=10, help="evaluation episodes")


def expert_cli(kind: str, args, train: Callable) -> dict:
    """Trains with ``train(env_id, frames, out, seed=, eval_episodes=, save_every=, run_dir=)`` (resuming where
    ``--run-dir`` holds a checkpoint) or, with ``--evaluate``, evaluates the saved expert, from the arguments of
    :func:`add_expert_arguments`; prints and returns the summary."""
    if args.threads:
        torch.set_num_threads(args.threads)
    run_dir = args.run_dir or Path("runs") / "experts" / f"{kind}-{args.env}-seed{args.seed}"
    out = args.out or run_dir / "expert.pt"
    if args.evaluate:
        summary = evaluate_saved(args.env, out, args.episodes, seed=args.seed)
    else:
        summary = train(args.env, args.frames, out, seed=args.seed, eval_episodes=args.episodes,
                        save_every=args.save_every, run_dir=run_dir)
    print(json.dumps(summary, indent=2))
    return summary
