"""The campaign queue keeps its cores busy in the queue's order and refuses a bad queue by job and field."""
import json
import subprocess
import sys
from pathlib import Path

import pytest

from benchmarks.learning import campaign

ROOT = Path(__file__).resolve().parents[1]


def _queue(tmp_path, jobs) -> Path:
    path = tmp_path / "queue.json"
    path.write_text(json.dumps({"jobs": jobs}))
    return path


def test_jobs_start_as_cores_free_and_a_later_job_that_fits_goes_first(tmp_path, monkeypatch):
    """Two cores: a and b start; c needs both and waits; when a ends, d (one core) takes the free core before c;
    c starts once d and b have ended. Each fake process ends after a number of polls."""
    lasts = {"a": 1, "b": 3, "c": 1, "d": 1}
    events = []

    class FakeProcess:
        def __init__(self, cmd, cwd, env, **kwargs):
            self.name, self.polls, self.returncode = cmd[3], 0, None
            assert env["OMP_NUM_THREADS"] == "1" and env["PYTHONPATH"].split(":")[0] == str(cwd)
            assert env["PYTHONPATH"].split(":").count(str(cwd)) == 1
            events.append(f"start {self.name}")

        def poll(self):
            self.polls += 1
            if self.polls >= lasts[self.name]:
                self.returncode = 3 if self.name == "b" else 0
                events.append(f"end {self.name}")
            return self.returncode

    monkeypatch.setattr(subprocess, "Popen", FakeProcess)
    monkeypatch.setattr(campaign.time, "sleep", lambda s: None)
    jobs = campaign.read_queue(_queue(tmp_path, [
        {"args": "a --seeds 0", "checkout": str(ROOT)}, {"args": ["b", "--seeds", "1"]},
        {"args": "c --seeds 0 1 --parallel 2", "slots": 2}, {"args": "d"}]), slots=2)
    for job in jobs:
        monkeypatch.setattr(type(job), "log", property(lambda j: tmp_path / f"{j.name}.log"))
    codes = campaign.run_campaign(jobs, slots=2)
    assert events == ["start a", "start b", "end a", "start d", "end d", "end b", "start c", "end c"]
    assert codes == {"a": 0, "b": 3, "c": 0, "d": 0}
    assert jobs[0].command()[1:4] == ["-m", "benchmarks.learning.learning_seeds", "a"]


@pytest.mark.parametrize("jobs, message", [
    ([], "at least one job"),
    ([{"args": "x", "cores": 2}], r"jobs\[0\] has unknown field\(s\) \['cores'\]"),
    ([{"args": "x"}, {"args": "--preset lift_state"}], r"jobs\[1\].args must begin with the run's NAME"),
    ([{"args": "x", "slots": 3}], r"jobs\[0\].slots=3: expected an integer from 1 to --slots \(2\)"),
    ([{"args": "x", "checkout": "nowhere"}], r"jobs\[0\].checkout .*nowhere holds no benchmarks"),
    ([{"args": "x --seeds 0"}, {"args": "x --seeds 1"}], r"names \['x'\] twice"),
    ([{"args": "x", "checkout": 3}], r"jobs\[0\].checkout must be a folder's path, not 3"),
])
def test_a_bad_queue_is_refused_naming_the_job_and_field(tmp_path, jobs, message):
    with pytest.raises(SystemExit, match=message):
        campaign.read_queue(_queue(tmp_path, jobs), slots=2)


def test_an_unreadable_queue_is_refused_by_its_path(tmp_path):
    (tmp_path / "torn.json").write_text('{"jobs": [')
    with pytest.raises(SystemExit, match="torn.json is not valid JSON"):
        campaign.read_queue(tmp_path / "torn.json", slots=2)
    with pytest.raises(SystemExit, match="cannot read the queue"):
        campaign.read_queue(tmp_path / "missing.json", slots=2)


def test_dry_run_prints_each_command_in_its_checkout(tmp_path, capsys):
    campaign.main([str(_queue(tmp_path, [{"args": "x --seeds 0", "checkout": str(ROOT)}])), "--dry-run"])
    out = capsys.readouterr().out
    command = f"{sys.executable} -m benchmarks.learning.learning_seeds x --seeds 0"
    assert out.startswith(f"[1 core(s)] cd {ROOT} && {command}")
