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


# ---- demonstrations ----------------------------------------------------------------------------------
def _demos_with_nan():
    import torch

    from torchrl_mpail2.data import demos_from_arrays

    demos = demos_from_arrays([torch.zeros(4, 2), torch.ones(3, 2), torch.ones(5, 2)], env_id="toy")
    demos.observations["observation"][4 + 3 + 1] = float("nan")  # episode 2, step 1
    return demos


def test_nan_or_inf_in_demonstrations_is_refused_when_recorded_naming_key_and_episode():
    import torch

    from torchrl_mpail2.data import demos_from_arrays, record_demos
    from torchrl_mpail2.envs import PointMassEnv, with_bookkeeping
    from torchrl_mpail2.experts import PointMassExpert

    with pytest.raises(ValueError, match=r"'observation' holds NaN or Inf in episode\(s\) \[1\]"):
        demos_from_arrays([torch.zeros(4, 2), torch.tensor([[0.0, 0.0], [float("inf"), 0.0]])])

    class Diverging(PointMassEnv):
        steps = 0

        def _step(self, tensordict):
            out = super()._step(tensordict)
            Diverging.steps += 1
            if Diverging.steps == 50 + 7:  # inside the second episode
                out["observation"][0] = float("nan")
            return out

    with pytest.raises(ValueError, match=r"'observation' holds NaN or Inf in episode\(s\) \[1\]"):
        record_demos(with_bookkeeping(Diverging(seed=0)), PointMassExpert(), episodes=2, progress=False)


def test_nan_in_demonstrations_is_refused_when_saved_and_when_loaded(tmp_path):
    from tensordict import TensorDict

    from torchrl_mpail2.data import DemoFormatError, demos_from_arrays, load_demos, save_demos
    from torchrl_mpail2.data.checksums import folder_manifest
    import json
    import torch

    with pytest.raises(ValueError, match=r"Not saving demonstrations to .*bad.*'observation' holds NaN or Inf in episode\(s\) \[2\]"):
        save_demos(_demos_with_nan(), tmp_path / "bad")
    assert not (tmp_path / "bad").exists()
    # data written with NaN by other means (its checksums match): loading names the key and the episode
    path = save_demos(demos_from_arrays([torch.zeros(4, 2), torch.ones(3, 2)]), tmp_path / "demos")
    stored = TensorDict.load_memmap(path / "observations")
    stored["observation"][5] = float("nan")
    header = json.loads((path / "header.json").read_text())
    header["files"] = folder_manifest(path, "observations")
    (path / "header.json").write_text(json.dumps(header))
    with pytest.raises(DemoFormatError, match=r"demos: observation key 'observation' holds NaN or Inf in episode\(s\) \[1\]"):
        load_demos(path)
