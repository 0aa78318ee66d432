"""``python -m torchrl_mpail2.evaluate``: an exported agent plays exactly as its training checkpoint, held-out
episodes differ from the fixed ones, and bad checkpoints are refused by name."""
import json

import pytest
import torch

from conftest import flip_a_byte, train_short_run
from torchrl_mpail2.agents import MPAIL2Agent
from torchrl_mpail2.data.checkpoint import MANIFEST_FILE, STATE_FILE, CheckpointError
from torchrl_mpail2.evaluate import AGENT_KEYS, LOCAL_PATHS, evaluate_checkpoint, export_agent, main
from torchrl_mpail2.trainers.evaluation import HELD_OUT_SEED_OFFSET


@pytest.fixture(scope="module")
def run(demo_dir, tmp_path_factory):
    return train_short_run(demo_dir, tmp_path_factory.mktemp("evaluate") / "run")


def test_an_exported_agent_is_smaller_and_plays_as_its_checkpoint(run, tmp_path):
    source = run / "checkpoints" / "last"
    out = export_agent(source, tmp_path / "agent")
    state = torch.load(out / STATE_FILE, weights_only=False)
    assert set(state) <= set(AGENT_KEYS) and "updater" not in state and "rng" not in state
    assert all(state["config"]["train"][key] is None for key in LOCAL_PATHS)  # no folders of this machine
    assert (out / STATE_FILE).stat().st_size < (source / STATE_FILE).stat().st_size
    assert json.loads((out / MANIFEST_FILE).read_text())["episodes"] == 2
    shipped, trained = (evaluate_checkpoint(path, episodes=3) for path in (out, source))
    assert shipped["success_any_step_per_episode"] == trained["success_any_step_per_episode"]
    assert shipped["return"] == pytest.approx(trained["return"])
    low, high = shipped["success_any_step_ci"]
    assert low <= shipped["success_rate_any_step"] <= high
    assert shipped["trained_episodes"] == 2 and shipped["episodes"] == 3
    weights = MPAIL2Agent.from_checkpoint(out).modules.state_dict()
    for name, value in MPAIL2Agent.from_checkpoint(source).modules.state_dict().items():
        assert torch.equal(weights[name], value), name


def test_held_out_and_fixed_episodes_start_from_their_own_seeds(run):
    held_out = evaluate_checkpoint(run / "checkpoints" / "last", episodes=2)
    fixed = evaluate_checkpoint(run / "checkpoints" / "last", episodes=2, held_out=False)
    assert held_out["first_seed"] == fixed["first_seed"] + HELD_OUT_SEED_OFFSET
    assert (held_out["episodes_set"], fixed["episodes_set"]) == ("held_out", "fixed")


def test_the_cli_prints_the_score_and_writes_json(run, tmp_path, capsys):
    main([str(run / "checkpoints" / "last"), "--episodes", "2", "--out", str(tmp_path / "score.json")])
    assert "any-step success" in capsys.readouterr().out
    assert json.loads((tmp_path / "score.json").read_text())["episodes"] == 2


def test_a_damaged_checkpoint_or_a_used_folder_is_refused_by_name(run, tmp_path, capsys):
    out = export_agent(run / "checkpoints" / "last", tmp_path / "agent")
    with pytest.raises(FileExistsError, match="already holds files"):
        export_agent(run / "checkpoints" / "last", out)
    flip_a_byte(out / STATE_FILE)
    with pytest.raises(CheckpointError, match=STATE_FILE):
        evaluate_checkpoint(out, episodes=1)
    with pytest.raises(SystemExit) as stop:
        main([str(out), "--episodes", "1"])
    assert stop.value.code == 2 and STATE_FILE in capsys.readouterr().err
    with pytest.raises(SystemExit):
        main([str(out), "--episodes", "0"])


@pytest.mark.parametrize("name", ["point_mass", "point_mass_pixels", "push_state"])
def test_each_shipped_agent_loads_verified_and_reaches_the_goal(name):
    from pathlib import Path

    folder = Path(__file__).resolve().parents[1] / "shipped" / name
    assert sorted(p.name for p in folder.iterdir()) == sorted([MANIFEST_FILE, STATE_FILE])
    score = evaluate_checkpoint(folder, episodes=2)  # loading checks the manifest's digests
    assert score["success_rate_any_step"] == 1.0, score
