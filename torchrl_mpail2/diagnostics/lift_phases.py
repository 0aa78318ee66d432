"""Where Lift episodes fail: how far each evaluation episode gets through reach, grasp, lift and success.

Read from the episode's own observations (robosuite Lift, ``"state"`` mode: ``"proprio"`` holds the finger joints
at ``[3:5]``, ``"object"`` the cube position at ``[0:3]`` and the end effector's offset from the cube at ``[7:10]``;
a camera run's evaluation env gets the same ``"object"`` vector from the simulator,
:class:`~torchrl_mpail2.envs.robosuite_env.SimulatorObject`, which its agent does not read):

* ``reach``: the end effector came within :data:`REACH_M` of the cube's centre;
* ``grasp``: while within reach, the fingers were closed onto something: their opening at least :data:`CLOSED_BY_M`
  below its largest value so far in the episode (closing; they start half open) but above :data:`SHUT_M` (stopped
  by the cube);
* ``lift``: the cube rose :data:`LIFT_M` above where it rests on the table (robosuite drops it from 1 cm above the
  table at reset; it settles by step :data:`SETTLED_STEP`, and heights are measured from there);
* ``success``: the task's own success flag at any step (the cube's centre 4 cm above the table: about 2.1 cm above
  where it rests).

Also per episode: the closest approach (cm), the cube's highest rise above its resting height (cm), the first step at
which the fingers were closing, and, for episodes that grasped, how far the hand rose after the first grasp
(``hand_rise_after_grasp_cm``: the hand's highest point after the grasp minus its height at the grasp), for how
many steps the fingers held something within reach (``grasped_steps``), and the mean action taken in those held
states (``held_action``: ``[x, y, z, gripper]``, z > 0 up, gripper > 0 closing). A hand that rose well past 2 cm while
the cube did not follow let it slip; a hand that stayed down never tried to lift::

    python -m torchrl_mpail2.diagnostics lift_phases RUN/checkpoints/episode_000300 [...] --episodes 20 --out F.json

``--planner planner.num_candidates=512 ...`` plays the same episodes with another planner than the run trained with
(the networks unchanged): does a larger planner at evaluation time lift more cubes? ``--acting random`` plays
them with the action sampled around the plan's mean as in training (the evaluation's noise generator, seeded per
episode) instead of the mean: does a run that lifts in training but not in evaluation lift when it explores?
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import torch
from tensordict import TensorDictBase

__all__ = ["cube_rise_m", "grasped_without_success", "hand_height", "held_states", "lift_phases", "play_lift_episodes",
           "summarize_phases", "use_planner_settings"]

REACH_M = 0.02
#: Panda finger opening (left minus right joint): 0.043 m at reset, about 0.078 m wide open, 0.003 m shut on
#: nothing, about 0.05 m on the cube.
CLOSED_BY_M, SHUT_M = 0.005, 0.01
LIFT_M = 0.01
#: The step (of ``("next", ...)``) by which the dropped cube has settled: -1.15, -1.27, -1.14, -1.08, -1.05, -1.03 and
#: then -1.02 cm below its reset height at steps 0-6 with the hand still. The hand starts 18-20 cm away and moves
#: at most about 1.3 cm per step, so it cannot have touched the cube by then.
SETTLED_STEP = 5
PHASES = ("reach", "grasp", "lift", "success")


def _check_state_keys(rollout: TensorDictBase) -> None:
    for key in ("proprio", "object"):
        if ("next", key) not in rollout.keys(include_nested=True):
            raise ValueError(f"lift_phases reads ('next', {key!r}) of a robosuite/Lift rollout in 'state' mode; the "
                           f"rollout has {sorted(str(k) for k in rollout.keys(include_nested=True, leaves_only=True))}")


def _reach_closing_held(proprio: np.ndarray, obj: np.ndarray) -> tuple[np.ndarray, ...]:
    """Per step: end-effector-to-cube distance, within reach, fingers closing, fingers held on something in reach."""
    from torchrl_mpail2.envs.robosuite_observations import OBJECT_EEF_TO_CUBE

    distance = np.linalg.norm(obj[:, OBJECT_EEF_TO_CUBE], axis=-1)
    opening = proprio[:, 3] - proprio[:, 4]
    near, closing = distance < REACH_M, opening < np.maximum.accumulate(opening) - CLOSED_BY_M
    return distance, near, closing, near & closing & (opening > SHUT_M)


def cube_rise_m(obj: np.ndarray) -> np.ndarray:
    """``[T]``: the cube's height above where it settled (step :data:`SETTLED_STEP`), from ``"object"`` ``[T, D]``."""
    return obj[:, 2] - obj[min(SETTLED_STEP, len(obj) - 1), 2]


