import json

import pytest

from torchrl_mpail2.config import PRESETS, ConfigError, preset
from torchrl_mpail2.train import main


def printed_config(capsys, argv):
    assert main([*argv, "--print-config"]) is None
    return json.loads(capsys.readouterr().out)


def test_env_and_obs_flags_are_overrides_of_their_fields_and_nothing_else(capsys):
    base = preset("lift_state").to_dict()
    cfg = printed_config(capsys, ["--preset", "lift_state", "--obs", "pixels", "--env", "robosuite/Push"])
    assert cfg["train"]["obs"] == "pixels" and cfg["train"]["env"] == "robosuite/Push"
    assert cfg["model"] == json.loads(json.dumps(base["model"]))  # the latent size stays the preset's
    # an explicit override given after the shorthand wins, as any later override does
    assert printed_config(capsys, ["--obs", "pixels", "train.obs=state"])["train"]["obs"] == "state"


def test_a_bad_obs_flag_is_refused_by_name(capsys):
    with pytest.raises(SystemExit) as exit_info:
        main(["--obs", "thermal", "--print-config"])
    assert exit_info.value.code == 2
    assert "unknown TrainConfig.obs 'thermal'" in capsys.readouterr().err


@pytest.mark.parametrize("argv, message", [
    (["train.batch_size=abc"], "error: train.batch_size='abc': expected an integer"),
    (["planner.temp=1"], "error: unknown field planner.temp"),
    (["--resume", "no_such_run"], "error: --resume no_such_run: cannot resume no_such_run"),
])
def test_a_bad_field_value_or_run_folder_is_one_line_and_status_2(capsys, argv, message):
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and message in err and len(err.strip().splitlines()) == 1
    assert "Traceback" not in err


def test_help_config_lists_every_field_with_its_type_value_and_docstring(capsys):
    from torchrl_mpail2.config import field_docs
    from torchrl_mpail2.config import TrainConfig

    assert main(["--preset", "push_video_only", "--help-config"]) is None
    out = capsys.readouterr().out
    assert "  train.demo_keys (comma-separated values, each a string or null) = [\"external_image\"]" in out
    assert "  model.reward_latent_keys (comma-separated values, each a string or null)" in out
    assert "Observation keys the demonstrations keep" in out  # the field's docstring, wrapped
    docs = field_docs(TrainConfig)
    assert all(docs.values()), [name for name, doc in docs.items() if not doc]  # every field says what it does
    assert out.count("  train.") == len(docs)
    main(["--help-config", "planner"])
    assert "planner.num_candidates" in (section := capsys.readouterr().out) and "train.env" not in section


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_every_preset_builds_and_the_paper_pixel_preset_has_the_image_latent(name):
    cfg = preset(name)
    if name.startswith("paper") and cfg.train.obs != "state":
        assert cfg.model.latent_dim == 512  # Table 4


def test_the_cpu_camera_presets_are_their_state_presets_with_cameras_batch_64_and_lifts_reward():
    for pixels, state in (("push_pixels", "push_state"), ("lift_pixels", "lift_state")):
        got, want = preset(pixels).to_dict(), preset(state).to_dict()
        assert (got["train"].pop("obs"), got["train"].pop("batch_size")) == ("pixels", 64)
        assert got["train"]["utd"] == want["train"]["utd"] == 1.0  # Table 4's UTD, as the state presets have it
        # the raw critic with a penalty of 10, as lift_state has it
        assert (got["loss"].pop("reward_scale_momentum"), got["loss"].pop("gp_coef")) == (None, 10.0)
        assert (got["model"].pop("image_head"), want["model"].pop("image_head")) == ("keypoints", "flatten")
        for section, key in (("train", "obs"), ("train", "batch_size"),
                             ("loss", "reward_scale_momentum"), ("loss", "gp_coef")):
            want[section].pop(key)
        assert got == want


def test_lift_uses_the_raw_critic_with_penalty_10_and_push_keeps_the_reward_it_was_measured_with():
    lift, push = preset("lift_state").to_dict(), preset("push_state").to_dict()
    assert (lift["loss"]["reward_scale_momentum"], lift["loss"]["gp_coef"]) == (None, 10.0)
    assert (push["loss"]["reward_scale_momentum"], push["loss"]["gp_coef"]) == (0.99, 0.1)
    # otherwise Push is Lift's configuration on another task
    for section in ("model", "planner"):
        assert push[section] == lift[section]
    differing = {k for k in lift["loss"] if lift["loss"][k] != push["loss"][k]}
    assert differing == {"reward_scale_momentum", "gp_coef"}
    assert {k for k in lift["train"] if lift["train"][k] != push["train"][k]} == {"env"}


def test_tuple_fields_take_commas_or_a_json_list_and_a_torn_list_is_named():
    from torchrl_mpail2.trainers import apply_overrides

    for text in ("external_image,wrist_image", '["external_image", "wrist_image"]'):
        cfg = apply_overrides(preset("push_pixels"), [f"train.demo_keys={text}", "model.hidden_dims=[128, 64]"])
        assert cfg.train.demo_keys == ("external_image", "wrist_image") and cfg.model.hidden_dims == (128, 64)
    with pytest.raises(ConfigError, match=r"model.hidden_dims='\[12': expected .* or a JSON list"):
        apply_overrides(preset("push_pixels"), ["model.hidden_dims=[12"])
    with pytest.raises(ConfigError, match="TrainConfig.demo_keys must be a non-empty list"):
        apply_overrides(preset("push_pixels"), ["train.demo_keys=[]"])
