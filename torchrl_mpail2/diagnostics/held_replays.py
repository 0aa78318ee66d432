r"""Back to a held Lift cube in the simulator: the held states a test starts from, their replay from the episode's
seeded reset, and the straight lift from there (:mod:`~torchrl_mpail2.diagnostics.held_plans` scores the same plans
with the learned model)."""
from __future__ import annotations

import numpy as np
import torch
from torchrl.envs.utils import step_mdp

from torchrl_mpail2.diagnostics.lift_phases import hand_height, held_states

__all__ = ["GRIPPER_CLOSING", "check_replay_args", "cube_and_hand_heights", "episode_outcome", "hold_action",
           "played_paths", "replay_to", "straight_lift_from_held_states", "tested_steps"]

#: The gripper command of every held plan: closing (robosuite's Panda gripper closes for positive commands).
GRIPPER_CLOSING = 1.0


def cube_and_hand_heights(obj: torch.Tensor) -> torch.Tensor:
    """``[*B, 2]``: the cube's and the end effector's heights (m) from the ``"object"`` observation."""
    return torch.stack([obj[..., 2], hand_height(obj)], dim=-1)


def tested_steps(rollout, every: int) -> np.ndarray:
    """The held steps a straight lift starts from: every ``every``-th one."""
    return np.flatnonzero(held_states(rollout))[::every]


def episode_outcome(rollout) -> str:
    """``"succeeded"`` if the task's success flag was set at any step, else ``"grasped_without_success"``."""
    succeeded = bool(rollout["next", "success"].any()) if ("next", "success") in rollout.keys(True) else False
    return "succeeded" if succeeded else "grasped_without_success"


def replay_to(env, seed: int, rollout, t: int) -> tuple:
    """Replays ``rollout``'s actions from ``env.set_seed(seed)`` and a reset to the state after step ``t``
    -> ``(tensordict there, whether its observation equals the recorded one)``."""
    env.set_seed(seed)
    td = env.reset()
    for k in range(t + 1):  # after step t the state is rollout["next"][t]
        td = step_mdp(env.step(td.set("action", rollout["action"][k].clone())))
    return td, bool(torch.equal(td["object"], rollout["next", "object"][t]))


def hold_action(env, td, action: torch.Tensor, steps: int) -> tuple[list, bool]:
    """Steps ``action`` ``steps`` times from ``td`` (fewer if the episode ends) -> ``(the observations after each
    step, whether the task succeeded on the way)``."""
    after, succeeded = [], False
    for _ in range(steps):
        stepped = env.step(td.set("action", action.clone()))
        after.append(stepped["next"])
        succeeded = succeeded or bool(stepped["next", "success"].any())
        if bool(stepped["next", "done"].any()):
            break
        td = step_mdp(stepped)
    return after, succeeded


def played_paths(env, seed: int, rollout, t: int, actions, steps: int, keys) -> list | None:
    """From the state after step ``t`` of ``rollout`` (reached by :func:`replay_to`), each of ``actions`` held for
    ``steps`` steps -> one ``[steps + 1]`` tensordict of the observation ``keys`` per action (the start first), or
    None if the episode ended before any of them finished."""
    paths = []
    for action in actions:
        td, _ = replay_to(env, seed, rollout, t)
        after, _ = hold_action(env, td, action.to(rollout["action"].dtype), steps)
        if len(after) < steps:
            return None
        paths.append(torch.stack([td.select(*keys)] + [obs.select(*keys) for obs in after]))
    return paths


def straight_lift_from_held_states(env, seeds: list[int], rollouts: list, every: int = 10,
                                   lift_steps: int = 20) -> dict:
    """From every ``every``-th held state of each rollout (``rollouts[i]`` played from ``env.set_seed(seeds[i])``
    and a reset), replays the recorded actions to that state, then commands ``[0, 0, +1, closing]`` for
    ``lift_steps`` steps -> per outcome group ``{"tested", "lifted", "replay_exact"}`` (shares of the tested states)
    and ``"cube_rise_cm"`` / ``"hand_rise_cm"``: the mean rise above the start after each lift step (an episode that
    ends early keeps its last height)."""
    check_replay_args(seeds, rollouts, every, lift_steps)
    lift = torch.tensor([0.0, 0.0, 1.0, GRIPPER_CLOSING])
    groups: dict[str, list[tuple[bool, bool, np.ndarray]]] = {}
    for seed, rollout in zip(seeds, rollouts):
        for t in tested_steps(rollout, every):
            td, exact = replay_to(env, seed, rollout, t)
            after, lifted = hold_action(env, td, lift.to(rollout["action"].dtype), lift_steps)
            start = cube_and_hand_heights(td["object"].float())
            rises = [(cube_and_hand_heights(obs["object"].float()) - start).numpy() for obs in after]
            rises += rises[-1:] * (lift_steps - len(rises))
            groups.setdefault(episode_outcome(rollout), []).append((lifted, exact, np.stack(rises)))
    result = {}
    for name, rows in groups.items():
        rise_cm = np.mean([r[2] for r in rows], axis=0) * 100
        result[name] = {"tested": len(rows), "lifted": round(float(np.mean([r[0] for r in rows])), 3),
                        "replay_exact": round(float(np.mean([r[1] for r in rows])), 3),
                        "cube_rise_cm": [round(float(v), 2) for v in rise_cm[:, 0]],
                        "hand_rise_cm": [round(float(v), 2) for v in rise_cm[:, 1]]}
    return result


def check_replay_args(seeds, rollouts, every, steps) -> None:
    if len(seeds) != len(rollouts):
        raise ValueError(f"one seed per rollout: {len(seeds)} seeds, {len(rollouts)} rollouts")
    if every < 1 or steps < 1:
        raise ValueError(f"every and the steps played must be >= 1, got {every} and {steps}")
