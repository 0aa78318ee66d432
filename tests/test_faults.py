"""Bad input and injected faults (issue #14): each is refused with a message naming its cause, or recovered from."""
import json
from dataclasses import fields

import pytest

from conftest import QUIET_RUN, flip_a_byte
from conftest import short_run_cfg as _cfg
from conftest import train_short_run as _trained
from torchrl_mpail2.config import ConfigError, LossConfig, ModelConfig, PlannerConfig
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
    ("model.obs_clip=0", "ModelConfig.obs_clip must be > 0"),
    ("model.log_std_min=-inf", "ModelConfig.log_std_min must be finite"),
])
def test_out_of_range_or_non_finite_values_fail_before_training(override, message):
    with pytest.raises(ConfigError, match=message):
        apply_overrides(preset("point_mass"), [override])


def test_typed_overrides_from_python_are_checked_like_strings():
    cfg = apply_overrides(preset("point_mass"), {"train.total_episodes": 7, "model.hidden_dims": [32, 32]})
    assert cfg.train.total_episodes == 7 and cfg.model.hidden_dims == (32, 32)
    with pytest.raises(ConfigError, match="TrainConfig.total_episodes must be >= 1, got 0"):
        apply_overrides(preset("point_mass"), {"train.total_episodes": 0})
    with pytest.raises(ConfigError, match="TrainConfig.batch_size must be an integer, got '64'"):
        apply_overrides(preset("point_mass"), {"train.batch_size": "64"})
    with pytest.raises(ConfigError, match="unknown field planner.temp"):
        apply_overrides(preset("point_mass"), {"planner.temp": 1.0})


def test_a_config_file_with_a_wrongly_typed_value_names_the_field():
    from torchrl_mpail2.trainers import ExperimentConfig

    data = preset("point_mass").to_dict()
    data["train"]["batch_size"] = "64"
    with pytest.raises(ConfigError, match="TrainConfig.batch_size must be an integer, got '64'"):
        ExperimentConfig.from_dict(data)


def test_a_config_file_of_an_older_version_with_planner_gamma_still_loads():
    from torchrl_mpail2.trainers import ExperimentConfig

    data = preset("point_mass").to_dict()
    data["planner"]["gamma"] = data["loss"]["gamma"]  # written when the discount was kept in both sections
    assert ExperimentConfig.from_dict(data) == preset("point_mass")
    data["planner"]["gamma"] = 0.5
    with pytest.raises(ConfigError, match=r"planner.gamma \(0.5\) differs from loss.gamma \(0.99\)"):
        ExperimentConfig.from_dict(data)


#: A value other than the one the code now runs, per removed field.
REMOVED_FIELD_OTHER_VALUES = {"planner.temperature_scale": "elite_spread", "loss.expert_start_fraction": 0.5}


def test_a_config_file_holding_removed_fields_loads_at_their_kept_values_and_names_them_otherwise(tmp_path):
    from torchrl_mpail2.config import REMOVED_FIELDS
    from torchrl_mpail2.config import read_run_config

    assert set(REMOVED_FIELD_OTHER_VALUES) == set(REMOVED_FIELDS)
    data = preset("point_mass").to_dict()
    for name, (kept, _) in REMOVED_FIELDS.items():
        section, field = name.split(".")
        data[section][field] = kept  # a config.json written before the field was removed
    (tmp_path / "config.json").write_text(json.dumps(data))
    assert read_run_config(tmp_path) == preset("point_mass")
    for name, other in REMOVED_FIELD_OTHER_VALUES.items():
        section, field = name.split(".")
        changed = {**data, section: {**data[section], field: other}}
        (tmp_path / "config.json").write_text(json.dumps(changed))
        with pytest.raises(ConfigError, match=rf"{name}={other!r}: the field was removed after commit "
                                              rf"{REMOVED_FIELDS[name][1]}"):
            read_run_config(tmp_path)
    data["train"]["update_precision"] = "bf16_stop_gradient"  # a removed value of a field that stays
    (tmp_path / "config.json").write_text(json.dumps(data))
    with pytest.raises(ConfigError, match="update_precision='bf16_stop_gradient' was removed after commit 7137cb5"):
        read_run_config(tmp_path)


