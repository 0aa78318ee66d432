"""robosuite's teleoperation recordings, written by robosuite's own DataCollectionWrapper and
gather_demonstrations_as_hdf5, imported by replaying their states through this library's env; bad files written
by hand in the same layout."""
import json
import os
import warnings

import h5py
import numpy as np
import pytest
import torch

from torchrl_mpail2.data import load_demo_source, load_demos, save_demos
from torchrl_mpail2.data.robosuite_hdf5 import import_robosuite_hdf5
from torchrl_mpail2.envs import make_env
from torchrl_mpail2.envs.robosuite_env import RobosuiteEnv, robosuite_base
from torchrl_mpail2.experts import get_expert

pytest.importorskip("robosuite")


def _base(env) -> RobosuiteEnv:
    base = robosuite_base(env)
    assert base is not None
    return base


def _record_with_robosuites_writer(tmp_path, episodes=2, env_info=None, **env_kwargs):
    """Drives the scripted expert through robosuite's DataCollectionWrapper (as a teleoperator would), then
    gathers the raw episodes into demo.hdf5 with robosuite's own script; returns the file and the live rollouts."""
    from robosuite.scripts.collect_human_demonstrations import gather_demonstrations_as_hdf5
    from robosuite.wrappers import DataCollectionWrapper

    env = make_env("robosuite/Lift", seed=3, **env_kwargs)
    base = _base(env)
    raw = tmp_path / "raw"
    base._sim_env = DataCollectionWrapper(base._sim_env, str(raw))
    expert = get_expert("robosuite/Lift", env)
    rollouts = []
    for i in range(episodes):
        env.set_seed(100 + i)
        if hasattr(expert, "reset"):
            expert.reset()
        rollouts.append(env.rollout(100, expert, break_when_any_done=True))
    base._sim_env.close()  # flushes the last episode
    out = tmp_path / "hdf5"
    out.mkdir()
    gather_demonstrations_as_hdf5(str(raw), str(out), env_info or json.dumps({"env_name": "Lift", "robots": "Panda"}))
    return out / "demo.hdf5", rollouts


@pytest.fixture(scope="module")
def recording(tmp_path_factory):
    return _record_with_robosuites_writer(tmp_path_factory.mktemp("rs"))


def test_replayed_states_give_exactly_the_observations_seen_live(recording):
    path, rollouts = recording
    with h5py.File(path) as f:
        assert len(f["data"].keys()) == 2  # robosuite keeps the successful episodes only
    demos = import_robosuite_hdf5(path, make_env("robosuite/Lift"), progress=False)
    assert demos.env_id == "robosuite/Lift" and demos.num_episodes == 2
    assert demos.observation_keys == ["proprio", "object"]
    assert demos.header["source"]["format"] == "robosuite_hdf5"
    assert set(demos.header["source"]["dropped"]) == {"actions", "rewards"}
    # robosuite gathers its episode folders in directory order: pair them with the live rollouts by first state
    live_by_start = {round(float(live["object"][0, 0]), 5): live for live in rollouts}
    for episode in range(demos.num_episodes):
        got = demos.episode(episode)
        live = live_by_start[round(float(got["object"][0, 0]), 5)]
        # states[t] is the state before action t: the live observations of steps 0..T-1. Replay recomputes the
        # kinematics of each state (mj_forward); live, robosuite's step ends on mj_step, whose positions were
        # computed before its integration, i.e. one 2 ms physics substep earlier: equal at reset, close after.
        for key in ("proprio", "object"):
            np.testing.assert_allclose(got[key][0].numpy(), live[key][0].numpy(), atol=1e-6, err_msg=key)
            np.testing.assert_allclose(got[key].numpy(), live[key].numpy(), atol=2e-3, err_msg=key)


def test_the_gripper_command_is_advanced_from_the_recorded_actions(tmp_path):
    path, rollouts = _record_with_robosuites_writer(tmp_path, episodes=1, observe_gripper_command=True)
    demos = import_robosuite_hdf5(path, make_env("robosuite/Lift", observe_gripper_command=True), progress=False)
    got = demos.episode(0)["proprio"]
    assert got.shape[-1] == 27
    np.testing.assert_allclose(got[:, -1].numpy(), rollouts[0]["proprio"][:, -1].numpy(), atol=1e-6)
    assert float(got[:, -1].max()) > 0.5  # the expert did close the gripper


def test_camera_observations_are_rendered_from_the_replayed_states(recording):
    path, _ = recording
    demos = import_robosuite_hdf5(path, make_env("robosuite/Lift", obs="external_pixels"), max_demos=1,
                                  progress=False)
    image = demos.episode(0)["external_image"]
    assert image.dtype == torch.uint8 and tuple(image.shape[1:]) == (3, 64, 64)
    assert image.float().std() > 1.0  # a scene, not a blank frame


