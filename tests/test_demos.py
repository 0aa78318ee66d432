import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from torchrl.data import Composite, Unbounded

import torchrl_mpail2.demos as demos_cli
from torchrl_mpail2.data import (
    DemoBuffer,
    DemoFormatError,
    demos_from_arrays,
    load_demos,
    record_demos,
    save_demos,
)
from torchrl_mpail2.envs import make_env
from torchrl_mpail2.experts import PointMassExpert

REPO_ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def point_mass_demos():
    return record_demos(make_env("point_mass"), PointMassExpert(), episodes=3, seed=0, progress=False, env_id="point_mass")


def _labelled_demos(lengths):
    """Episodes whose observation encodes (episode, step), so samples can be traced back."""
    episodes = [
        np.stack([np.full(length + 1, episode), np.arange(length + 1)], axis=-1).astype(np.float32)
        for episode, length in enumerate(lengths)
    ]
    return demos_from_arrays(episodes, env_id="labelled")


def test_record_keeps_only_observations(point_mass_demos):
    demos = point_mass_demos
    assert set(demos.observations.keys()) == {"observation", "episode", "step"}
    assert demos.episode_lengths == [50, 50, 50]
    assert demos.observations.batch_size == (153,)
    assert demos.success_rate == 1.0
    assert demos.mean_return < 0
    assert [meta["seed"] for meta in demos.header["episodes"]] == [0, 1, 2]


def test_episodes_match_rollouts(point_mass_demos):
    env = make_env("point_mass")
    env.set_seed(1)
    rollout = env.rollout(100, policy=PointMassExpert())
    expected = torch.cat([rollout["observation"], rollout["next", "observation"][-1:]])
    assert torch.equal(point_mass_demos.episode(1)["observation"], expected)
    assert point_mass_demos.header["episodes"][1]["task_return"] == pytest.approx(
        rollout["next", "task_reward"].sum().item(), rel=1e-5
    )


def test_recording_is_reproducible(point_mass_demos):
    again = record_demos(make_env("point_mass"), PointMassExpert(), episodes=3, seed=0, progress=False)
    other = record_demos(make_env("point_mass"), PointMassExpert(), episodes=3, seed=5, progress=False)
    assert torch.equal(again.observations["observation"], point_mass_demos.observations["observation"])
    assert not torch.equal(other.observations["observation"], point_mass_demos.observations["observation"])


def test_round_trip(point_mass_demos, tmp_path):
    save_demos(point_mass_demos, tmp_path / "demos")
    loaded = load_demos(tmp_path / "demos", observation_spec=make_env("point_mass").observation_spec)
    assert (loaded.observations == point_mass_demos.observations).all()
    assert loaded.episode_lengths == point_mass_demos.episode_lengths
    assert loaded.success_rate == point_mass_demos.success_rate
    assert loaded.mean_return == pytest.approx(point_mass_demos.mean_return)
    with pytest.raises(FileExistsError):
        save_demos(point_mass_demos, tmp_path / "demos")
    save_demos(loaded, tmp_path / "demos", overwrite=True)
    assert (load_demos(tmp_path / "demos").observations == loaded.observations).all()


def test_no_actions_or_rewards_on_disk(point_mass_demos, tmp_path):
    path = save_demos(point_mass_demos, tmp_path / "demos")
    stored = {file.relative_to(path).as_posix() for file in path.rglob("*") if file.is_file()}
    assert stored == {
        "header.json",
        "observations/meta.json",
        "observations/observation.memmap",
        "observations/episode.memmap",
        "observations/step.memmap",
    }
    assert "action" not in (path / "observations" / "meta.json").read_text()


def test_header_content(point_mass_demos, tmp_path):
    path = save_demos(point_mass_demos, tmp_path / "demos")
    header = json.loads((path / "header.json").read_text())
    assert header["format"] == "torchrl_mpail2.demos" and header["format_version"] == 1
    assert header["env_id"] == "point_mass"
    assert header["observation_keys"] == [{"key": "observation", "shape": [4], "dtype": "float32"}]
    assert header["num_episodes"] == 3 and header["num_steps"] == 150 and header["num_observations"] == 153
    assert "actions and rewards are not stored" in header["note"]
    assert {meta["length"] for meta in header["episodes"]} == {50}
    assert all(meta["success"] is True for meta in header["episodes"])
    entry = header["files"]["observations/observation.memmap"]
    assert entry["nbytes"] == 153 * 4 * 4 and len(entry["sha256"]) == 64