@pytest.mark.parametrize("cls", [TrainConfig, ModelConfig, LossConfig, PlannerConfig])
def test_every_numeric_config_field_declares_its_range(cls):
    from torchrl_mpail2.config import field_kind

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

    import json

    import torch

    from torchrl_mpail2.data import DemoFormatError, demos_from_arrays, load_demos, save_demos

    with pytest.raises(ValueError, match=r"Not saving demonstrations to .*bad.*'observation' holds NaN or Inf in episode\(s\) \[2\]"):
        save_demos(_demos_with_nan(), tmp_path / "bad")
    assert not (tmp_path / "bad").exists()
    from torchrl_mpail2.data.checksums import folder_manifest

    # data written with NaN by other means (its checksums match): loading names the key and the episode
    path = save_demos(demos_from_arrays([torch.zeros(4, 2), torch.ones(3, 2)]), tmp_path / "demos")
    stored = TensorDict.load_memmap(path / "observations")
    stored["observation"][5] = float("nan")
    header = json.loads((path / "header.json").read_text())
    header["files"] = folder_manifest(path, "observations")
    (path / "header.json").write_text(json.dumps(header))
    with pytest.raises(DemoFormatError, match=r"demos: observation key 'observation' holds NaN or Inf in episode\(s\) \[1\]"):
        load_demos(path)


# ---- checkpoints, replay and run folders ----------------------------------------------------------------
def _episodes_logged(run):
    import json

    return [json.loads(line)["episode"] for line in (run / "metrics.jsonl").read_text().splitlines()]


def test_a_flipped_byte_in_a_checkpoint_is_refused_naming_the_file(demo_dir, tmp_path):
    from torchrl_mpail2.trainers import MPAIL2Trainer

    run = _trained(demo_dir, tmp_path / "run")
    state = run / "checkpoints" / "last" / "state.pt"
    flip_a_byte(state)
    with pytest.raises(RuntimeError, match=r"last/state.pt is corrupted: its sha256 does not match"):
        MPAIL2Trainer.resume(run)


