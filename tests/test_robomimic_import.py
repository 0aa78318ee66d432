"""robomimic HDF5 datasets written by robomimic's own ``dataset_states_to_obs.py`` (fixtures in ``tests/data``, made
by ``tests/data/make_robomimic_lift.py``: 2 scripted Lift episodes, low-dim with ``next_obs``; 1 episode with both
84 x 84 cameras, ``--exclude-next-obs``)."""
import json
import os
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from torchrl_mpail2.data import load_demo_source, load_demos
from torchrl_mpail2.data.robomimic_import import import_robomimic
from torchrl_mpail2.envs import make_env
from torchrl_mpail2.envs.robosuite_env import RobosuiteEnv, robosuite_base

pytest.importorskip("robosuite")

DATA = Path(__file__).parent / "data"
LOW_DIM = DATA / "robomimic_lift_low_dim.hdf5"
IMAGE = DATA / "robomimic_lift_image.hdf5"


def _base(env) -> RobosuiteEnv:
    base = robosuite_base(env)
    assert base is not None
    return base


def _replayed(env, demo, steps: int | None = None) -> list:
    """This library's own observations of the recorded mujoco states of one robomimic demo (its first ``steps``)."""
    base = _base(env)
    base.load_model_xml(demo.attrs["model_file"])
    return [base.observe_state(state) for state in np.asarray(demo["states"])[:steps]]


@pytest.fixture(scope="module")
def lift_state_env():
    return make_env("robosuite/Lift")


def test_low_dim_keys_match_the_envs_own_observations_of_the_recorded_states(lift_state_env):
    demos = import_robomimic(LOW_DIM, lift_state_env)
    assert demos.env_id == "robosuite/Lift" and demos.num_episodes == 2
    assert demos.observation_keys == ["proprio", "object"]
    assert demos.header["source"]["format"] == "robomimic"
    assert set(demos.header["source"]["dropped"]) >= {"actions", "rewards"}
    assert demos.success_rate == 1.0  # robomimic's sparse reward is 1 at the last step of both
    with h5py.File(LOW_DIM) as f:
        for episode, name in enumerate(demos.header["source"]["demos"]):
            demo = f["data"][name]
            got = demos.episode(episode)
            steps = len(demo["actions"])
            assert got["proprio"].shape == (steps + 1, 26)  # obs, then the last next_obs
            frames = _replayed(lift_state_env, demo)
            for key in ("proprio", "object"):
                expected = np.stack([frame[key].numpy() for frame in frames])
                np.testing.assert_allclose(got[key][:steps].numpy(), expected, atol=1e-5, err_msg=key)
            last = np.asarray(demo["next_obs"]["object"][-1])  # robosuite's order: offset is cube - end effector
            np.testing.assert_allclose(got["object"][-1].numpy(), np.concatenate([last[:7], -last[7:]]), atol=1e-6)


def test_the_gripper_command_is_advanced_from_the_recorded_actions():
    env = make_env("robosuite/Lift", observe_gripper_command=True)
    demos = import_robomimic(LOW_DIM, env, max_demos=1)
    command = demos.episode(0)["proprio"][:, -1].numpy()
    with h5py.File(LOW_DIM) as f:
        closing = np.asarray(f["data"][demos.header["source"]["demos"][0]]["actions"])[:, -1]
    assert command[0] == 0.0 and command.min() >= -1 and command.max() <= 1
    # integrating gripper: each step moves the command 0.2 towards the sign of the action, so it leads by a step
    first_close = int(np.argmax(closing > 0))
    assert command[first_close] <= command[first_close + 1] and command[first_close + 1] > command[first_close] - 1e-6
    assert np.isclose(command[-1], 1.0) == (closing[-1] > 0)


