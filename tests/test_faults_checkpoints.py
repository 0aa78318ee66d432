"""Faults at the later doors (issue #47): checkpoints loaded outside ``--resume``, resume edge cases, a full disk,
stop signals and settings that would hang. Each is refused with a message naming its cause, or recovered from."""
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import QUIET_RUN, flip_a_byte
from conftest import short_run_cfg as _cfg
from conftest import train_short_run as _trained
from torchrl_mpail2.config import ConfigError
from torchrl_mpail2.data.checkpoint import CheckpointError
from torchrl_mpail2.trainers import apply_overrides, preset


@pytest.fixture(scope="module")
def trained_run(demo_dir, tmp_path_factory):
    """A finished two-episode point-mass run (do not modify: copy it with ``_copy``)."""
    return _trained(demo_dir, tmp_path_factory.mktemp("trained") / "run")


def _copy(run: Path, to: Path) -> Path:
    shutil.copytree(run, to, ignore=shutil.ignore_patterns(".lock"))
    return to


# ---- checkpoints loaded from other places than --resume -------------------------------------------------
def test_a_state_file_path_is_verified_against_its_folders_manifest(trained_run, tmp_path):
    from torchrl_mpail2.agents import LearnedRewardTransform

    run = _copy(trained_run, tmp_path / "run")
    state = run / "checkpoints" / "last" / "state.pt"
    flip_a_byte(state)
    with pytest.raises(CheckpointError, match=r"last/state.pt is corrupted: its sha256 does not match"):
        LearnedRewardTransform.from_checkpoint(state)


def test_from_checkpoint_with_an_env_of_other_specs_names_env_and_parameters(trained_run):
    import torch
    from torchrl.data import Unbounded
    from torchrl.envs import Transform, TransformedEnv

    from torchrl_mpail2.agents import MPAIL2Agent
    from torchrl_mpail2.envs import PointMassEnv

    class Widen(Transform):  # a point mass observed through 6 numbers instead of 4
        def _apply_transform(self, obs):
            return torch.cat([obs, obs[..., :2]], -1)

        def _reset(self, tensordict, tensordict_reset):
            return self._call(tensordict_reset)

        def transform_observation_spec(self, spec):
            spec["observation"] = Unbounded(shape=(6,), dtype=torch.float32)
            return spec

    wide = TransformedEnv(PointMassEnv(), Widen(in_keys=["observation"], out_keys=["observation"]))
    with pytest.raises(CheckpointError, match=r"(?s)written for train.env='point_mass'.*'observation': \(6,\).*"
                                              r"in the checkpoint, \(.*\) here"):
        MPAIL2Agent.from_checkpoint(trained_run / "checkpoints" / "last", wide)


def test_init_from_a_checkpoint_of_other_network_sizes_names_the_fields_and_leaves_no_folder(demo_dir, trained_run,
                                                                                            tmp_path):
    from torchrl_mpail2.train import main

    argv = ["--preset", "point_mass", *QUIET_RUN, f"train.demos={demo_dir}", "train.total_episodes=2",
            "train.warmup_episodes=1", "model.latent_dim=16", f"train.run_dir={tmp_path / 'new'}",
            "--init-from", str(trained_run / "checkpoints" / "last")]
    with pytest.raises(SystemExit) as exit_:
        main(argv)
    assert exit_.value.code == 1
    assert not (tmp_path / "new").exists()  # the retry is not refused as "already holds a run"
    from torchrl_mpail2.trainers import MPAIL2Trainer

    trainer = MPAIL2Trainer(_cfg(demo_dir, "model.latent_dim=16", "train.ablation=PM"), run_dir=tmp_path / "pm")
    with pytest.raises(CheckpointError, match=r"model.latent_dim: 32 in the checkpoint, 16 now"):
        trainer.init_from(trained_run / "checkpoints" / "last")
    assert not (tmp_path / "pm").exists()