def test_a_truncated_stored_replay_is_refused_naming_the_file(demo_dir, tmp_path):
    from torchrl_mpail2.trainers import MPAIL2Trainer

    run = _trained(demo_dir, tmp_path / "run")
    stored = run / "checkpoints" / "last" / "replay" / "storage" / "observation.memmap"
    stored.write_bytes(stored.read_bytes()[: stored.stat().st_size // 4])
    with pytest.raises(RuntimeError, match=r"observation.memmap is truncated or corrupted: \d+ bytes on disk"):
        MPAIL2Trainer.resume(run)


def test_a_checkpoint_holds_the_stored_replay_steps_alone_and_resumes_to_the_same_samples(demo_dir, tmp_path):
    """The live replay memmap spans the whole capacity (sparse on disk); its checkpoint copies the stored steps
    alone (issue 48: it copied the whole capacity), and a resumed run samples from them as the run would have."""
    import torch

    from torchrl_mpail2.trainers import MPAIL2Trainer

    run = tmp_path / "run"
    trainer = MPAIL2Trainer(_cfg(demo_dir, "train.replay_size=100000"), run_dir=run)
    trainer.train()
    stored = run / "checkpoints" / "last" / "replay" / "storage" / "observation.memmap"
    row = trainer.replay._storage._storage["observation"][0]
    assert len(trainer.replay) == 100 and stored.stat().st_size == 100 * row.numel() * row.element_size()
    torch.manual_seed(5)
    expected = trainer.replay.sample().exclude("expert")
    resumed = MPAIL2Trainer.resume(run, ["train.total_episodes=3"])
    assert len(resumed.replay) == 100 and resumed.replay._writer._cursor == trainer.replay._writer._cursor
    torch.manual_seed(5)
    assert (resumed.replay.sample().exclude("expert") == expected).all()
    resumed.train()  # and it goes on from there
    assert len(resumed.replay) == 150
    stored = run / "checkpoints" / "last" / "replay" / "storage" / "observation.memmap"
    assert stored.stat().st_size == 150 * row.numel() * row.element_size()


def test_a_zero_byte_state_file_is_refused_naming_the_file(demo_dir, tmp_path):
    from torchrl_mpail2.data.checkpoint import read_checkpoint

    run = _trained(demo_dir, tmp_path / "run")
    state = run / "checkpoints" / "last" / "state.pt"
    state.write_bytes(b"")
    with pytest.raises(RuntimeError, match=r"last/state.pt is truncated or corrupted: 0 bytes on disk") as err:
        read_checkpoint(run / "checkpoints" / "last")
    from torchrl_mpail2.data.checkpoint import CheckpointError

    assert isinstance(err.value, CheckpointError)
    (run / "checkpoints" / "last" / "manifest.json").unlink()  # a checkpoint written before manifests
    with pytest.warns(RuntimeWarning, match="not verified"), pytest.raises(RuntimeError, match=r"state.pt cannot be read"):
        read_checkpoint(run / "checkpoints" / "last")


def test_a_crash_between_the_renames_resumes_from_the_complete_old_checkpoint(demo_dir, tmp_path):
    import os

    from torchrl_mpail2.trainers import MPAIL2Trainer
    from torchrl_mpail2.data.checkpoint import read_checkpoint

    run = _trained(demo_dir, tmp_path / "run")
    checkpoints = run / "checkpoints"
    saved = read_checkpoint(checkpoints / "last")["counters"]
    os.replace(checkpoints / "last", checkpoints / ".last.old")
    (checkpoints / ".last.tmp").mkdir()  # the new one, cut short before its manifest
    (checkpoints / ".last.tmp" / "state.pt").write_bytes(b"partial")
    with pytest.warns(RuntimeWarning, match=r"resuming from .*\.last\.old \(episode 2\)"):
        trainer = MPAIL2Trainer.resume(run)
    assert trainer.counters == saved and len(trainer.replay) == 100
    trainer.close()


def test_last_is_written_every_last_every_episodes_before_the_first_evaluation(demo_dir, tmp_path):
    from torchrl_mpail2.trainers import MPAIL2Trainer
    trainer = MPAIL2Trainer(_cfg(demo_dir, "train.total_episodes=4", "train.last_every=2", "train.eval_every=4",
                                 "train.eval_episodes=1"), run_dir=tmp_path / "run")
    written = []
    save = trainer.save
    trainer.save = lambda tag, with_replay=False: written.append((tag, trainer.counters["episodes"], with_replay)) or save(tag, with_replay)
    trainer.train()
    assert ("last", 2, True) in written and ("last", 4, True) in written
    assert [w for w in written if w[0] == "last"].count(("last", 4, True)) == 1  # not twice at the evaluation
    from torchrl_mpail2.data.checkpoint import checkpoint_episodes

    assert checkpoint_episodes(tmp_path / "run" / "checkpoints" / "last") == 4


def test_resume_falls_back_to_the_newest_numbered_checkpoint(demo_dir, tmp_path):
    import shutil

    from torchrl_mpail2.trainers import MPAIL2Trainer

    run = _trained(demo_dir, tmp_path / "run", "train.total_episodes=3", "train.checkpoint_every=1")
    shutil.rmtree(run / "checkpoints" / "last")
    with pytest.warns(RuntimeWarning, match=r"resuming from .*episode_000003 \(episode 3\)"):
        trainer = MPAIL2Trainer.resume(run)
    assert trainer.counters["episodes"] == 3
    trainer.close()


def test_a_torn_last_line_of_the_metrics_is_dropped_with_a_warning(demo_dir, tmp_path):
    from torchrl_mpail2.trainers import MPAIL2Trainer

    run = _trained(demo_dir, tmp_path / "run")
    with open(run / "metrics.jsonl", "a") as f:
        f.write('{"episode": 3, "succ')
    with pytest.warns(RuntimeWarning, match=r"metrics.jsonl: dropping its torn last line"):
        trainer = MPAIL2Trainer.resume(run, ["train.total_episodes=3"])
    trainer.train()
    assert _episodes_logged(run) == [1, 2, 3]
    (run / "eval.jsonl").write_text('{"episode": 1}\nnot json\n{"episode": 2}\n')
    from torchrl_mpail2.trainers.plots import read_jsonl
    with pytest.raises(ValueError, match=r"eval.jsonl, line 2 is not JSON"):
        read_jsonl(run / "eval.jsonl")


def test_a_finished_run_can_be_extended_on_resume(demo_dir, tmp_path):
    from torchrl_mpail2.config import ConfigError
    from torchrl_mpail2.trainers import MPAIL2Trainer

    run = _trained(demo_dir, tmp_path / "run")
    with pytest.raises(ConfigError, match=r"\['train.batch_size'\] cannot change"):
        MPAIL2Trainer.resume(run, ["train.batch_size=4"])
    with pytest.raises(ConfigError, match=r"\['model.horizon'\] cannot change"):
        MPAIL2Trainer.resume(run, {"model.horizon": 4})
    # a Ray run may go on on another cluster; its address is checked like the rest (it needs collector='ray')
    with pytest.raises(ConfigError, match="ray_address='auto' applies to collector='ray' only"):
        MPAIL2Trainer.resume(run, ["train.ray_address=auto"])
    # typed, from Python; denser checkpoints may be asked of a resumed run (they change nothing it learns)
    trainer = MPAIL2Trainer.resume(run, {"train.total_episodes": 3, "train.checkpoint_every": 3})
    first_launch = json.loads((run / "summary.json").read_text())
    summary = trainer.train()
    assert summary["episodes"] == 3 and len(trainer.replay) == 150 and _episodes_logged(run) == [1, 2, 3]
    # the run's wall time counts the first launch (to its final checkpoint) and the extension
    assert summary["run_wall_time_s"] >= first_launch["wall_time_s"] + summary["wall_time_s"] - 1.0
    assert first_launch["run_wall_time_s"] == pytest.approx(first_launch["wall_time_s"], abs=1.0)
    assert '"total_episodes": 3' in (run / "config.json").read_text()
    assert [p.name for p in sorted((run / "checkpoints").glob("episode_*"))] == ["episode_000003"]


def test_resume_with_other_network_sizes_names_the_fields(demo_dir, tmp_path):
    import json

    from torchrl_mpail2.trainers import MPAIL2Trainer

    run = _trained(demo_dir, tmp_path / "run")
    config = json.loads((run / "config.json").read_text())
    config["model"]["hidden_dims"], config["model"]["latent_dim"] = [32], 16
    (run / "config.json").write_text(json.dumps(config))
    with pytest.raises(RuntimeError, match=r"model.hidden_dims: \[64, 64\] in the checkpoint, \[32\] now"):
        MPAIL2Trainer.resume(run)
    with pytest.raises(RuntimeError, match=r"model.latent_dim: 32 in the checkpoint, 16 now"):
        MPAIL2Trainer.resume(run)


def test_relative_paths_are_saved_resolved(demo_dir, tmp_path, monkeypatch):
    import json
    import shutil

    from torchrl_mpail2.trainers import MPAIL2Trainer

    shutil.copytree(demo_dir, tmp_path / "demos" / "pm")  # tmp_path is the working directory (conftest.py)
    MPAIL2Trainer(_cfg("demos/pm", "train.run_dir=runs/a")).train()
    saved = json.loads((tmp_path / "runs" / "a" / "config.json").read_text())["train"]
    assert saved["demos"] == str(tmp_path / "demos" / "pm") and saved["run_dir"] == str(tmp_path / "runs" / "a")
    (tmp_path / "elsewhere").mkdir()
    monkeypatch.chdir(tmp_path / "elsewhere")
    MPAIL2Trainer.resume(tmp_path / "runs" / "a", ["train.total_episodes=3"]).train()


def test_a_run_folder_is_locked_and_not_reused_without_resume_or_overwrite(demo_dir, tmp_path):
    from torchrl_mpail2.trainers import MPAIL2Trainer

    first = MPAIL2Trainer(_cfg(demo_dir), run_dir=tmp_path / "run")
    with pytest.raises(RuntimeError, match=r"run .* is in use by another training \(pid \d+\)") as err:
        MPAIL2Trainer(_cfg(demo_dir), run_dir=tmp_path / "run")
    from torchrl_mpail2.trainers.run_folder import RunFolderError

    assert isinstance(err.value, RunFolderError)
    with pytest.raises(RuntimeError, match="in use"):
        MPAIL2Trainer.resume(tmp_path / "run")
    first.train()
    with pytest.raises(RuntimeError, match=r"already holds a run .*resume it"):
        MPAIL2Trainer(_cfg(demo_dir), run_dir=tmp_path / "run")
    assert _episodes_logged(tmp_path / "run") == [1, 2]
    MPAIL2Trainer(_cfg(demo_dir), run_dir=tmp_path / "run", if_exists="overwrite").train()
    assert _episodes_logged(tmp_path / "run") == [1, 2]


def test_a_run_that_fails_validation_leaves_no_folder_behind(demo_dir, tmp_path):
    from torchrl.envs import TransformedEnv
    from torchrl.envs.transforms import ActionScaling

    from torchrl_mpail2.envs import make_env
    from torchrl_mpail2.trainers import MPAIL2Trainer

    def wide_actions(seed=0):
        return TransformedEnv(make_env("point_mass", seed=seed), ActionScaling(loc=0.0, scale=2.0))

    with pytest.raises(ValueError, match=r"bounded to \[-1, 1\]"):
        MPAIL2Trainer(_cfg(demo_dir), env_fn=wide_actions, run_dir=tmp_path / "run")
    assert not (tmp_path / "run").exists()


# ---- learning state against one bad batch ---------------------------------------------------------------
def _updater():
    from torchrl_mpail2.config import LossConfig
    from torchrl_mpail2.objectives.mpail2 import MPAIL2Loss
    from torchrl_mpail2.agents.update import MPAIL2Updater

    from conftest import tiny_modules

    return MPAIL2Updater(MPAIL2Loss(tiny_modules(), LossConfig(reward_scale_momentum=0.9)))


def test_a_batch_with_a_nan_observation_is_skipped_whole_counted_and_logged(caplog):
    import torch

    from conftest import replay_batch

    updater = _updater()
    updater.update(replay_batch())
    before = {k: v.clone() for k, v in updater.loss.state_dict().items()}
    adam = [dict(o.state_dict()["state"]) for o in updater.optimizers.values()]
    bad = replay_batch()
    bad["next", "observation"][1, 2, 0] = float("nan")
    with caplog.at_level("WARNING"):
        assert updater.update(bad) is None
    assert "['next.observation']" in caplog.text
    assert updater.skipped["batch"] == 1 and updater.last_nonfinite_keys == ["next.observation"]
    after = updater.loss.state_dict()
    assert all(torch.equal(v, after[k]) for k, v in before.items())  # weights, targets, reward scale, log alpha
    assert [len(o.state_dict()["state"]) for o in updater.optimizers.values()] == [len(a) for a in adam]
    out = updater.update(replay_batch())  # later batches learn as before
    assert torch.isfinite(out["reward_scale"]) and torch.isfinite(out["loss_value"])
    assert sum(updater.skipped.values()) == 1


@pytest.mark.parametrize("sync_free", [False, True], ids=["host-check", "sync-free"])
def test_a_stage_with_a_nan_loss_is_skipped_leaving_its_weights_and_adam_state(monkeypatch, sync_free):
    # sync-free (the GPU default, forced here on the CPU): fused Adam is handed the flag instead of a host check
    import torch
    from torchrl_mpail2.agents.update import MPAIL2Updater

    from conftest import replay_batch

    loss = _updater().loss
    updater = MPAIL2Updater(loss, sync_free_skips=sync_free)
    updater.update(replay_batch())  # Adam has state from here on
    value = updater.optimizers["value"]
    params = [p for g in value.param_groups for p in g["params"]]
    before = [p.detach().clone() for p in params]
    adam_before = {(id(param), name): t.clone() for param, st in value.state.items() for name, t in st.items()}
    reward_before = [p.detach().clone() for g in updater.optimizers["reward"].param_groups for p in g["params"]]
    forward = loss.value_loss.forward

    def nan_value_loss(*args, **kwargs):
        out = forward(*args, **kwargs)
        out.set("loss_value", out["loss_value"] * float("nan"))
        return out

    monkeypatch.setattr(loss.value_loss, "forward", nan_value_loss)
    metrics = updater.update(replay_batch())
    assert metrics["nonfinite_skips"].item() == 1
    assert all(torch.equal(a, p) for a, p in zip(before, params))  # no step with NaN gradients
    adam_after = {(id(param), name): t for param, st in value.state.items() for name, t in st.items()}
    assert adam_after.keys() == adam_before.keys()
    assert all(torch.equal(adam_before[k], adam_after[k]) for k in adam_before), "moments or step count moved"
    reward_after = [p for g in updater.optimizers["reward"].param_groups for p in g["params"]]
    assert any(not torch.equal(a, p) for a, p in zip(reward_before, reward_after))  # the other stages still learn
    assert dict(updater.skipped) == {"value": 1}
    assert updater.state_dict()["skipped"] == {"value": 1}


@pytest.mark.parametrize("saved_sync_free, sync_free", [(False, True), (True, False)])
def test_an_updater_resumes_another_kinds_adam_state_in_its_own_kind(saved_sync_free, sync_free):
    # a CPU checkpoint (plain Adam) resumed on a GPU (fused Adam, NaN flag on the device), and the reverse
    import torch
    from torchrl_mpail2.agents.update import MPAIL2Updater

    from conftest import replay_batch

    saved = MPAIL2Updater(_updater().loss, sync_free_skips=saved_sync_free)
    saved.update(replay_batch())
    updater = MPAIL2Updater(saved.loss, sync_free_skips=sync_free)
    updater.load_state_dict(saved.state_dict())
    assert all(g["fused"] is (True if sync_free else None) for o in updater.optimizers.values() for g in o.param_groups)
    metrics = updater.update(replay_batch())  # plain Adam refuses the NaN flag that fused Adam takes
    assert torch.isfinite(metrics["loss_value"]) and metrics["nonfinite_skips"].item() == 0
    assert all(st["step"].item() == 2 for o in updater.optimizers.values() for st in o.state.values())


def test_one_nan_batch_through_the_loss_in_training_mode_leaves_the_reward_scale_finite():
    import torch

    from conftest import replay_batch

    loss = _updater().loss
    loss.train()
    loss(replay_batch())
    net = loss.components.reward.module
    scale, updates = net.reward_scale.clone(), net.scale_updates.clone()
    bad = replay_batch()
    bad["observation"][0, 0, 0] = float("nan")
    loss(bad)
    assert torch.equal(net.reward_scale, scale) and torch.equal(net.scale_updates, updates)
    assert torch.isfinite(loss(replay_batch())["reward_scale"])
    fresh = _updater().loss.components.reward.module  # a first call with NaN leaves the initial scale of 1
    fresh.track_scale(torch.tensor([1.0, float("nan")]), 0.9)
    assert fresh.reward_scale.item() == 1.0


def test_the_learners_nan_actions_stop_training_at_once_naming_the_cause(demo_dir, tmp_path):
    import torch

    from torchrl_mpail2.trainers import MPAIL2Trainer

    trainer = MPAIL2Trainer(_cfg(demo_dir, "train.total_episodes=3"), run_dir=tmp_path / "run")
    with torch.no_grad():
        next(trainer.agent.modules.dynamics.parameters()).fill_(float("nan"))
    with pytest.raises(FloatingPointError, match=r"episode 2, after \d+ updates: LatentMPPIPlanner returned non-finite") as err:
        trainer.train()
    from torchrl_mpail2.planners.policy_actor import NonFiniteActionError

    assert isinstance(err.value, NonFiniteActionError)
    assert trainer.counters["warnings"] == 0 and trainer.counters["episodes"] == 1


# ---- keys and specs ----------------------------------------------------------------------------------
def _with_episode_reward(seed=0):
    from torchrl.envs import RewardSum

    from torchrl_mpail2.envs import make_env

    env = make_env("point_mass", seed=seed)
    env.append_transform(RewardSum(in_keys=["task_reward"], out_keys=["episode_reward"]))  # TorchRL's standard key
    return env


def test_torchrls_reward_sum_key_is_not_an_observation_in_modules_demos_or_the_trainer(demo_dir, tmp_path):
    from torchrl_mpail2.data import record_demos
    from torchrl_mpail2.data import observation_keys_of
    from torchrl_mpail2.experts import PointMassExpert
    from torchrl_mpail2.modules import make_mpail2_modules
    from torchrl_mpail2.trainers import MPAIL2Trainer

    env = _with_episode_reward()
    assert "episode_reward" in env.observation_spec.keys()
    assert observation_keys_of(env) == ["observation"]
    assert record_demos(env, PointMassExpert(), episodes=1, progress=False).observation_keys == ["observation"]
    assert make_mpail2_modules(env.observation_spec, env.action_spec).encoder.in_keys == ["observation"]
    trainer = MPAIL2Trainer(_cfg(demo_dir), env_fn=_with_episode_reward, run_dir=tmp_path / "run")
    assert trainer.agent.modules.encoder.in_keys == ["observation"]
    trainer.close()


def test_the_planner_checks_its_action_spec_at_construction():
    from torchrl.data import Bounded

    from torchrl_mpail2.planners.mppi import LatentMPPIPlanner

    from conftest import tiny_modules

    with pytest.raises(ValueError, match=r"bounded to \[-1, 1\].*low=\[-2.0, -2.0\]"):
        LatentMPPIPlanner(tiny_modules(), Bounded(-2, 2, (2,)), gamma=LossConfig.gamma)
    with pytest.raises(ValueError, match="the action spec has 3 dimensions .*the networks act in 2"):
        LatentMPPIPlanner(tiny_modules(), Bounded(-1, 1, (3,)), gamma=LossConfig.gamma)


# ---- kills at random moments ----------------------------------------------------------------------------
@pytest.mark.slow
def test_a_run_killed_at_random_moments_and_resumed_ends_like_an_uninterrupted_one(demo_dir, tmp_path):
    """SIGKILL three times (the first before the first evaluation), resume after each: the same counts as a
    run that was never interrupted, each episode logged once, and never more than last_every episodes lost."""
    import json
    import os
    import random
    import signal
    import subprocess
    import sys
    import time
    import warnings
    from pathlib import Path

    from torchrl_mpail2.trainers import MPAIL2Trainer
    from torchrl_mpail2.data.checkpoint import checkpoint_episodes, find_resumable
    from torchrl_mpail2.trainers.plots import read_jsonl

    settings = ["train.total_episodes=12", "train.eval_every=6", "train.eval_episodes=1", "train.last_every=2",
                "train.utd=0.05", "train.checkpoint_every=5"]
    reference = MPAIL2Trainer(_cfg(demo_dir, *settings), run_dir=tmp_path / "reference").train()

    run = tmp_path / "run"
    args = [sys.executable, "-m", "torchrl_mpail2.train", "--preset", "point_mass"]
    overrides = [*QUIET_RUN, f"train.demos={demo_dir}",
                 "train.warmup_episodes=1", "train.batch_size=8", "planner.num_candidates=32", "planner.num_elites=4",
                 *settings, f"train.run_dir={run}"]
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1]), "OMP_NUM_THREADS": "1"}
    rng, kills = random.Random(14), []

    def logged() -> int:  # complete records (a torn last line is not one)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return len(read_jsonl(run / "metrics.jsonl"))

    for kill in range(3):
        command = args + (overrides if kill == 0 else ["--resume", str(run)])
        proc = subprocess.Popen(command, cwd=tmp_path, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
        try:
            start, deadline = logged(), time.time() + 300
            while logged() < start + 1 and time.time() < deadline:  # wait for this process to make progress
                assert proc.poll() is None, proc.stderr.read()
                time.sleep(0.05)
            time.sleep(rng.uniform(0.0, 0.3 if kill == 0 else 2.0))
            before_eval = not (run / "eval.jsonl").exists()
            proc.send_signal(signal.SIGKILL)
            proc.wait(30)
        finally:
            if proc.poll() is None:
                proc.kill()
        if kill == 0:
            assert before_eval, "the first kill came after the first evaluation"
        lines = logged()
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            resumable = find_resumable(run / "checkpoints")
            restart = 0 if resumable is None else checkpoint_episodes(resumable)
        assert lines - restart <= 2, (kill, lines, restart)  # lost episodes: at most last_every
        kills.append((lines, restart))
    print("episodes logged at each kill, episode resumed from:", kills)
    assert kills[-1][1] > 0  # the later kills came after checkpoints: resuming restored one

    done = subprocess.run(args + ["--resume", str(run)], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    summary = json.loads((run / "summary.json").read_text())
    for counter in ("episodes", "env_steps", "updates"):
        assert summary[counter] == reference[counter], counter
    assert _episodes_logged(run) == list(range(1, 13))
    evaluations = [json.loads(line)["episode"] for line in (run / "eval.jsonl").read_text().splitlines()]
    assert evaluations == [6, 12]