def hand_height(obj):
    """``[*B]``: the end effector's height (m) from the ``"object"`` observation ``[*B, D]`` (array or tensor)."""
    from torchrl_mpail2.envs.robosuite_observations import OBJECT_EEF_TO_CUBE

    return obj[..., 2] + obj[..., OBJECT_EEF_TO_CUBE][..., 2]


def held_states(rollout: TensorDictBase) -> np.ndarray:
    """``[T]`` booleans: after step ``t`` (``rollout["next"][t]``) the fingers hold something within reach of the
    cube (the ``grasp`` phase's test)."""
    _check_state_keys(rollout)
    return _reach_closing_held(rollout["next", "proprio"].numpy(), rollout["next", "object"].numpy())[3]


def lift_phases(rollout: TensorDictBase) -> dict:
    """The phases one Lift episode reached, from its rollout ``[T]`` (``rollout()`` output: observations and
    ``("next", ...)``). Raises ``ValueError`` naming a missing key (``"proprio"`` / ``"object"``: state mode)."""
    _check_state_keys(rollout)
    proprio, obj = rollout["next", "proprio"].numpy(), rollout["next", "object"].numpy()
    distance, near, closing, held = _reach_closing_held(proprio, obj)
    rise = cube_rise_m(obj)
    hand_z = hand_height(obj)
    first_grasp = int(np.argmax(held)) if held.any() else None
    held_actions = rollout["action"].numpy()[1:][held[:-1]]  # the action taken in each held state
    success = rollout.get(("next", "success"), None)
    return {
        "reach": bool(near.any()),
        "grasp": first_grasp is not None,
        "lift": bool((rise > LIFT_M).any()),
        "success": bool(success.any()) if success is not None else None,
        "closest_cm": round(float(distance.min()) * 100, 1),
        "highest_rise_cm": round(float(rise.max()) * 100, 1),
        "first_closing_step": int(np.argmax(closing)) if closing.any() else None,
        "first_grasp_step": first_grasp,
        "grasped_steps": int(held.sum()),
        "hand_rise_after_grasp_cm": (round(float(hand_z[first_grasp:].max() - hand_z[first_grasp]) * 100, 1)
                                     if first_grasp is not None else None),
        "held_action": [round(float(a), 2) for a in held_actions.mean(0)] if len(held_actions) else None,
    }


def summarize_phases(episodes: list[dict]) -> dict:
    """The share of episodes that reached each phase."""
    return {phase: float(np.mean([bool(e[phase]) for e in episodes])) for phase in PHASES if episodes}


def grasped_without_success(episodes: list[dict]) -> list[dict]:
    """The episodes that grasped the cube and never succeeded: how high the cube and the hand rose after the grasp
    (cm) and how many steps the fingers held it."""
    keys = ("highest_rise_cm", "hand_rise_after_grasp_cm", "grasped_steps", "held_action")
    return [{k: e[k] for k in keys} for e in episodes if e["grasp"] and not e["success"]]


def _check_planner_overrides(overrides) -> None:
    from torchrl_mpail2.config import ConfigError

    outside = [o for o in overrides if not o.startswith("planner.")]
    if outside:
        raise ConfigError(f"--planner takes planner.FIELD=VALUE overrides only, got {outside}")


def use_planner_settings(agent, overrides) -> None:
    """Gives ``agent``'s planner the run's planner settings (``agent.run_config``) changed by ``overrides``
    (``planner.FIELD=VALUE`` strings, checked like any config override); the networks are untouched."""
    from torchrl_mpail2.config import ExperimentConfig, apply_overrides

    _check_planner_overrides(overrides)
    if overrides:
        agent.planner.cfg = apply_overrides(ExperimentConfig.from_dict(agent.run_config), list(overrides)).planner


