"""robomimic HDF5 datasets (low-dim and image) as observation-only demonstrations (``train.demos=robomimic:PATH``).

robomimic's ``dataset_states_to_obs.py`` writes one file: a ``data`` group with the attribute ``env_args`` (JSON:
``env_name``, ``env_kwargs`` with ``control_freq``) and per demonstration a group ``demo_N`` holding ``obs/<key>``
(``[T, ...]``, the observation before each action), ``next_obs/<key>`` (after it), ``actions``, ``rewards``,
``dones`` and ``states``; an optional ``mask`` group lists demo names per split (``train``, ``valid``).

Each of this library's keys is assembled from robomimic's keys by :data:`ROBOMIMIC_KEY_MAP` (vectors concatenated
in order; ``"proprio"`` is robosuite's end-effector position, finger joints, joint sin/cos and velocities, as
:class:`~torchrl_mpail2.envs.robosuite_env.RobosuiteEnv` builds it; ``"object"`` is robosuite's object state with
its end-effector offset turned round). Images (``[H, W, 3]``, stored upright: robomimic's env wrapper flips
robosuite's OpenGL-order renders) are moved to ``[3, H, W]`` and resized with antialiasing to the env's size
(robomimic's default is 84 x 84, this library's 64 x 64). The ``T + 1`` observations
of an episode are ``obs`` followed by the last ``next_obs`` (``obs`` alone, ``T`` observations, when the file was
written with ``--exclude-next-obs``). Where the env observes the gripper command, it is advanced from the recorded
actions as the env's own controller would. Actions, rewards and dones are dropped.
"""
from __future__ import annotations

import warnings
from collections.abc import Callable
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch
from tqdm.auto import tqdm

from torchrl_mpail2.data.demos import Demonstrations, demos_from_arrays
from torchrl_mpail2.data.hdf5_files import json_attribute, open_hdf5
from torchrl_mpail2.data.robosuite_hdf5 import sorted_demo_names

__all__ = ["ROBOMIMIC_KEY_MAP", "KeyRule", "import_robomimic"]


class KeyRule(NamedTuple):
    """How one of this library's keys is made from robomimic's: ``sources`` concatenated along the last axis (an
    image key takes one source), then ``convert`` (if given) applied to the ``[T, D]`` result."""

    sources: tuple[str, ...]
    convert: Callable[[np.ndarray], np.ndarray] | None = None


def _relative_position_from_eef(object_state: np.ndarray) -> np.ndarray:
    """robosuite's cube ``object`` state ends with ``gripper_to_cube_pos`` = cube - end effector; this library's
    ``object`` ends with end effector - cube (:meth:`RobosuiteEnv._observation_td`)."""
    out = object_state.copy()
    out[..., -3:] = -out[..., -3:]
    return out


#: This library's observation key -> the rule that assembles it from robomimic's observation keys (Lift; the
#: robosuite names robomimic keeps).
ROBOMIMIC_KEY_MAP: dict[str, KeyRule] = {
    "proprio": KeyRule(("robot0_eef_pos", "robot0_gripper_qpos", "robot0_joint_pos_sin", "robot0_joint_pos_cos",
                        "robot0_joint_vel")),
    "object": KeyRule(("object",), _relative_position_from_eef),
    "external_image": KeyRule(("agentview_image",)),
    "wrist_image": KeyRule(("robot0_eye_in_hand_image",)),
}
def _selected_demos(path: Path, f, filter_key: str | None, max_demos: int | None) -> list[str]:
    if filter_key is None:
        names = list(f["data"].keys())
    else:
        if "mask" not in f or filter_key not in f["mask"]:
            known = sorted(f["mask"].keys()) if "mask" in f else []
            raise ValueError(f"{path}: no filter key {filter_key!r} under 'mask' (known: {known})")
        names = [name.decode() if isinstance(name, bytes) else str(name) for name in f["mask"][filter_key][()]]
    names = sorted_demo_names(names)[:max_demos]
    if not names:
        raise ValueError(f"{path}: no demo_N groups under 'data'" + (f" in split {filter_key!r}" if filter_key else ""))
    return names