def test_spec_mismatch_is_rejected(point_mass_demos, tmp_path):
    path = save_demos(point_mass_demos, tmp_path / "demos")
    wrong_shape = Composite(observation=Unbounded(shape=(6,)))
    with pytest.raises(ValueError, match=r"'observation'.*\(4,\).*\(6,\)"):
        load_demos(path, observation_spec=wrong_shape)
    extra_key = Composite(observation=Unbounded(shape=(4,)), cube_pos=Unbounded(shape=(3,)))
    with pytest.raises(ValueError, match="missing from the demos \\['cube_pos'\\]"):
        load_demos(path, observation_spec=extra_key)
    # Batch dimensions of the spec are not part of the observation shape.
    load_demos(path, observation_spec=make_env("point_mass", num_envs=4).observation_spec)


def test_truncated_file_is_detected(point_mass_demos, tmp_path):
    path = save_demos(point_mass_demos, tmp_path / "demos")
    array = path / "observations" / "observation.memmap"
    os.truncate(array, array.stat().st_size - 16)
    with pytest.raises(DemoFormatError, match="truncated"):
        load_demos(path)


def test_corrupted_data_is_detected(point_mass_demos, tmp_path):
    path = save_demos(point_mass_demos, tmp_path / "demos")
    array = path / "observations" / "observation.memmap"
    data = bytearray(array.read_bytes())
    data[100] ^= 0xFF  # same size, different bytes: only the checksum can tell
    array.write_bytes(bytes(data))
    with pytest.raises(DemoFormatError, match="corrupted"):
        load_demos(path)


