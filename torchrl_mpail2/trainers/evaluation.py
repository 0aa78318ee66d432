"""Evaluation on a fixed set of episodes: the same initial states and the same planner noise in every run.

Episode ``i`` of an evaluation resets the env with seed ``first_seed + i``; a planner acting in it is cleared of
its warm start and draws its sampling noise from a generator seeded the same way. A score then depends only on
the learner's weights, so checkpoints of different runs, seeds and configurations are compared on the same
episodes. Success at any step of an episode (the paper's definition, Appendix "Metrics") is the headline figure.
"""
from __future__ import annotations

import numpy as np
import torch
from tensordict import TensorDict
from torchrl.envs import EnvBase
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_mpail2.envs.keys import EPISODE_RETURN_KEY

__all__ = ["episode_outcome", "evaluate_episodes", "evaluation_seeds", "summarize_outcomes"]

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


@torch.no_grad()
def evaluate_episodes(env: EnvBase, actor, seeds: list[int], planner=None, *, videos: list | None = None,
                      video_episodes: int = 0, rollouts: list | None = None) -> list[dict[str, float]]:
    """Plays one deterministic episode per seed with ``actor``; returns each :func:`episode_outcome`.

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
    """
    saved = (planner.get_extra_state(), planner.generator) if planner is not None else None
    device = next(iter(planner.components.parameters())).device if planner is not None else None
    outcomes = []
    try:
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            for seed in seeds:
                env.set_seed(seed)
                if planner is not None:
                    planner.reset()
                    planner.generator = torch.Generator(device=device).manual_seed(seed)
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
                if rollouts is not None:
                    rollouts.append(episode)
    finally:
        if planner is not None:
            planner.set_extra_state(saved[0])
            planner.generator = saved[1]
    return outcomes


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
