"""Minari import on datasets written by minari's own writer (``create_dataset_from_buffers``)."""
import os

import numpy as np
import pytest

minari = pytest.importorskip("minari")
gym = pytest.importorskip("gymnasium")

from minari.data_collector import EpisodeBuffer  # noqa: E402

from torchrl_mpail2.data import load_demo_source  # noqa: E402
from torchrl_mpail2.envs import make_env  # noqa: E402


def write_dataset(root, monkeypatch, env_id="Hopper-v5", episodes=2, steps=12, **kwargs):
    """A small Minari dataset of random actions, written by minari into ``root``; returns its folder."""
    monkeypatch.setenv("MINARI_DATASETS_PATH", str(root))
    env = gym.make(env_id, max_episode_steps=steps, **kwargs)
    buffers = []
    for i in range(episodes):
        obs, _ = env.reset(seed=i)
        observations, actions, rewards, terminations, truncations = [obs], [], [], [], []
        done = False
        while not done:
            action = env.action_space.sample()
            obs, reward, terminated, truncated, _ = env.step(action)
            observations.append(obs), actions.append(action), rewards.append(reward)
            terminations.append(terminated), truncations.append(truncated)
            done = terminated or truncated
        buffers.append(EpisodeBuffer(observations=np.array(observations), actions=np.array(actions),
                                     rewards=np.array(rewards), terminations=np.array(terminations),
                                     truncations=np.array(truncations), infos={}))
    name = f"mpail2/{env_id.lower()}-test-v0"
    minari.create_dataset_from_buffers(name, buffers, env=env, algorithm_name="random", author="tests",
                                       author_email="tests@example.org", code_permalink="none", description="test")
    return root / name, buffers


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_a_minari_dataset_imports_its_observations_for_the_gym_env(tmp_path, monkeypatch):
    folder, buffers = write_dataset(tmp_path, monkeypatch)
    demos = load_demo_source(f"minari:{folder}", make_env("gym/Hopper-v5"))
    assert demos.episode_lengths == [len(b.actions) for b in buffers]
    np.testing.assert_allclose(demos.episode(1)["observation"].numpy(), buffers[1].observations, rtol=1e-6)
    assert demos.header["source"]["dropped"] == ["actions", "rewards"] and demos.env_id == "gym/Hopper-v5"


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_another_task_or_control_rate_or_folder_is_refused_by_name(tmp_path, monkeypatch):
    from torchrl_mpail2.data.minari_import import import_minari

    folder, _ = write_dataset(tmp_path / "a", monkeypatch, env_id="Ant-v5")
    with pytest.raises(ValueError, match="collected on 'Ant-v5', the env is 'Hopper-v5'"):
        import_minari(folder, make_env("gym/Hopper-v5"))
    folder, _ = write_dataset(tmp_path / "b", monkeypatch, frame_skip=2)
    with pytest.raises(ValueError, match="frame_skip 2 in its env spec, 4 in the env"):
        import_minari(folder, make_env("gym/Hopper-v5"))
    with pytest.raises(FileNotFoundError, match="not a Minari dataset folder"):
        import_minari(tmp_path, make_env("gym/Hopper-v5"))


@pytest.mark.filterwarnings("ignore::UserWarning")
def test_a_truncated_main_data_file_is_refused_naming_it(tmp_path, monkeypatch):
    from torchrl_mpail2.data.minari_import import import_minari

    folder, _ = write_dataset(tmp_path, monkeypatch, episodes=1, steps=5)
    data_file = folder / "data" / "main_data.hdf5"
    os.truncate(data_file, data_file.stat().st_size // 2)
    with pytest.raises(ValueError, match=r"main_data\.hdf5 cannot be read as HDF5: the file is truncated"):
        import_minari(folder, make_env("gym/Hopper-v5"))