def test_images_are_upright_chw_and_resized_to_the_envs_size():
    env = make_env("robosuite/Lift", obs="pixels")
    demos = import_robomimic(IMAGE, env)
    assert demos.observation_keys == ["proprio", "external_image", "wrist_image"]
    got = demos.episode(0)
    with h5py.File(IMAGE) as f:
        demo = f["data"]["demo_1"]
        steps = len(demo["actions"])
        assert "next_obs" not in demo  # written with --exclude-next-obs: T observations
        assert np.asarray(demo["obs"]["agentview_image"]).shape[1:] == (84, 84, 3)
        own = _replayed(env, demo, steps=1)[0]
    image = got["external_image"]
    assert image.shape == (steps, 3, 64, 64) and str(image.dtype) == "torch.uint8"
    # Same scene, same orientation as the env's own 64 x 64 camera: far closer than the upside-down picture
    # (measured: 1.1 against 59 grey levels).
    ours = own["external_image"].numpy().astype(np.float32)
    imported = image[0].numpy().astype(np.float32)
    upright_error = np.abs(imported - ours).mean()
    flipped_error = np.abs(imported[:, ::-1] - ours).mean()
    assert upright_error < 5 and upright_error < flipped_error / 10, (upright_error, flipped_error)


def test_the_external_camera_mode_takes_agentview_alone_and_image_rules_take_one_key():
    env = make_env("robosuite/Lift", obs="external_pixels")
    demos = import_robomimic(IMAGE, env)
    assert demos.observation_keys == ["external_image"] and demos.episode(0)["external_image"].shape[1:] == (3, 64, 64)
    with pytest.raises(ValueError, match="'external_image' is made of exactly one"):
        import_robomimic(IMAGE, env, key_map={"external_image": ("agentview_image", "robot0_eye_in_hand_image")})


def _edited_copy(tmp_path, edit) -> Path:
    copy = tmp_path / "edited.hdf5"
    shutil.copy(LOW_DIM, copy)
    with h5py.File(copy, "r+") as f:
        edit(f)
    return copy


def _set_control_freq(f, hz):
    env_args = json.loads(f["data"].attrs["env_args"])
    env_args["env_kwargs"]["control_freq"] = hz
    f["data"].attrs["env_args"] = json.dumps(env_args)


@pytest.mark.parametrize("edit, message", [
    (lambda f: f["data"].attrs.__delitem__("env_args"), "env_args"),
    (lambda f: _set_control_freq(f, 10), "10 Hz"),
    (lambda f: [f["data"][name]["obs"].__delitem__("object") for name in f["data"]], "'object'"),
])
def test_bad_files_are_refused_by_name(tmp_path, lift_state_env, edit, message):
    with pytest.raises(ValueError, match=message):
        import_robomimic(_edited_copy(tmp_path, edit), lift_state_env)


def test_wrong_task_unknown_split_and_missing_file_are_refused(tmp_path, lift_state_env):
    with pytest.raises(ValueError, match="'Lift'.*'Push'"):
        import_robomimic(LOW_DIM, make_env("robosuite/Push"))
    with pytest.raises(ValueError, match="'valdiation'"):
        import_robomimic(LOW_DIM, lift_state_env, filter_key="valdiation")
    with pytest.raises(FileNotFoundError, match="nothere"):
        import_robomimic(tmp_path / "nothere.hdf5", lift_state_env)


def test_a_plain_key_map_entry_concatenates_without_converting(lift_state_env):
    demos = import_robomimic(LOW_DIM, lift_state_env, max_demos=1, key_map={"object": ("object",)})
    with h5py.File(LOW_DIM) as f:
        raw = np.asarray(f["data"][demos.header["source"]["demos"][0]]["obs"]["object"])
    np.testing.assert_allclose(demos.episode(0)["object"][:-1].numpy(), raw, atol=1e-6)


def test_train_split_the_source_prefix_and_the_command_line(tmp_path, lift_state_env):
    from torchrl_mpail2.demos import main

    demos = load_demo_source(f"robomimic:{LOW_DIM}", lift_state_env)
    train = import_robomimic(LOW_DIM, lift_state_env, filter_key="train")
    assert train.num_episodes == demos.num_episodes == 2
    out = tmp_path / "imported"
    main(["import", "robomimic", str(LOW_DIM), "--env", "robosuite/Lift", "--out", str(out), "--no-progress"])
    saved = load_demos(out, lift_state_env)
    assert saved.num_episodes == 2 and saved.header["source"]["format"] == "robomimic"