def test_the_source_syntax_saves_and_loads_and_bad_files_are_named(recording, tmp_path):
    path, _ = recording
    env = make_env("robosuite/Lift")
    demos = load_demo_source(f"robosuite_hdf5:{path}", env)
    save_demos(demos, tmp_path / "saved")
    again = load_demo_source(str(tmp_path / "saved"), env)
    assert again.header["source"]["path"] == str(path.resolve())
    torch.testing.assert_close(again.observations["object"], demos.observations["object"])
    with pytest.raises(ValueError, match="recorded on robosuite task 'Lift', the env is 'Push'"):
        import_robosuite_hdf5(path, make_env("robosuite/Push"), progress=False)
    with pytest.raises(TypeError, match="robosuite env of this library"):
        import_robosuite_hdf5(path, make_env("point_mass"), progress=False)
    with pytest.raises(FileNotFoundError, match="no robosuite recording"):
        import_robosuite_hdf5(tmp_path / "missing.hdf5", env)
    other_rate = tmp_path / "other_rate.hdf5"
    other_rate.write_bytes(path.read_bytes())
    with h5py.File(other_rate, "r+") as f:
        f["data"].attrs["env_info"] = json.dumps({"env_name": "Lift", "control_freq": 10})
    with pytest.raises(ValueError, match="recorded at 10 Hz"):
        import_robosuite_hdf5(other_rate, env, progress=False)
    broken = tmp_path / "broken.hdf5"
    with h5py.File(broken, "w") as f:
        f.create_group("data").attrs["env"] = "Lift"
        f["data"].create_group("demo_1").create_dataset("states", data=np.zeros((3, 5)))
    with pytest.raises(ValueError, match="demo_1 has no 'actions' dataset"):
        import_robosuite_hdf5(broken, env, progress=False)
    with pytest.raises(ValueError, match="unknown demonstration source prefix 'lerobot'"):
        load_demo_source(f"lerobot:{path}", env)


def test_the_command_line_imports_into_a_demo_folder(recording, tmp_path, capsys):
    from torchrl_mpail2.demos import main

    path, _ = recording
    out = tmp_path / "lift_teleop"
    assert main(["import", "robosuite_hdf5", str(path), "--env", "robosuite/Lift", "--out", str(out),
                 "--no-progress"]) == 0
    assert "wrote" in capsys.readouterr().out
    header = json.loads((out / "header.json").read_text())
    assert header["env_id"] == "robosuite/Lift" and header["source"]["format"] == "robosuite_hdf5"
    assert len(header["episodes"]) == 2


def test_a_saved_config_keeps_the_source_prefix_with_an_absolute_path(tmp_path):
    from torchrl_mpail2.trainers import ExperimentConfig
    from torchrl_mpail2.config import resolve_for_run

    cfg = ExperimentConfig()
    cfg.train.demos = "robosuite_hdf5:teleop/demo.hdf5"
    assert resolve_for_run(cfg, "run").train.demos == f"robosuite_hdf5:{tmp_path / 'teleop' / 'demo.hdf5'}"
    cfg.train.demos = "demos/lift"
    assert resolve_for_run(cfg, "run").train.demos == str(tmp_path / "demos" / "lift")


def test_a_demonstrations_frames_match_the_learners_frames_of_the_same_states(tmp_path):
    """Frames replayed from a recording by the importer's env match the frames the learner's env (which recorded it)
    rendered live. The importer rebuilds the scene from the recorded MJCF text, whose rounded numbers move a few
    pixels by one intensity level; built from the same model, two envs' frames are bit-identical
    (``test_robosuite_envs.py::test_recorder_and_learner_envs_render_identical_frames``)."""
    path, rollouts = _record_with_robosuites_writer(tmp_path, episodes=1, obs="pixels")
    demos = import_robosuite_hdf5(path, make_env("robosuite/Lift", obs="pixels"), progress=False)
    got, live = demos.episode(0), rollouts[0]
    for key in ("external_image", "wrist_image"):
        assert got[key].shape == live[key].shape
        # states[0] is the reset state, computed by both envs with mj_forward: the same scene
        first = (got[key][0].float() - live[key][0].float()).abs()
        assert first.max() <= 1 and first.mean() < 0.01, key
        # later states: the physics substep of the replay (see the state test above) moves edges by a pixel
        assert (got[key].float() - live[key].float()).abs().mean() < 3, key


@pytest.fixture(scope="module")
def lift_and_state():
    """A Lift env, its model's MJCF and its flattened mujoco state after a reset (32 wide)."""
    env = make_env("robosuite/Lift", seed=0)
    env.reset()
    sim = _base(env).sim_env.sim
    return env, sim.model.get_xml(), sim.get_state().flatten()


def _hand_written(path, xml, states, env_info='{"env_name": "Lift"}'):
    """A demo.hdf5 in robosuite's layout holding one demo of the given states (zero actions)."""
    with h5py.File(path, "w") as f:
        data = f.create_group("data")
        data.attrs["env"], data.attrs["env_info"] = "Lift", env_info
        demo = data.create_group("demo_1")
        demo.attrs["model_file"] = xml
        demo.create_dataset("states", data=states)
        demo.create_dataset("actions", data=np.zeros((len(states), 7)))
    return path


