"""Bad input and injected faults (issue #14): each is refused with a message naming its cause, or recovered from."""
from dataclasses import fields

import pytest

from torchrl_mpail2.config import ConfigError, LossConfig, ModelConfig, PlannerConfig, field_kind
from torchrl_mpail2.trainers import TrainConfig, apply_overrides, preset


# ---- configuration -----------------------------------------------------------------------------------
@pytest.mark.parametrize("override, message", [
    ("train.batch_size=abc", r"train.batch_size='abc': expected an integer"),
    ("train.batch_size=1e3", r"train.batch_size='1e3': expected an integer"),
    ("train.batch_size=3.5", r"train.batch_size='3.5': expected an integer"),
    ("model.hidden_dims=64,abc", r"model.hidden_dims='64,abc' \(item 'abc'\): expected .*integer"),
    ("train.utd=fast", r"train.utd='fast': expected a number"),
    ("train.progress=maybe", r"train.progress='maybe': expected a boolean"),
])
def test_an_unparsable_override_names_field_value_and_type(override, message):
    with pytest.raises(ConfigError, match=message):
        apply_overrides(preset("point_mass"), [override])


@pytest.mark.parametrize("override, message", [
    ("planner.temperature=nan", "PlannerConfig.temperature must be finite, got nan"),
    ("planner.temperature=inf", "PlannerConfig.temperature must be finite, got inf"),
    ("train.utd=nan", "TrainConfig.utd must be finite"),
    ("train.replay_size=-10", r"TrainConfig.replay_size must be >= 1 \(or null\), got -10"),
    ("train.replay_size=0", r"TrainConfig.replay_size must be >= 1"),
    ("train.max_wall_s=-1", "TrainConfig.max_wall_s must be > 0"),
    ("train.threads=-1", "TrainConfig.threads must be >= 1"),
    ("train.eval_every=-3", "TrainConfig.eval_every must be >= 0"),
    ("train.checkpoint_every=-1", "TrainConfig.checkpoint_every must be >= 0"),
    ("train.last_every=-1", "TrainConfig.last_every must be >= 0"),
    ("loss.lr=-0.1", "LossConfig.lr must be > 0"),
    ("loss.gamma=1.5", r"LossConfig.gamma must lie in \[0, 1\]"),
    ("model.obs_clip=0", "ModelConfig.obs_clip must be > 0"),
    ("model.log_std_min=-inf", "ModelConfig.log_std_min must be finite"),
])
def test_out_of_range_or_non_finite_values_fail_before_training(override, message):
    with pytest.raises(ConfigError, match=message):
        apply_overrides(preset("point_mass"), [override])


def test_a_config_file_with_a_wrongly_typed_value_names_the_field():
    from torchrl_mpail2.trainers import ExperimentConfig

    data = preset("point_mass").to_dict()
    data["train"]["batch_size"] = "64"
    with pytest.raises(ConfigError, match="TrainConfig.batch_size must be an integer, got '64'"):
        ExperimentConfig.from_dict(data)


@pytest.mark.parametrize("cls", [TrainConfig, ModelConfig, LossConfig, PlannerConfig])
def test_every_numeric_config_field_declares_its_range(cls):
    numeric = [f.name for f in fields(cls) if field_kind(cls, f.name).numeric]
    assert numeric and sorted(set(numeric) - set(cls.RANGES)) == []