def test_a_run_that_fails_before_its_first_episode_leaves_no_folder(demo_dir, tmp_path):
    from torchrl_mpail2.trainers import MPAIL2Trainer

    trainer = MPAIL2Trainer(_cfg(demo_dir), run_dir=tmp_path / "run")

    def broken_env():
        raise OSError("the simulator's display went away")

    trainer._collector = broken_env
    with pytest.raises(OSError, match="display went away"):
        trainer.train()
    assert not (tmp_path / "run").exists()  # a retry is not refused as "already holds a run"
    MPAIL2Trainer(_cfg(demo_dir), run_dir=tmp_path / "run").train()


def test_init_from_with_resume_is_refused(trained_run, tmp_path, capsys):
    from torchrl_mpail2.train import main

    with pytest.raises(SystemExit) as exit_:
        main(["--resume", str(trained_run), "--init-from", str(trained_run / "checkpoints" / "last")])
    assert exit_.value.code == 2
    assert "a resumed run keeps its own weights" in capsys.readouterr().err


# ---- resume edge cases ----------------------------------------------------------------------------------
def test_a_budget_below_the_episodes_done_says_so(demo_dir, tmp_path):
    from torchrl_mpail2.trainers import MPAIL2Trainer

    run = _trained(demo_dir, tmp_path / "run", "train.total_episodes=3")
    with pytest.raises(ConfigError, match=r"train.total_episodes=2: .* has already run 3 episodes"):
        MPAIL2Trainer.resume(run, ["train.total_episodes=2"])


def test_resuming_a_finished_run_changes_nothing(demo_dir, tmp_path):
    from torchrl_mpail2.trainers import MPAIL2Trainer

    run = _trained(demo_dir, tmp_path / "run", "train.eval_every=2", "train.eval_episodes=1")
    files = {p: p.read_bytes() for p in (run / "eval.jsonl", run / "metrics.jsonl", run / "summary.json")}
    with pytest.warns(RuntimeWarning, match=r"has already finished its 2 episodes.*train.total_episodes=N"):
        summary = MPAIL2Trainer.resume(run).train()
    assert summary["episodes"] == 2
    assert {p: p.read_bytes() for p in files} == files
    # a run that reached its budget but died before its summary: no second evaluation at the same episode
    (run / "summary.json").unlink()
    MPAIL2Trainer.resume(run).train()
    assert [json.loads(line)["episode"] for line in (run / "eval.jsonl").read_text().splitlines()] == [2]


def test_replaced_demonstrations_are_refused_on_resume_unless_allowed(demo_dir, trained_run, tmp_path):
    import torch

    from torchrl_mpail2.data import load_demos, save_demos
    from torchrl_mpail2.trainers import MPAIL2Trainer

    demos = load_demos(demo_dir)
    demos.observations["observation"] = demos.observations["observation"] + 0.01
    other = tmp_path / "other_demos"
    save_demos(demos, other)
    run = _copy(trained_run, tmp_path / "run")
    config = json.loads((run / "config.json").read_text())
    config["train"]["demos"] = str(other)  # the same path with other content, as far as the run can tell
    (run / "config.json").write_text(json.dumps(config))
    with pytest.raises(CheckpointError, match=r"trained on other demonstrations .*--allow-other-demos"):
        MPAIL2Trainer.resume(run)
    trainer = MPAIL2Trainer.resume(run, allow_other_demos=True)
    assert trainer.counters["episodes"] == 2
    trainer.close()
    assert torch.isfinite(demos.observations["observation"]).all()