def play_lift_episodes(path: str | Path, episodes: int, planner_overrides: list[str] = (),
                       acting: str = "deterministic") -> tuple:
    """Plays the run's first ``episodes`` fixed evaluation episodes with the checkpoint's planner (changed by
    ``planner_overrides``, ``planner.FIELD=VALUE`` strings), acting as ``acting`` says (``evaluate_episodes``)
    -> ``(agent, rollouts)``. Refuses runs other than robosuite/Lift with ``"proprio"`` observed (``"state"`` or
    ``"pixels"``: a camera run's env gets :class:`~torchrl_mpail2.envs.robosuite_env.SimulatorObject`), naming
    them."""
    from torchrl_mpail2.agents import MPAIL2Agent
    from torchrl_mpail2.trainers.evaluation import evaluate_episodes, evaluation_env, evaluation_seeds, run_eval_seed

    _check_planner_overrides(planner_overrides)
    agent = MPAIL2Agent.from_checkpoint(path)
    use_planner_settings(agent, planner_overrides)
    train = agent.run_config["train"]
    if train["env"] != "robosuite/Lift" or train["obs"] not in ("state", "pixels"):
        raise ValueError(f"{path}: lift_phases reads robosuite/Lift runs in 'state' or 'pixels' mode, this run is "
                         f"{train['env']} with obs {train['obs']!r}")
    env = evaluation_env(train)  # the run's own evaluation env (the same cube as its evaluations)
    from torchrl_mpail2.envs.robosuite_env import with_simulator_object

    env = with_simulator_object(env)
    rollouts: list = []
    evaluate_episodes(env, agent.policy, evaluation_seeds(run_eval_seed(train), episodes), agent.planner,
                      rollouts=rollouts, acting=acting)
    env.close()
    return agent, rollouts


def evaluate_checkpoint(path: str | Path, episodes: int, planner_overrides: list[str] = (),
                        acting: str = "deterministic") -> dict:
    """:func:`play_lift_episodes` -> the phases of each episode and their shares."""
    _, rollouts = play_lift_episodes(path, episodes, planner_overrides, acting)
    per_episode = [lift_phases(rollout) for rollout in rollouts]
    return {"checkpoint": str(path), "episodes": episodes, "planner_overrides": list(planner_overrides),
            "acting": acting, "phases": summarize_phases(per_episode),
            "grasped_without_success": grasped_without_success(per_episode), "per_episode": per_episode}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m torchrl_mpail2.diagnostics lift_phases",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="+", help="checkpoint folders of robosuite/Lift runs (state or cameras)")
    parser.add_argument("--episodes", type=int, default=20, help="the run's first N fixed evaluation episodes")
    parser.add_argument("--out", help="write the results to this JSON file")
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--planner", nargs="+", default=[], metavar="planner.FIELD=VALUE",
                        help="play with these planner settings instead of the run's (e.g. planner.num_candidates=512)")
    from torchrl_mpail2.trainers.evaluation import ACTING

    parser.add_argument("--acting", choices=sorted(ACTING), default="deterministic",
                        help="the plan's mean (the evaluation's default) or the action sampled around it as in training")
    args = parser.parse_args(argv)
    torch.set_num_threads(args.threads)
    results = []
    print(f"{'checkpoint':60s} " + " ".join(f"{p:>7s}" for p in PHASES))
    for path in args.checkpoints:
        result = evaluate_checkpoint(path, args.episodes, args.planner, args.acting)
        results.append(result)
        print(f"{path[-60:]:60s} " + " ".join(f"{result['phases'][p]:7.2f}" for p in PHASES), flush=True)
        for episode in result["grasped_without_success"]:
            print(f"  grasped, no success: cube rose {episode['highest_rise_cm']} cm, hand "
                  f"{episode['hand_rise_after_grasp_cm']} cm after the grasp, held {episode['grasped_steps']} steps, "
                  f"mean action there {episode['held_action']}")
    if args.out:
        Path(args.out).write_text(json.dumps(results, indent=1) + "\n")
        print(f"wrote {args.out}")