def test_corrupted_header_is_detected(point_mass_demos, tmp_path):
    path = save_demos(point_mass_demos, tmp_path / "demos")
    header = path / "header.json"
    text = header.read_text()
    header.write_text(text[: len(text) // 2])
    with pytest.raises(DemoFormatError, match="truncated or corrupted"):
        load_demos(path)
    edited = json.loads(text)
    edited["episodes"][0]["length"] = 49
    header.write_text(json.dumps(edited))
    with pytest.raises(DemoFormatError):
        load_demos(path)
    with pytest.raises(DemoFormatError, match="missing"):
        load_demos(tmp_path / "nowhere")


def test_demos_from_arrays_dicts_and_validation(tmp_path):
    episodes = [
        {"joint_pos": np.random.rand(6, 7), "cube_pos": torch.rand(6, 3)},
        {"joint_pos": np.random.rand(4, 7), "cube_pos": torch.rand(4, 3)},
    ]
    demos = demos_from_arrays(episodes, env_id="robosuite/Lift", success=[True, False])
    assert demos.episode_lengths == [5, 3]
    assert demos.success_rate == 0.5
    assert demos.observations["joint_pos"].dtype == torch.float32  # float64 cast
    assert torch.equal(demos.episode(1)["cube_pos"], episodes[1]["cube_pos"])
    loaded = load_demos(save_demos(demos, tmp_path / "custom"))
    assert torch.equal(loaded.episode(0)["joint_pos"], torch.as_tensor(episodes[0]["joint_pos"]).float())
    with pytest.raises(ValueError, match="at least 2"):
        demos_from_arrays([np.zeros((1, 4))])
    with pytest.raises(ValueError, match=r"\[T \+ 1, \*shape\]"):
        demos_from_arrays([np.zeros(5)])
    with pytest.raises(ValueError, match="cube_pos"):
        demos_from_arrays([{"cube_pos": np.zeros((3, 3))}, {"cube_pos": np.zeros((3, 2))}])


def test_pairs_stay_inside_episodes():
    buffer = DemoBuffer(_labelled_demos([3, 1, 5]), generator=torch.Generator().manual_seed(0))
    pairs = buffer.sample_pairs(2000)
    now, nxt = pairs["observation"], pairs["next", "observation"]
    assert pairs.batch_size == (2000,)
    assert torch.equal(nxt[:, 0], now[:, 0])  # same episode
    assert torch.equal(nxt[:, 1], now[:, 1] + 1)  # consecutive steps
    # Every one of the 9 pairs is reachable, including the single pair of the 1-step episode.
    assert len({tuple(row) for row in now.tolist()}) == len(buffer) == 9


def test_windows_are_contiguous():
    buffer = DemoBuffer(_labelled_demos([2, 6, 4]), generator=torch.Generator().manual_seed(0))
    windows = buffer.sample_windows(500, 4)
    obs, nxt = windows["observation"], windows["next", "observation"]
    assert windows.batch_size == (500, 4)
    assert (obs[..., 0] == obs[:, :1, 0]).all() and (nxt[..., 0] == obs[..., 0]).all()
    assert torch.equal(obs[:, 1:], nxt[:, :-1])
    assert torch.equal(nxt[..., 1], obs[..., 1] + 1)
    assert set(obs[:, 0, 0].tolist()) == {1.0, 2.0}  # the 2-step episode is too short for a window of 4
    with pytest.raises(ValueError, match="No episode"):
        buffer.sample_windows(1, 7)


def test_sampling_is_seeded():
    demos = _labelled_demos([10, 10])
    first = DemoBuffer(demos, generator=torch.Generator().manual_seed(3)).sample_pairs(64)
    again = DemoBuffer(demos, generator=torch.Generator().manual_seed(3)).sample_pairs(64)
    assert (first == again).all()


def test_observation_stats():
    observations = np.array([[0.0, 5.0], [2.0, 5.0], [4.0, 5.0]], dtype=np.float32)
    pixels = np.zeros((3, 3, 2, 2), dtype=np.uint8)
    buffer = DemoBuffer(demos_from_arrays([{"state": observations, "pixels": pixels}]))
    stats = buffer.observation_stats()
    assert list(stats) == ["state"]  # integer (pixel) keys are skipped
    mean, std = stats["state"]
    assert torch.allclose(mean, torch.tensor([2.0, 5.0]))
    assert torch.allclose(std, torch.tensor([(8 / 3) ** 0.5, 1e-3]))  # constant dim floored


def test_cli_record_and_info(tmp_path, capsys):
    out = tmp_path / "pm"
    env = {**os.environ, "PYTHONPATH": str(REPO_ROOT)}
    command = [sys.executable, "-m", "torchrl_mpail2.demos"]
    record = subprocess.run(
        [*command, "record", "--env", "point_mass", "--episodes", "3", "--seed", "0", "--out", str(out), "--no-progress"],
        capture_output=True, text=True, env=env, timeout=120,
    )
    assert record.returncode == 0, record.stderr
    demos = load_demos(out)
    assert demos.num_episodes == 3 and demos.env_id == "point_mass"
    demos_cli.main(["info", str(out)])  # in-process: each interpreter start costs seconds
    info = capsys.readouterr().out
    assert "episodes: 3  steps: 150" in info
    assert "observation: shape [4] float32" in info
    assert "success rate: 1.000" in info
    os.truncate(out / "observations" / "step.memmap", 8)
    with pytest.raises(DemoFormatError, match="truncated"):
        demos_cli.main(["info", str(out)])


def test_cli_lift_speed_is_lift_only(tmp_path):
    with pytest.raises(SystemExit, match="robosuite/Lift only"):
        demos_cli.main(["record", "--env", "point_mass", "--lift-speed", "0.01", "--out", str(tmp_path / "pm")])
    assert not (tmp_path / "pm").exists()


def test_cli_record_takes_a_preset_and_env_kwargs_and_records_them(tmp_path, capsys):
    out = tmp_path / "pm"
    assert demos_cli.main(["record", "--preset", "point_mass", "--env-kwargs", '{"horizon": 10}', "--episodes", "1",
                           "--out", str(out), "--no-progress"]) == 0
    assert "env: point_mass {'obs': 'state', 'horizon': 10}" in capsys.readouterr().out
    demos = load_demos(out)
    assert demos.env_id == "point_mass" and demos.header["env_kwargs"] == {"obs": "state", "horizon": 10}
    assert demos.episode_lengths == [10]  # the option reached the env


@pytest.mark.parametrize("argv, message", [
    (["--env-kwargs", "{horizon: 10}"], "not JSON"),
    (["--env-kwargs", "[10]"], "expected a JSON object"),
    (["--env-kwargs", '{"obs": "pixels"}'], "with --obs"),
])
def test_cli_bad_env_kwargs_exit_with_status_2_naming_the_fault(tmp_path, capsys, argv, message):
    with pytest.raises(SystemExit) as exit_info:
        demos_cli.main(["record", "--env", "point_mass", *argv, "--out", str(tmp_path / "pm")])
    assert exit_info.value.code == 2 and message in capsys.readouterr().err


def test_cli_without_env_or_preset_says_so(tmp_path):
    with pytest.raises(SystemExit, match="--env, or a training preset with --preset"):
        demos_cli.main(["record", "--out", str(tmp_path / "pm")])


def test_a_spec_mismatch_names_the_env_option_that_differs(point_mass_demos, tmp_path):
    demos = point_mass_demos.with_keys(["observation"])
    demos.header["env_kwargs"] = {"obs": "state", "horizon": 50}
    path = save_demos(demos, tmp_path / "demos")
    pixels = make_env("point_mass", obs="pixels")
    with pytest.raises(ValueError, match=r"keys missing from the demos \['external_image'\].*The env option that "
                                         r"likely differs: obs \(demos: state, env: pixels\)"):
        load_demos(path, pixels, env_kwargs={"obs": "pixels", "horizon": 50})
    with pytest.raises(ValueError, match=r"The demos were made with the env options \{'obs': 'state', 'horizon': 50\}"):
        load_demos(path, pixels)  # the env's options unknown: the demos' are shown
    demos.header["env_kwargs"] = {}  # recorded by nobody: no hint
    with pytest.raises(ValueError, match=r"extra keys in the demos \['observation'\]\.$"):
        load_demos(save_demos(demos, tmp_path / "unrecorded"), pixels, env_kwargs={"obs": "pixels"})


def test_recordings_end_steps_after_the_first_success():
    env = make_env("point_mass")
    full = record_demos(env, PointMassExpert(), episodes=2, progress=False, seed=4)
    cut = record_demos(env, PointMassExpert(), episodes=2, progress=False, seed=4, steps_after_success=3)
    for i in range(2):
        env.set_seed(4 + i)
        success = env.rollout(1000, PointMassExpert(), break_when_any_done=True)["next", "success"].reshape(-1)
        first = int(success.float().argmax())  # the step whose next observation first succeeds
        assert success.any() and cut.episode_lengths[i] == min(first + 1 + 3, full.episode_lengths[i]) < 50
        torch.testing.assert_close(cut.episode(i)["observation"],
                                   full.episode(i)["observation"][: cut.episode_lengths[i] + 1])
    with pytest.raises(ValueError, match="steps_after_success"):
        record_demos(env, PointMassExpert(), episodes=1, progress=False, steps_after_success=-1)


def test_demo_api_is_reexported_at_the_top_level():
    import torchrl_mpail2
    import torchrl_mpail2.data as data

    for name in ("record_demos", "load_demos", "save_demos", "demos_from_arrays", "DemoBuffer", "Demonstrations"):
        assert getattr(torchrl_mpail2, name) is getattr(data, name), name  # one home: torchrl_mpail2.data
        assert name in torchrl_mpail2.__all__


def test_a_demo_cache_written_by_another_run_meanwhile_is_loaded_not_fatal(monkeypatch, caplog):
    """Two runs of the same seed started together both record the cache; the later save finds the earlier one's."""
    import logging

    from torchrl_mpail2.trainers import apply_overrides, preset
    from torchrl_mpail2.trainers import run_demos

    cfg = apply_overrides(preset("point_mass"), ["train.num_demos=2", "train.progress=false"])
    path = run_demos.default_demo_dir(cfg)
    real_record = run_demos.record_demos

    def record_while_another_run_saves(*args, **kwargs):
        demos = real_record(*args, **kwargs)
        save_demos(real_record(*args, **kwargs), path)  # the other run wins the race
        return demos

    monkeypatch.setattr(run_demos, "record_demos", record_while_another_run_saves)
    env = make_env("point_mass")
    with caplog.at_level(logging.INFO, logger=run_demos.__name__):
        demos = run_demos.load_or_record_demos(cfg, env, lambda seed=0: make_env("point_mass", seed=seed))
    assert "written by another run meanwhile" in caplog.text
    assert demos.num_episodes == 2 and torch.equal(demos.observations["observation"],
                                                   load_demos(path).observations["observation"])
    assert sorted(p.name for p in path.parent.iterdir()) == [path.name]  # no staging folder left behind


def test_save_demos_names_a_folder_moved_into_place_by_another_writer(tmp_path, monkeypatch):
    demos = record_demos(make_env("point_mass"), PointMassExpert(), episodes=1, progress=False)
    target = tmp_path / "pm"
    real_replace = os.replace

    def replace_after_another_writer(src, dst):
        monkeypatch.setattr(os, "replace", real_replace)  # the other writer renames as usual
        save_demos(demos, dst)  # and lands between this save's check and its rename
        return real_replace(src, dst)

    monkeypatch.setattr(os, "replace", replace_after_another_writer)
    with pytest.raises(FileExistsError, match="written meanwhile by another process"):
        save_demos(demos, target)
    assert load_demos(target).num_episodes == 1 and [p.name for p in tmp_path.iterdir()] == ["pm"]


def test_a_runs_cached_demos_record_the_env_options_not_the_experts():
    from torchrl_mpail2.trainers import apply_overrides, preset
    from torchrl_mpail2.trainers import run_demos

    cfg = apply_overrides(preset("point_mass"), ["train.num_demos=1", "train.progress=false"])
    env = make_env("point_mass")
    demos = run_demos.load_or_record_demos(cfg, env, lambda seed=0: make_env("point_mass", seed=seed))
    assert demos.header["env_kwargs"] == {"obs": "state"}
    assert load_demos(run_demos.default_demo_dir(cfg)).header["env_kwargs"] == {"obs": "state"}


def test_the_demo_recorder_env_is_closed_after_recording_and_the_training_env_is_not():
    """A dropped recorder env would free its simulator (and a robosuite GL context) only at some later garbage
    collection; it is closed as soon as the demonstrations are recorded. An env_fn that hands back the training env
    itself leaves it open."""
    from torchrl_mpail2.trainers import apply_overrides, preset
    from torchrl_mpail2.trainers import run_demos

    closed = []

    def tracked(env):
        real_close = env.close
        env.close = lambda *a, **k: (closed.append(env), real_close(*a, **k))[1]
        return env

    made = []

    def env_fn(seed=0):
        made.append(tracked(make_env("point_mass", seed=seed)))
        return made[-1]

    cfg = apply_overrides(preset("point_mass"), ["train.num_demos=1", "train.progress=false", "train.seed=11"])
    env = tracked(make_env("point_mass"))
    run_demos.load_or_record_demos(cfg, env, env_fn)
    assert len(made) == 1 and closed == made
    cfg = apply_overrides(cfg, ["train.seed=12"])
    run_demos.load_or_record_demos(cfg, env, lambda seed=0: env)
    assert closed == made


def test_gym_demo_cache_names_its_expert_file_so_a_new_expert_records_anew(tmp_path, monkeypatch):
    import torchrl_mpail2.experts.gym as gym_experts
    from torchrl_mpail2.trainers import apply_overrides, preset
    from torchrl_mpail2.trainers import run_demos

    cfg = apply_overrides(preset("hopper"), ["train.num_demos=2"])
    monkeypatch.setattr(gym_experts, "ASSET_DIR", tmp_path)
    assert run_demos.default_demo_dir(cfg).name.endswith("-expertnone-2ep-seed0")
    (tmp_path / "Hopper-v5.pt").write_bytes(b"one expert")
    first = run_demos.default_demo_dir(cfg)
    (tmp_path / "Hopper-v5.pt").write_bytes(b"another expert")
    assert run_demos.default_demo_dir(cfg) != first
    # the robot tasks' scripted experts have no file: their cache folders are as before
    assert "expert" not in run_demos.default_demo_dir(preset("push_state")).name
