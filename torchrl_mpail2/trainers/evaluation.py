"""Evaluation on a fixed set of episodes: the same initial states and the same planner noise in every run.

Episode ``i`` of an evaluation resets the env with seed ``first_seed + i``; a planner acting in it is cleared of
its warm start and draws its sampling noise from a generator seeded the same way. A score then depends only on
the learner's weights, so checkpoints of different runs, seeds and configurations are compared on the same
episodes. Success at any step of an episode (the paper's definition, Appendix "Metrics") is the headline figure.

With several environments (``train.eval_envs``), :func:`evaluate_episodes_lockstep` plays the episodes that many at
a time, the planner acting on all of them in one batched call (on a GPU a batch of 16 plans about as fast as one).
The initial states are the same; the planner's noise is drawn per batch, so scores compare between evaluations
played with the same number of environments.
"""
from __future__ import annotations

import contextlib
import json
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDict
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp
from tqdm.auto import tqdm

from torchrl_mpail2.config import DEFAULT_EVAL_SEED, EVAL_ACTINGS
from torchrl_mpail2.envs.keys import EPISODE_RETURN_KEY

__all__ = ["DEFAULT_EVAL_SEED", "episode_outcome", "evaluate_episodes", "evaluate_episodes_lockstep",
           "evaluation_env", "evaluation_seeds", "run_eval_seed", "run_evaluation_env", "summarize_outcomes"]

#: Safety cap on an evaluation episode's length (the envs end their episodes themselves).
MAX_EVAL_STEPS = 100_000


def episode_outcome(episode: TensorDict) -> dict[str, float]:
    """Success at the last step, success at any step (the paper's definition) and task return of one episode."""
    success = episode["next", "success"]
    return {"success": float(success[-1].item()), "success_any_step": float(success.any().item()),
            "task_return": float(episode["next", EPISODE_RETURN_KEY][-1].item())}


def evaluation_seeds(first_seed: int, episodes: int) -> list[int]:
    """Seeds of the fixed evaluation episodes: ``first_seed + i``."""
    return [first_seed + i for i in range(episodes)]


#: First seed of the held-out episodes is ``train.eval_seed`` plus this: clear of any fixed evaluation set.
HELD_OUT_SEED_OFFSET = 100_000


def run_eval_seed(train: Mapping) -> int:
    """A saved run's ``train.eval_seed`` (:data:`DEFAULT_EVAL_SEED` for runs saved before it existed)."""
    return train.get("eval_seed", DEFAULT_EVAL_SEED)


def evaluation_env(train: Mapping) -> EnvBase:
    """The environment a run's own evaluations play in, rebuilt from its saved ``train`` section (``env``, ``obs``,
    ``env_kwargs``, ``eval_seed``): constructed with seed ``eval_seed``, as the trainer builds its evaluation env.

    The construction seed matters beside the per-episode seeds: robosuite draws Lift's cube size once, when the env
    is built (``hard_reset=False``), so an env built with another seed plays the same initial states with a cube up
    to about 2 mm different, and a checkpoint re-evaluated in it can score otherwise than in its run."""
    from torchrl_mpail2.envs import make_env

    return make_env(train["env"], obs=train["obs"], seed=run_eval_seed(train),
                    **(train.get("env_kwargs") or {}))


def run_evaluation_env(run_dir: Path) -> tuple[EnvBase, dict]:
    """A run folder's :func:`evaluation_env` and the ``train`` section of its ``config.json`` it was built from."""
    train = json.loads((Path(run_dir) / "config.json").read_text())["train"]
    return evaluation_env(train), train


@torch.no_grad()
def evaluate_episodes(env: EnvBase, actor, seeds: list[int], planner=None, *, videos: list | None = None,
                      video_episodes: int = 0, rollouts: list | None = None,
                      acting: str = "deterministic", progress: bool = False) -> list[dict[str, float]]:
    """Plays one episode per seed with ``actor`` (deterministic by default); returns each :func:`episode_outcome`.

    Args:
        env (EnvBase): the evaluation environment (batch size ``[]``).
        actor: a TensorDict policy writing ``"action"``.
        seeds (list[int]): one env seed per episode (:func:`evaluation_seeds`).
        planner (LatentMPPIPlanner, optional): the planner inside ``actor``, if any: its warm start is cleared and
            its noise seeded per episode; its warm start and generator are restored afterwards.

    Keyword Args:
        videos (list, optional): receives the frames ``[T + 1, H, W, 3]`` uint8 (``env.render()`` after the reset
            and after each step) of the first ``video_episodes`` episodes.
        rollouts (list, optional): receives each episode's rollout tensordict ``[T]``.
        acting (str): ``"deterministic"`` (the plan's mean, the evaluation of every recorded result) or ``"random"``
            (the action sampled around it as in training, the noise still drawn from the per-episode seeded
            generator).
        progress (bool): a progress bar over the episodes, with the any-step success so far. Defaults to False.
    """
    outcomes = []
    bar = tqdm(seeds, desc="evaluation", unit="episode", disable=not progress)
    with _evaluation_planner(planner, acting) as start_episode:
        for seed in bar:
            env.set_seed(seed)
            start_episode(seed)
            if videos is not None and len(outcomes) < video_episodes:
                start = env.reset()
                frames = [env.render()]
                episode = env.rollout(MAX_EVAL_STEPS, actor, break_when_any_done=True, auto_reset=False,
                                      tensordict=start, callback=lambda env_, td: frames.append(env_.render()))
                frames.append(env.render())  # torchrl calls the callback on every step but the last
                videos.append(np.stack(frames))
            else:
                episode = env.rollout(MAX_EVAL_STEPS, actor, break_when_any_done=True)
            outcomes.append(episode_outcome(episode))
            bar.set_postfix(success=f"{sum(o['success_any_step'] for o in outcomes) / len(outcomes):.2f}")
            if rollouts is not None:
                rollouts.append(episode)
    return outcomes


