"""Recording observation-only demonstrations from an expert acting in an environment."""
from __future__ import annotations

from pathlib import Path

import torch
from torchrl.envs import EnvBase
from tqdm.auto import tqdm

from torchrl_mpail2.data.demo_files import save_demos
from torchrl_mpail2.data.demos import Demonstrations, assemble_demonstrations
from torchrl_mpail2.envs.keys import observation_keys_of, pictures_of

__all__ = ["record_demos"]


def record_demos(
    env: EnvBase,
    expert,
    episodes: int,
    out: str | Path | None = None,
    seed: int = 0,
    progress: bool = True,
    *,
    env_id: str | None = None,
    env_kwargs: dict | None = None,
    max_steps: int = 10_000,
    overwrite: bool = False,
    steps_after_success: int | None = None,
) -> Demonstrations:
    """Rolls an expert out and keeps only the observations.

    Episode ``i`` is reset with seed ``seed + i`` (env seed and, inside a forked RNG scope, the
    global torch seed, so stochastic experts are reproducible too): the same ``seed`` gives
    identical data. Kept keys: those of :func:`~torchrl_mpail2.envs.keys.observation_keys_of` (the
    observation spec minus success, reward and bookkeeping keys). Actions and rewards are dropped; per-episode metadata keeps the success at
    the last step, the task return (reporting only), the length and the seed.

    Args:
        env (EnvBase): an env with an empty batch size (one episode at a time).
        expert: callable ``tensordict -> tensordict`` writing ``"action"``; its ``reset()``, if it
            has one, is called before each episode.
        episodes (int): number of episodes.
        out (str or Path, optional): if given, the demos are also saved there (:func:`save_demos`).
        seed (int): seed of the first episode. Defaults to 0.
        progress (bool): show a tqdm progress bar. Defaults to ``True``.

    Keyword Args:
        env_id (str, optional): name stored in the header; defaults to the base env's class name.
        env_kwargs (dict, optional): how the env was built (e.g. ``{"obs": "state"}``), stored in the header.
        max_steps (int): safety cap on episode length if the env never ends an episode.
        overwrite (bool): replace an existing ``out`` directory.
        steps_after_success (int, optional): end each recording this many steps after its first success (as a
            teleoperator stops recording), instead of at the env's horizon. ``None`` keeps whole episodes.

    Examples:
        >>> from torchrl_mpail2.envs import make_env
        >>> from torchrl_mpail2.experts import PointMassExpert
        >>> demos = record_demos(make_env("point_mass"), PointMassExpert(), episodes=2, progress=False)
        >>> demos.episode_lengths, demos.success_rate, "action" in demos.observations.keys()
        ([50, 50], 1.0, False)
    """
    if env.batch_size != torch.Size([]):
        raise ValueError(f"record_demos needs an env with an empty batch size, got {tuple(env.batch_size)}")
    if episodes < 1:
        raise ValueError(f"episodes must be >= 1, got {episodes}.")
    if steps_after_success is not None and steps_after_success < 0:
        raise ValueError(f"steps_after_success must be >= 0 or None, got {steps_after_success}.")
    keys = observation_keys_of(env)
    if env_id is None:
        env_id = type(getattr(env, "base_env", env)).__name__
    has_success = "success" in env.observation_spec.keys()
    reward_key = "task_reward" if "task_reward" in env.reward_keys else env.reward_key

    recorded, metadata = [], []
    bar = tqdm(range(episodes), desc=f"recording {env_id}", disable=not progress)
    for i in bar:
        episode_seed = seed + i
        with torch.random.fork_rng(devices=[]), torch.no_grad():
            torch.manual_seed(episode_seed)
            env.set_seed(episode_seed)
            if callable(getattr(expert, "reset", None)):
                expert.reset()
            rollout = env.rollout(max_steps, policy=expert, break_when_any_done=True)
        if steps_after_success is not None and has_success:
            success = rollout["next", "success"].reshape(-1)
            if success.any():
                rollout = rollout[: int(success.float().argmax()) + 1 + steps_after_success]
        recorded.append({key: torch.cat([rollout[key], rollout["next", key][-1:]]) for key in keys})
        metadata.append(
            {
                "success": bool(rollout["next", "success"][-1].item()) if has_success else None,
                "task_return": float(rollout["next", reward_key].sum().item()),
                "seed": episode_seed,
            }
        )
        successes = [meta["success"] for meta in metadata if meta["success"] is not None]
        if successes:
            bar.set_postfix(success=f"{sum(successes) / len(successes):.2f}")
    demos = assemble_demonstrations(recorded, metadata, env_id=env_id, env_kwargs=env_kwargs, pictures=pictures_of(env))
    if out is not None:
        save_demos(demos, out, overwrite=overwrite)
    return demos
