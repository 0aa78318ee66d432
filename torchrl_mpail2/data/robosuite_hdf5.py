"""robosuite's own teleoperation recordings (``demo.hdf5``) as observation-only demonstrations.

robosuite's ``collect_human_demonstrations`` script (space mouse or keyboard, the way the paper's demonstrations
were made) writes one ``demo.hdf5``: a ``data`` group with attributes ``env`` (the task class) and ``env_info``
(JSON: the env's settings), and per demonstration a group ``demo_N`` holding ``states`` (flattened mujoco states,
``[T, S]``: ``states[t]`` is the state before ``actions[t]``), ``actions`` (``[T, A]``) and the MJCF model under
the attribute ``model_file``. There are no observations in it: each state is replayed through this library's
environment, which computes exactly its own observation keys (camera images included). Actions are used only to
advance the gripper command where the env observes it; they and any rewards are dropped.
"""
from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from torchrl_mpail2.data.demos import Demonstrations, demos_from_arrays
from torchrl_mpail2.data.hdf5_files import json_attribute, open_hdf5

__all__ = ["import_robosuite_hdf5"]

#: The env setting that fixes the control rate of a recording (Hz).
CONTROL_FREQ_FIELD = "control_freq"


def _robosuite_base(env):
    """The :class:`RobosuiteEnv` inside ``env`` (a TransformedEnv of the project's robosuite factory)."""
    from torchrl_mpail2.envs.robosuite_env import robosuite_base

    inner = robosuite_base(env)
    if inner is None:
        raise TypeError(f"import_robosuite_hdf5 replays states through a robosuite env of this library "
                        f"(make_env('robosuite/<task>', ...)), got {type(env).__name__}")
    return inner


def sorted_demo_names(names) -> list[str]:
    """The ``demo_N`` names among ``names`` in the order of N (robosuite's and robomimic's group names)."""
    names = [str(name) for name in names if str(name).startswith("demo_")]
    try:
        return sorted(names, key=lambda name: int(name.removeprefix("demo_")))
    except ValueError:
        return sorted(names)


def _check_states(path: Path, name: str, states: np.ndarray, width: int | None = None) -> None:
    """Refuses a demo's ``states`` ``[T, S]`` that are not finite, or whose ``S`` is not ``width`` (the flattened
    mujoco state of the demo's model), naming the file and the demo; mujoco would fail on them mid-replay."""
    if states.ndim != 2:
        raise ValueError(f"{path}: {name}/states has shape {states.shape}, expected [T, S] (flattened mujoco states)")
    bad = ~np.isfinite(states).all(axis=1)
    if bad.any():
        raise ValueError(f"{path}: {name}/states holds NaN or Inf at step(s) {np.flatnonzero(bad)[:10].tolist()} "
                         f"({int(bad.sum())} of {len(states)} states)")
    if width is not None and states.shape[1] != width:
        raise ValueError(f"{path}: {name}/states are {states.shape[1]} wide, the flattened mujoco state of its "
                         f"model_file is {width} wide (sim.get_state().flatten())")


def import_robosuite_hdf5(path: str | Path, env, *, max_demos: int | None = None,
                          progress: bool = True) -> Demonstrations:
    """Replays a robosuite ``demo.hdf5`` through ``env`` and keeps its observations.

    Args:
        path: the ``demo.hdf5`` file.
        env: ``make_env("robosuite/<task>", obs=...)`` of the recorded task; its observation mode and options
            decide the keys (``proprio``, ``object``, camera images).

    Keyword Args:
        max_demos (int, optional): import only the first ``max_demos`` demonstrations.
        progress (bool): show a progress bar.

    Returns:
        Demonstrations: one episode per ``demo_N`` with its ``T`` recorded states as observations (``T - 1``
        transitions), ``env_id`` ``robosuite/<task>`` and a header ``source`` naming the file.

    Raises:
        FileNotFoundError: ``path`` does not exist.
        ValueError: the file is not a robosuite recording (the missing group, attribute or dataset is named), is
            truncated, has an ``env_info`` that is not JSON, was recorded on another task or at another control
            rate than ``env``'s, or a demo's states are not finite or not as wide as its model's state.

    Warns:
        RuntimeWarning: the file's ``env_info`` records no ``control_freq`` (robosuite's own recordings do not), so
            the control rate could not be checked; the file is named.
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"no robosuite recording at {path}")
    base = _robosuite_base(env)
    episodes, successes = [], []
    with open_hdf5(path) as f:
        if "data" not in f:
            raise ValueError(f"{path}: no 'data' group (not a robosuite demo.hdf5); groups: {list(f.keys())}")
        data = f["data"]
        task = data.attrs.get("env")
        if task is None:
            raise ValueError(f"{path}: the 'data' group has no 'env' attribute naming the task")
        if str(task) != base.task:
            raise ValueError(f"{path} was recorded on robosuite task {task!r}, the env is {base.task!r}")
        env_info = json_attribute(path, data.attrs, "env_info", default={})
        recorded_hz = env_info.get(CONTROL_FREQ_FIELD)
        if recorded_hz is None:  # robosuite's collect_human_demonstrations writes none
            warnings.warn(f"{path}: env_info records no {CONTROL_FREQ_FIELD}, so the control rate could not be "
                          f"checked: the recording is replayed as if made at the env's {base.sim_env.control_freq} "
                          "Hz", RuntimeWarning, stacklevel=2)
        elif float(recorded_hz) != float(base.sim_env.control_freq):
            raise ValueError(f"{path} was recorded at {recorded_hz} Hz ({CONTROL_FREQ_FIELD} in env_info), "
                             f"the env steps at {base.sim_env.control_freq} Hz")
        names = sorted_demo_names(data.keys())[:max_demos]
        if not names:
            raise ValueError(f"{path}: no demo_N groups under 'data'")
        for name in tqdm(names, desc=f"replaying {path.name}", disable=not progress):
            demo = data[name]
            for field in ("states", "actions"):
                if field not in demo:
                    raise ValueError(f"{path}: {name} has no {field!r} dataset")
            if "model_file" not in demo.attrs:
                raise ValueError(f"{path}: {name} has no 'model_file' attribute (the recorded MJCF model)")
            states, actions = np.asarray(demo["states"]), np.asarray(demo["actions"])
            if len(states) < 2 or len(states) != len(actions):
                raise ValueError(f"{path}: {name} holds {len(states)} states and {len(actions)} actions "
                                 "(need as many of each, at least 2)")
            _check_states(path, name, states)
            base.load_model_xml(demo.attrs["model_file"])
            _check_states(path, name, states, width=base.sim_env.sim.get_state().flatten().size)
            frames = []
            for t, state in enumerate(states):
                frames.append(base.observe_state(state))
                base.apply_gripper_command(actions[t])
            keys = [k for k in frames[0].keys() if k != "success"]
            episodes.append({k: np.stack([frame[k].numpy() for frame in frames]) for k in keys})
            successes.append(bool(any(bool(frame["success"]) for frame in frames)))
    demos = demos_from_arrays(episodes, env_id=f"robosuite/{base.task}", success=successes)
    demos.header["source"] = {"format": "robosuite_hdf5", "path": str(path.resolve()),
                              "demos": names, "dropped": ["actions", "rewards"]}
    return demos
