r"""Observation-only demonstrations from a local Minari dataset (``train.demos=minari:PATH``).

Minari (Farama's offline-RL format, the successor of D4RL) stores each episode's ``T + 1`` observations, its
actions, rewards and termination flags, and the gymnasium ``EnvSpec`` the data was collected with. The
observations are kept (a ``Box`` space under ``"observation"``, as TorchRL's ``GymEnv`` names it; a ``Dict``
space key by key); actions and rewards are dropped. A dataset collected on another task, or at another control
rate (``frame_skip``), is refused by name.
"""
from __future__ import annotations

from pathlib import Path

from torchrl_mpail2.data.demos import Demonstrations, demos_from_arrays
from torchrl_mpail2.data.hdf5_files import open_hdf5

__all__ = ["import_minari"]

#: The key TorchRL's ``GymEnv`` gives a ``Box`` observation.
BOX_OBSERVATION_KEY = "observation"


def _data_folder(path: Path) -> Path:
    """The folder holding ``metadata.json`` and the episodes: ``path`` itself or its ``data/``."""
    for folder in (path, path / "data"):
        if (folder / "metadata.json").is_file():
            return folder
    raise FileNotFoundError(f"{path}: not a Minari dataset folder (no metadata.json in it or in its data/)")


def _check_hdf5_files(folder: Path) -> None:
    """Opens each HDF5 file of the dataset once, so that one cut short is refused by name (Minari would open it
    mid-iteration and pass on h5py's error, which names no file)."""
    for file in sorted(folder.glob("*.hdf5")):
        open_hdf5(file).close()


def _gym_env(env):
    """The gymnasium env inside a TorchRL env (through its transforms), or None."""
    base = getattr(env, "base_env", env)
    return getattr(base, "_env", None)


def _check_task(dataset_spec, env, path: Path) -> None:
    """Refuses a dataset whose task or ``frame_skip`` differs from ``env``'s (where both are known)."""
    gym_env = _gym_env(env)
    if dataset_spec is None or gym_env is None or gym_env.spec is None:
        return
    if dataset_spec.id != gym_env.spec.id:
        raise ValueError(f"{path}: the Minari dataset was collected on {dataset_spec.id!r}, the env is "
                         f"{gym_env.spec.id!r}")
    recorded = (dataset_spec.kwargs or {}).get("frame_skip")
    current = getattr(gym_env.unwrapped, "frame_skip", None)
    if recorded is not None and current is not None and recorded != current:
        raise ValueError(f"{path}: the Minari dataset's control rate differs: frame_skip {recorded} in its env spec, "
                         f"{current} in the env")


def import_minari(path: str | Path, env=None, *, max_demos: int | None = None, progress: bool = False) -> Demonstrations:
    """Demonstrations from the Minari dataset in the folder ``path`` (e.g. ``~/.minari/datasets/mujoco/hopper/expert-v0``).

    Args:
        path: the dataset's folder, or its ``data/`` subfolder.
        env (optional): the TorchRL env the demos are for; its gymnasium task and ``frame_skip`` must match the
            dataset's env spec (observation keys and shapes are checked by ``load_demo_source``).

    Keyword Args:
        max_demos (int, optional): import only the first ``max_demos`` episodes.
        progress (bool): show a progress bar over episodes.

    Raises:
        FileNotFoundError: ``path`` is not a Minari dataset folder.
        ValueError: the dataset was collected on another task or at another control rate, or its HDF5 file is
            truncated (the file is named).
    """
    try:
        import minari
    except ImportError as error:
        raise ImportError("importing Minari datasets needs minari: pip install 'torchrl-mpail2[minari]'") from error
    from tqdm import tqdm

    path = Path(path).expanduser()
    folder = _data_folder(path)
    _check_hdf5_files(folder)
    dataset = minari.MinariDataset(folder)
    _check_task(dataset.spec.env_spec, env, path)
    count = dataset.total_episodes if max_demos is None else min(max_demos, dataset.total_episodes)
    episodes, returns = [], []
    for episode in tqdm(dataset.iterate_episodes(), total=count, disable=not progress, desc="minari episodes"):
        if len(episodes) == count:
            break
        obs = episode.observations
        episodes.append(dict(obs) if isinstance(obs, dict) else {BOX_OBSERVATION_KEY: obs})
        returns.append(float(episode.rewards.sum()))
    env_spec = dataset.spec.env_spec
    demos = demos_from_arrays(episodes, env_id=f"gym/{env_spec.id}" if env_spec is not None else "custom",
                              task_returns=returns)  # the returns are reported by `info`, never learned from
    demos.header["source"] = {"format": "minari", "path": str(path.resolve()), "dataset_id": dataset.spec.dataset_id,
                              "episodes": count, "dropped": ["actions", "rewards"]}
    return demos