def test_a_truncated_file_is_refused_naming_it(tmp_path, lift_state_env):
    cut = tmp_path / "cut.hdf5"
    shutil.copy(LOW_DIM, cut)
    os.truncate(cut, cut.stat().st_size // 2)
    with pytest.raises(ValueError, match=r"cut\.hdf5 cannot be read as HDF5: the file is truncated"):
        import_robomimic(cut, lift_state_env)


def test_env_args_that_is_not_json_is_refused_naming_file_and_attribute(tmp_path, lift_state_env):
    copy = _edited_copy(tmp_path, lambda f: f["data"].attrs.__setitem__("env_args", "{env_name: Lift"))
    with pytest.raises(ValueError, match=r"edited\.hdf5: the attribute 'env_args' is not JSON"):
        import_robomimic(copy, lift_state_env)


def _emptied(demo, keys=None):
    """Replaces the datasets of ``demo`` (all of them, or its top-level ``keys``) by ones of 0 rows."""
    def empty(group, name):
        dataset = group[name]
        shape, dtype = dataset.shape, dataset.dtype
        del group[name]
        group.create_dataset(name, shape=(0, *shape[1:]), dtype=dtype)

    for name in keys or list(demo.keys()):
        if isinstance(demo[name], h5py.Group):
            for inner in list(demo[name].keys()):
                empty(demo[name], inner)
        else:
            empty(demo, name)


def test_demos_without_steps_are_skipped_by_name_and_a_file_of_none_is_refused(tmp_path, lift_state_env):
    copy = _edited_copy(tmp_path, lambda f: _emptied(f["data"]["demo_1"]))
    with pytest.warns(RuntimeWarning, match=r"edited\.hdf5: demo_1 holds fewer than 2 observations .*skipped"):
        demos = import_robomimic(copy, lift_state_env)
    assert demos.num_episodes == 1 and demos.header["source"]["demos"] == ["demo_2"]
    assert demos.header["source"]["skipped"] == ["demo_1"]
    with h5py.File(copy, "r+") as f:
        _emptied(f["data"]["demo_2"])
    refused = r"edited\.hdf5: none of its demos holds a transition \(all skipped: \['demo_1', 'demo_2'\]\)"
    with pytest.warns(RuntimeWarning), pytest.raises(ValueError, match=refused):
        import_robomimic(copy, lift_state_env)


def test_a_demo_with_empty_rewards_is_imported_with_its_success_unrecorded(tmp_path, lift_state_env):
    copy = _edited_copy(tmp_path, lambda f: _emptied(f["data"]["demo_2"], ["rewards"]))
    with pytest.warns(RuntimeWarning, match=r"edited\.hdf5: demo_2/rewards is missing or empty"):
        demos = import_robomimic(copy, lift_state_env)
    assert demos.num_episodes == 2 and np.isnan(demos.success_rate)


def test_the_command_line_imports_one_split_with_filter_key(tmp_path, lift_state_env):
    from torchrl_mpail2.demos import main

    split = tmp_path / "split.hdf5"
    shutil.copy(LOW_DIM, split)
    with h5py.File(split, "r+") as f:
        f["mask"].create_dataset("second", data=np.array([b"demo_2"]))
    out = tmp_path / "second"
    assert main(["import", "robomimic", str(split), "--env", "robosuite/Lift", "--filter-key", "second",
                 "--out", str(out), "--no-progress"]) == 0
    saved = load_demos(out, lift_state_env)
    assert saved.num_episodes == 1
    assert saved.header["source"]["demos"] == ["demo_2"] and saved.header["source"]["filter_key"] == "second"
    with pytest.raises(ValueError, match="no filter key 'valdiation' under 'mask'"):
        main(["import", "robomimic", str(split), "--env", "robosuite/Lift", "--filter-key", "valdiation",
              "--out", str(tmp_path / "typo"), "--no-progress"])
    with pytest.raises(SystemExit, match="--filter-key applies to robomimic files only, not ted"):
        main(["import", "ted", str(tmp_path), "--env", "point_mass", "--filter-key", "train",
              "--out", str(tmp_path / "ted")])
