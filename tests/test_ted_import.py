"""TED import on data written by TorchRL's own collector and replay buffer, and on bad TED folders."""
import os

import pytest
import torch
from tensordict import TensorDict
from torchrl.collectors import Collector
from torchrl.data import LazyMemmapStorage, TensorDictReplayBuffer
from torchrl.envs import TrajCounter

from torchrl_mpail2.data import load_demo_source
from torchrl_mpail2.data.ted import demos_from_ted
from torchrl_mpail2.envs import make_env


def collected(frames=120):
    """Random-policy transitions of the point mass as TorchRL's collector writes them (TED, trajectory ids)."""
    env = make_env("point_mass", seed=0)
    env.set_seed(0)
    collector = Collector(env, policy=None, frames_per_batch=frames, total_frames=frames)
    data = next(iter(collector))
    collector.shutdown()
    return env, data


def test_collector_output_becomes_episodes_of_t_plus_one_observations():
    env, data = collected()
    demos = demos_from_ted(data, ["observation"])
    ids = data["collector", "traj_ids"]
    lengths = [int((ids == i).sum()) for i in ids.unique(sorted=True)]
    assert demos.episode_lengths == lengths and sum(lengths) == data.shape[0]
    first = demos.episode(0)["observation"]
    n = lengths[0]
    assert torch.equal(first[:n], data["observation"][:n]) and torch.equal(first[n], data["next", "observation"][n - 1])
    assert demos.header["source"]["dropped"] == ["actions", "rewards"]


def test_a_memmapped_replay_buffer_imports_through_train_demos(tmp_path):
    env, data = collected()
    rb = TensorDictReplayBuffer(storage=LazyMemmapStorage(1000, scratch_dir=tmp_path / "scratch"))
    rb.extend(data)
    rb[:].memmap(tmp_path / "ted", copy_existing=True)  # the buffer's rows in insertion order
    demos = load_demo_source(f"ted:{tmp_path / 'ted'}", env)
    assert demos.num_steps == data.shape[0]
    assert demos.observation_keys == ["observation"]
    from torchrl_mpail2.data import load_demos
    from torchrl_mpail2.demos import main

    assert main(["import", "ted", str(tmp_path / "ted"), "--env", "point_mass", "--out", str(tmp_path / "demos")]) == 0
    saved = load_demos(tmp_path / "demos", env)
    assert saved.env_id == "point_mass" and saved.episode_lengths == demos.episode_lengths


def test_without_an_id_key_episodes_end_at_done_and_disorder_is_refused():
    _, data = collected()
    plain = data.exclude("collector")
    assert demos_from_ted(plain, ["observation"]).episode_lengths == demos_from_ted(data, ["observation"]).episode_lengths
    shuffled = plain[torch.randperm(plain.shape[0], generator=torch.Generator().manual_seed(0))]
    with pytest.raises(ValueError, match="differs from the next step's observation"):
        demos_from_ted(shuffled, ["observation"])
    with pytest.raises(KeyError, match=r"TED data has no .*velocity"):
        demos_from_ted(plain, ["velocity"])
    with pytest.raises(FileNotFoundError, match="meta.json"):
        load_demo_source("ted:/nonexistent/folder", make_env("point_mass"))


def test_trajcounter_ids_are_found_too():
    env = make_env("point_mass", seed=0).append_transform(TrajCounter())
    rollout = env.rollout(30, break_when_any_done=False)
    assert demos_from_ted(rollout, ["observation"]).num_steps == 30
    assert isinstance(rollout, TensorDict)


def synthetic_ted(lengths=(50, 50, 50), dim=4):
    """Consistent TED transitions of point-mass-shaped observations, ``len(lengths)`` episodes with ids."""
    generator = torch.Generator().manual_seed(0)
    parts = []
    for i, steps in enumerate(lengths):
        obs = torch.randn(steps + 1, dim, generator=generator)
        parts.append(TensorDict({"observation": obs[:-1], ("next", "observation"): obs[1:],
                                 "episode": torch.full((steps,), i)}, [steps]))
    return torch.cat(parts)


def test_a_truncated_memmap_is_refused_naming_the_file_and_both_sizes(tmp_path):
    synthetic_ted().memmap(tmp_path / "ted")  # 150 transitions: episode.memmap holds 150 int64, 1200 bytes
    cut = tmp_path / "ted" / "episode.memmap"
    assert cut.stat().st_size == 1200
    os.truncate(cut, 400)  # read back, the ids of the last 100 transitions would be zeros
    expected = r"episode\.memmap is truncated or corrupted: 400 bytes on disk, 1200 expected"
    with pytest.raises(ValueError, match=expected):
        load_demo_source(f"ted:{tmp_path / 'ted'}", make_env("point_mass"))


def test_nan_in_ted_observations_is_reported_with_key_and_episode(tmp_path):
    data = synthetic_ted()
    data["next", "observation"][70, 2] = float("nan")  # episode 1, and its step 71 observation with it
    data["observation"][71, 2] = float("nan")
    data.memmap(tmp_path / "ted")
    with pytest.raises(ValueError, match=r"TED data .*ted: observation key 'observation' holds NaN or Inf in "
                                         r"episode\(s\) \[1\]"):
        load_demo_source(f"ted:{tmp_path / 'ted'}", make_env("point_mass"))
    data["observation"][71, 2] = 0.0  # the next-observation alone
    with pytest.raises(ValueError, match=r"key \('next', 'observation'\) holds NaN or Inf in episode\(s\) \[1\]"):
        demos_from_ted(data, ["observation"])


def test_ted_data_without_transitions_is_refused_naming_the_folder(tmp_path):
    synthetic_ted(lengths=(0,)).memmap(tmp_path / "empty_ted")
    with pytest.raises(ValueError, match=r"TED data .*empty_ted holds no transitions"):
        load_demo_source(f"ted:{tmp_path / 'empty_ted'}", make_env("point_mass"))


def test_an_episode_id_that_comes_back_later_starts_a_new_episode():
    """Two saved batches whose ids both start at 0 (TorchRL's ``split_trajectories`` counts every transition of an
    id and fails on them): an episode is a run of one id, as TorchRL's ``SliceSampler`` reads its storage."""
    data = torch.cat([synthetic_ted(lengths=(3, 2)), synthetic_ted(lengths=(2,))])
    assert data["episode"].tolist() == [0, 0, 0, 1, 1, 0, 0]
    demos = demos_from_ted(data, ["observation"])
    assert demos.episode_lengths == [3, 2, 2]
    assert torch.equal(demos.episode(2)["observation"][0], data["observation"][5])


def test_the_success_after_each_episodes_last_transition_is_kept(tmp_path, capsys):
    from torchrl_mpail2.demos import main

    data = synthetic_ted(lengths=(4, 4, 4))
    success = torch.zeros(12, 1, dtype=torch.bool)
    success[3] = True  # episode 0 ends at the goal
    success[5] = True  # episode 1 passes through it and leaves: not a success at its last step
    data["next", "success"] = success
    demos = demos_from_ted(data, ["observation"])
    assert [meta["success"] for meta in demos.header["episodes"]] == [True, False, False]
    assert demos.success_rate == pytest.approx(1 / 3)
    assert demos_from_ted(data.exclude(("next", "success")), ["observation"]).header["episodes"][0]["success"] is None
    data.memmap(tmp_path / "ted")
    assert main(["import", "ted", str(tmp_path / "ted"), "--env", "point_mass", "--out", str(tmp_path / "demos"),
                 "--no-progress"]) == 0
    assert "success rate: 0.333" in capsys.readouterr().out