def _check_env_args(path: Path, data, base) -> dict:
    """``env_args`` of the file, checked against the env's task and control rate."""
    if "env_args" not in data.attrs:
        raise ValueError(f"{path}: the 'data' group has no 'env_args' attribute (not a robomimic dataset)")
    env_args = json_attribute(path, data.attrs, "env_args")
    if base is None:
        return env_args
    task = env_args.get("env_name")
    if task != base.task:
        raise ValueError(f"{path} was recorded on robosuite task {task!r} (env_args), the env is {base.task!r}")
    recorded_hz = env_args.get("env_kwargs", {}).get("control_freq")
    if recorded_hz is not None and float(recorded_hz) != float(base.sim_env.control_freq):
        raise ValueError(f"{path} was recorded at {recorded_hz} Hz (env_args' control_freq), the env steps at "
                         f"{base.sim_env.control_freq} Hz")
    return env_args


def _chw_resized(images: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """``[N, H, W, 3]`` uint8 -> ``[N, 3, *size]`` uint8 (antialiased bilinear resize where the size differs)."""
    chw = torch.as_tensor(np.ascontiguousarray(images)).permute(0, 3, 1, 2)
    if tuple(chw.shape[-2:]) != tuple(size):
        chw = torch.nn.functional.interpolate(chw.float(), size=size, mode="bilinear", antialias=True,
                                              align_corners=False).round().clamp_(0, 255).to(torch.uint8)
    return chw.numpy()


def _rules(path: Path, keys: list[str], image_sizes: dict, key_map: dict) -> dict[str, KeyRule]:
    """The rule of each of the env's keys (plain tuples made rules), checked once for the whole file."""
    rules = {}
    for key in keys:
        if key not in key_map:
            raise ValueError(f"{path}: the env observes {key!r}, which ROBOMIMIC_KEY_MAP does not map "
                             f"(mapped: {sorted(key_map)}); pass key_map={{{key!r}: KeyRule((robomimic keys...))}}")
        rule = key_map[key] if isinstance(key_map[key], KeyRule) else KeyRule(tuple(key_map[key]))
        if key in image_sizes and len(rule.sources) != 1:
            raise ValueError(f"the image key {key!r} is made of exactly one robomimic key, the key map gives "
                             f"{rule.sources}")
        rules[key] = rule
    return rules


def _episode(path: Path, name: str, demo, rules: dict[str, KeyRule], image_sizes: dict) -> dict | None:
    """The demo's observations in this library's keys, or None for a demo without a transition (fewer than 2)."""
    if "obs" not in demo:
        raise ValueError(f"{path}: {name} has no 'obs' group")
    frames = {}
    for key, rule in rules.items():
        for source in rule.sources:
            if source not in demo["obs"]:
                raise ValueError(f"{path}: {name}/obs has no {source!r}, needed for this library's {key!r} "
                                 f"(its keys: {sorted(demo['obs'].keys())})")
            frames[source] = np.asarray(demo["obs"][source])
            if "next_obs" in demo and source in demo["next_obs"]:
                frames[source] = np.concatenate([frames[source], np.asarray(demo["next_obs"][source][-1:])])
    if min(len(f) for f in frames.values()) < 2:
        return None
    out = {}
    for key, rule in rules.items():
        parts = [frames[source] for source in rule.sources]
        if key in image_sizes:
            out[key] = _chw_resized(parts[0], image_sizes[key])
        else:
            vector = np.concatenate([part.reshape(len(part), -1) for part in parts], axis=-1)
            out[key] = (vector if rule.convert is None else rule.convert(vector)).astype(np.float32)
    return out


def _success(path: Path, name: str, demo) -> bool | None:
    """Whether the demo succeeded at its last step, from robosuite's sparse reward (1 exactly on success steps);
    None, with a warning naming the demo, where its ``rewards`` are missing or empty."""
    rewards = np.asarray(demo["rewards"]) if "rewards" in demo else np.zeros(0)
    if rewards.size == 0:
        warnings.warn(f"{path}: {name}/rewards is missing or empty: the demos' success is not recorded",
                      RuntimeWarning, stacklevel=3)
        return None
    return bool(rewards.reshape(-1)[-1] >= 1.0)


def _gripper_commands(base, actions: np.ndarray, length: int) -> np.ndarray:
    """The gripper command the env observes at each of ``length`` frames (before each action)."""
    base.reset_gripper_command()
    commands = []
    for t in range(length):
        commands.append(base.gripper_command())
        if t < len(actions):
            base.apply_gripper_command(actions[t])
    return np.asarray(commands, dtype=np.float32)[:, None]


def import_robomimic(path: str | Path, env, *, max_demos: int | None = None, filter_key: str | None = None,
                     key_map: dict[str, KeyRule | tuple[str, ...]] | None = None, progress: bool = False) -> Demonstrations:
    """Observation-only demonstrations from a robomimic HDF5 dataset, in ``env``'s keys.

    Args:
        path: the robomimic ``.hdf5`` file (low-dim or image).
        env: the env the demos are for (``make_env("robosuite/Lift", obs=...)``): its observation keys decide what
            is assembled; for this library's robosuite envs the task and control rate must match ``env_args``.

    Keyword Args:
        max_demos (int, optional): import only the first ``max_demos`` demonstrations.
        filter_key (str, optional): import only the demos of this split of the file's ``mask`` (e.g. ``"train"``).
        key_map (dict, optional): entries that replace or extend :data:`ROBOMIMIC_KEY_MAP`: a :class:`KeyRule` or
            a plain tuple of robomimic keys (concatenated, not converted).
        progress (bool): show a progress bar.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ValueError: the file is not a robomimic dataset, is truncated, has an ``env_args`` that is not JSON, was
            recorded on another task or at another control rate, lacks a key the env observes (the file, demo and
            both keys are named), or holds no demo with a transition.

    Warns:
        RuntimeWarning: a demo without a transition is skipped, by name; a demo without rewards leaves the
            success of the demos unrecorded.
    """
    from torchrl_mpail2.envs.keys import observation_keys_of
    from torchrl_mpail2.envs.robosuite_env import robosuite_base

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no robomimic dataset at {path}")
    base = robosuite_base(env)
    keys = observation_keys_of(env)
    command_in_proprio = base is not None and base.observe_gripper_command
    # images are the env's [3, H, W] entries; every other key is a vector
    image_sizes = {key: tuple(env.observation_spec[key].shape[-2:]) for key in keys
                   if len(env.observation_spec[key].shape) == 3}
    rules = _rules(path, keys, image_sizes, {**ROBOMIMIC_KEY_MAP, **(key_map or {})})
    episodes, successes = [], []
    with open_hdf5(path) as f:
        if "data" not in f:
            raise ValueError(f"{path}: no 'data' group (not a robomimic dataset); groups: {list(f.keys())}")
        env_args = _check_env_args(path, f["data"], base)
        # a shaped reward says nothing certain about success
        sparse = env_args.get("env_kwargs", {}).get("reward_shaping") is False
        names = _selected_demos(path, f, filter_key, max_demos)
        kept, skipped = [], []
        for name in tqdm(names, desc=f"reading {path.name}", disable=not progress):
            demo = f["data"][name]
            episode = _episode(path, name, demo, rules, image_sizes)
            if episode is None:
                warnings.warn(f"{path}: {name} holds fewer than 2 observations (no transition): skipped",
                              RuntimeWarning, stacklevel=2)
                skipped.append(name)
                continue
            if command_in_proprio and "proprio" in episode:
                commands = _gripper_commands(base, np.asarray(demo["actions"]), len(episode["proprio"]))
                episode["proprio"] = np.concatenate([episode["proprio"], commands], axis=-1)
            episodes.append(episode)
            kept.append(name)
            successes.append(_success(path, name, demo) if sparse else None)
    if not episodes:
        raise ValueError(f"{path}: none of its demos holds a transition (all skipped: {skipped})")
    env_id = f"robosuite/{base.task}" if base is not None else "custom"
    demos = demos_from_arrays(episodes, env_id=env_id,
                              success=successes if None not in successes else None)
    demos.header["source"] = {"format": "robomimic", "path": str(path.resolve()), "demos": kept, "skipped": skipped,
                              "filter_key": filter_key, "dropped": ["actions", "rewards", "dones", "states"]}
    return demos