def test_a_truncated_demo_hdf5_is_refused_naming_it(tmp_path, lift_and_state):
    env, xml, state = lift_and_state
    cut = _hand_written(tmp_path / "demo.hdf5", xml, np.stack([state] * 3))
    os.truncate(cut, cut.stat().st_size // 2)
    with pytest.raises(ValueError, match=r"demo\.hdf5 cannot be read as HDF5: the file is truncated"):
        import_robosuite_hdf5(cut, env, progress=False)


def test_env_info_that_is_not_json_is_refused_naming_file_and_attribute(tmp_path, lift_and_state):
    env, xml, state = lift_and_state
    path = _hand_written(tmp_path / "demo.hdf5", xml, np.stack([state] * 3), env_info="{env_name: Lift")
    with pytest.raises(ValueError, match=r"demo\.hdf5: the attribute 'env_info' is not JSON"):
        import_robosuite_hdf5(path, env, progress=False)


def test_states_with_nan_or_of_another_width_are_refused_naming_the_demo(tmp_path, lift_and_state):
    env, xml, state = lift_and_state
    states = np.stack([state] * 3)
    good = import_robosuite_hdf5(_hand_written(tmp_path / "good.hdf5", xml, states), env, progress=False)
    assert good.episode_lengths == [2]  # the file is well made but for the faults below
    with_nan = states.copy()
    with_nan[1, 5] = np.nan
    with pytest.raises(ValueError, match=r"nan\.hdf5: demo_1/states holds NaN or Inf at step\(s\) \[1\]"):
        import_robosuite_hdf5(_hand_written(tmp_path / "nan.hdf5", xml, with_nan), env, progress=False)
    with pytest.raises(ValueError, match=rf"narrow\.hdf5: demo_1/states are 20 wide, the flattened mujoco state of "
                                         rf"its model_file is {state.size} wide"):
        import_robosuite_hdf5(_hand_written(tmp_path / "narrow.hdf5", xml, states[:, :20]), env, progress=False)


def test_a_file_without_control_freq_warns_naming_it(tmp_path, lift_and_state):
    """robosuite's collect_human_demonstrations records no control_freq in env_info: the rate cannot be checked."""
    from torchrl_mpail2.envs.robosuite_control import CONTROL_FREQ_HZ

    env, xml, state = lift_and_state
    states = np.stack([state] * 3)
    with pytest.warns(RuntimeWarning, match=r"no_rate\.hdf5: env_info records no control_freq, so the control rate "
                                            rf"could not be checked: .* at the env's {CONTROL_FREQ_HZ} Hz"):
        import_robosuite_hdf5(_hand_written(tmp_path / "no_rate.hdf5", xml, states), env, progress=False)
    rated = _hand_written(tmp_path / "rated.hdf5", xml, states,
                          env_info=json.dumps({"env_name": "Lift", "control_freq": CONTROL_FREQ_HZ}))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        import_robosuite_hdf5(rated, env, progress=False)


def test_an_import_with_a_presets_env_options_trains_with_it_and_a_mismatch_names_the_option(tmp_path, lift_and_state):
    """``demos import --preset lift_state`` replays through the preset's env (the gripper command observed, 27
    proprioception values) and records its options; demos imported without them are refused by the run of that
    preset naming the option."""
    from torchrl_mpail2.demos import main
    from torchrl_mpail2.trainers import preset
    from torchrl_mpail2.trainers.run_demos import load_or_record_demos

    _, xml, state = lift_and_state
    path = _hand_written(tmp_path / "demo.hdf5", xml, np.stack([state] * 3))
    common = ["import", "robosuite_hdf5", str(path), "--no-progress", "--out"]
    with pytest.warns(RuntimeWarning, match="control_freq"):
        assert main([*common, str(tmp_path / "plain"), "--env", "robosuite/Lift"]) == 0
        assert main([*common, str(tmp_path / "lift_state"), "--preset", "lift_state"]) == 0
        assert main([*common, str(tmp_path / "explicit"), "--preset", "lift_state",
                     "--env-kwargs", '{"observe_gripper_command": false}']) == 0
    cfg = preset("lift_state")
    env = make_env(cfg.train.env, obs=cfg.train.obs, **cfg.train.env_kwargs)
    cfg.train.demos = str(tmp_path / "lift_state")
    demos = load_or_record_demos(cfg, env, env_fn=None)
    assert demos.observations["proprio"].shape[-1] == 27
    assert demos.header["env_kwargs"] == {"obs": "state", "observe_gripper_command": True}
    assert load_demos(tmp_path / "explicit").header["env_kwargs"] == {"obs": "state", "observe_gripper_command": False}
    cfg.train.demos = str(tmp_path / "plain")
    with pytest.raises(ValueError, match=r"'proprio' has shape \(26,\) in the demonstrations but \(27,\) .* likely "
                                         r"differs: observe_gripper_command \(demos: not set, env: True\)"):
        load_or_record_demos(cfg, env, env_fn=None)