def test_a_full_disk_during_a_checkpoint_names_the_folder_and_keeps_the_previous_one(trained_run, tmp_path,
                                                                                    monkeypatch):
    import errno

    import torch

    from torchrl_mpail2.data import checkpoint as ckpt

    run = _copy(trained_run, tmp_path / "run")
    last = run / "checkpoints" / "last"
    before = ckpt.read_checkpoint(last)["counters"]
    real_save = torch.save

    def save_until_full(obj, f, *args, **kwargs):
        Path(f).write_bytes(b"partial")
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(torch, "save", save_until_full)
    with pytest.raises(CheckpointError, match=r"cannot write checkpoint .*last: the disk is full .* MiB free.*"
                                              r"partial checkpoint was removed and the previous checkpoint is kept"):
        ckpt.write_checkpoint(last, {"counters": {"episodes": 9}})
    monkeypatch.setattr(torch, "save", real_save)
    assert not (run / "checkpoints" / ".last.tmp").exists()
    assert ckpt.read_checkpoint(last)["counters"] == before
    # torch.save's own report of a full disk
    monkeypatch.setattr(torch, "save", lambda *a, **k: (_ for _ in ()).throw(
        RuntimeError("[enforce fail at inline_container.cc:672] . unexpected pos 553280 vs 553232")))
    with pytest.raises(CheckpointError, match="the disk is full"):
        ckpt.write_checkpoint(last, {"counters": {"episodes": 9}})


# ---- settings that would hang -----------------------------------------------------------------------------
def test_more_envs_than_episodes_is_refused():
    with pytest.raises(ConfigError, match=r"num_envs=300 is more than total_episodes=3"):
        apply_overrides(preset("point_mass"), ["train.total_episodes=3", "train.num_envs=300"])


# ---- stop signals -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_a_stop_signal_ends_the_episode_and_saves_last(demo_dir, tmp_path, sig):
    from torchrl_mpail2.data.checkpoint import checkpoint_episodes
    from torchrl_mpail2.trainers.plots import read_jsonl

    run = tmp_path / "run"
    command = [sys.executable, "-m", "torchrl_mpail2.train", "--preset", "point_mass", *QUIET_RUN,
               f"train.demos={demo_dir}", "train.total_episodes=200", "train.warmup_episodes=1", "train.utd=0.02",
               "train.batch_size=8", "train.eval_every=0", "train.last_every=1000", "train.checkpoint_every=0",
               "planner.num_candidates=16", "planner.num_elites=4", f"train.run_dir={run}"]
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parents[1]), "OMP_NUM_THREADS": "1"}
    proc = subprocess.Popen(command, cwd=tmp_path, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True)
    try:
        deadline = time.time() + 120
        while not (run / "metrics.jsonl").exists() or len(read_jsonl(run / "metrics.jsonl")) < 2:
            assert proc.poll() is None and time.time() < deadline, proc.stderr.read()[-3000:] if proc.poll() else "slow"
            time.sleep(0.05)
        proc.send_signal(sig)
        _, err = proc.communicate(timeout=120)
    finally:
        if proc.poll() is None:
            proc.kill()
    assert proc.returncode == 0, err[-3000:]
    logged = len(read_jsonl(run / "metrics.jsonl"))
    assert 2 <= logged < 200
    assert checkpoint_episodes(run / "checkpoints" / "last") == logged  # nothing since the last save lost
    assert json.loads((run / "summary.json").read_text())["stopped_by"] == sig.name
    assert not (run / "eval.jsonl").exists()


def test_a_checkpoint_from_before_the_reward_scale_buffers_still_loads(trained_run):
    """The shape check around ``load_state_dict`` must leave the modules' own hooks to fill what older checkpoints
    lack (here the reward's running-scale buffers)."""
    from torchrl_mpail2.agents import MPAIL2Agent
    from torchrl_mpail2.agents.mpail2 import load_weights
    from torchrl_mpail2.data.checkpoint import read_checkpoint

    state = read_checkpoint(trained_run / "checkpoints" / "last")
    agent = MPAIL2Agent.from_checkpoint(trained_run / "checkpoints" / "last")
    older = {k: v for k, v in state["modules"].items() if not k.startswith("reward.module.reward_scale")
             and not k.startswith("reward.module.scale_")}
    assert len(older) < len(state["modules"])
    load_weights(agent.modules, older, "an older checkpoint")
    assert agent.modules.reward.module.reward_scale.item() == 1.0  # the hook's: the raw critic, as it ran
    agent.load_state_dict({**state, "modules": older}, with_optimizers=False)  # the agent's own path loads it too