@torch.no_grad()
def evaluate_episodes_lockstep(envs: Sequence[EnvBase], actor, seeds: list[int], planner=None, *,
                               videos: list | None = None, video_episodes: int = 0,
                               rollouts: list | None = None, acting: str = "deterministic") -> list[dict[str, float]]:
    """:func:`evaluate_episodes` played ``len(envs)`` episodes at a time, in lockstep.

    Episode ``i`` still starts from seed ``seeds[i]``'s initial state (each env of a batch is seeded like the one env
    of :func:`evaluate_episodes`). ``actor`` acts on the stacked observations ``[b]`` of a batch in one call; a
    planner is cleared of its warm start per batch and draws its noise from one generator seeded with the batch's
    first seed, so an episode's outcome depends on the episodes that share its batch: compare scores between
    evaluations played with the same number of envs (with one env this is :func:`evaluate_episodes`, step for step).
    An episode that ends before the others of its batch is not stepped again; its slot is planned for (from its
    last observation) and the action dropped until the batch's last episode ends.

    Args:
        envs (sequence of EnvBase): the evaluation environments (batch size ``[]`` each, on one device).
        actor, seeds, planner, videos, video_episodes, rollouts, acting: as in :func:`evaluate_episodes`.
    """
    if not envs:
        raise ValueError("evaluate_episodes_lockstep needs at least one environment")
    outcomes = []
    with _evaluation_planner(planner, acting) as start_episode:
        for first in range(0, len(seeds), len(envs)):
            batch = list(zip(envs, seeds[first:first + len(envs)]))
            current = []
            for env, seed in batch:
                env.set_seed(seed)
                current.append(env.reset())
            start_episode(batch[0][1])
            filmed = [videos is not None and first + i < video_episodes for i in range(len(batch))]
            frames = [[env.render()] if film else None for (env, _), film in zip(batch, filmed)]
            steps: list[list] = [[] for _ in batch]
            running = [True] * len(batch)
            for _ in range(MAX_EVAL_STEPS):
                acted = actor(torch.stack(current))
                for i, (env, _) in enumerate(batch):
                    if not running[i]:
                        continue
                    stepped = env.step(acted[i])
                    steps[i].append(stepped)
                    if frames[i] is not None:
                        frames[i].append(env.render())
                    running[i] = not bool(stepped["next", "done"].any())
                    current[i] = step_mdp(stepped, reward_keys=env.reward_keys, done_keys=env.done_keys,
                                          action_keys=env.action_keys)
                if not any(running):
                    break
            for i, episode_steps in enumerate(steps):
                episode = torch.stack(episode_steps)
                outcomes.append(episode_outcome(episode))
                if rollouts is not None:
                    rollouts.append(episode)
                if frames[i] is not None:
                    videos.append(np.stack(frames[i]))
    return outcomes


#: Evaluation acting modes (:data:`~torchrl_mpail2.config.EVAL_ACTINGS`) -> torchrl exploration types.
ACTING = dict(zip(EVAL_ACTINGS, (ExplorationType.DETERMINISTIC, ExplorationType.RANDOM)))


@contextlib.contextmanager
def _evaluation_planner(planner, acting: str = "deterministic"):
    """Acting as ``acting`` says (:data:`ACTING`); yields ``start_episode(seed)``, which clears the planner's warm
    start and seeds its noise. The planner's warm start and generator are restored afterwards. Acting ``random``,
    the global generators are seeded per episode too (inside a fork, restored afterwards), so an actor that samples
    from them (a policy without a planner) also plays the same episodes each time."""
    if acting not in ACTING:
        raise ValueError(f"acting must be one of {sorted(ACTING)}, got {acting!r}")
    saved = (planner.get_extra_state(), planner.generator) if planner is not None else None
    device = next(iter(planner.components.parameters())).device if planner is not None else None
    sampled = acting == "random"

    def start_episode(seed: int) -> None:
        if planner is not None:
            planner.reset()
            planner.generator = torch.Generator(device=device).manual_seed(seed)
        if sampled:
            torch.manual_seed(seed)

    forked = (torch.random.fork_rng(devices=list(range(torch.cuda.device_count())) if torch.cuda.is_initialized() else [])
              if sampled else contextlib.nullcontext())
    try:
        with forked, set_exploration_type(ACTING[acting]):
            yield start_episode
    finally:
        if planner is not None:
            planner.set_extra_state(saved[0])
            planner.generator = saved[1]


def summarize_outcomes(outcomes: list[dict[str, float]]) -> dict:
    """The headline figures of :func:`evaluate_episodes`' outcomes: ``success_rate_any_step`` (the paper's
    definition), ``success_rate`` (at the last step), mean ``return``, ``episodes`` and the per-episode any-step
    successes."""
    if not outcomes:
        raise ValueError("no evaluation episodes to summarise")
    mean = {key: sum(o[key] for o in outcomes) / len(outcomes) for key in outcomes[0]}
    return {"success_rate_any_step": mean["success_any_step"], "success_rate": mean["success"],
            "return": mean["task_return"], "episodes": len(outcomes),
            "success_any_step_per_episode": [o["success_any_step"] for o in outcomes]}
