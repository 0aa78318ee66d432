"""Learning over several training seeds, scored on the fixed evaluation episodes.

    python -m benchmarks.learning.learning_seeds NAME --preset lift_state --seeds 0 1 --episodes 300 --budget-min 100 \\
        [section.field=value ...]
    python -m benchmarks.learning.learning_seeds NAME --summarize           # rewrite the results from the run folders
    python -m benchmarks.learning.run_status [NAME ...]                     # where each seed stands (running, resumable...)
    python -m benchmarks.learning.learning_seeds --compare NAME [NAME ...] --out docs/results/learning/compare.png
    python -m benchmarks.learning.learning_seeds NAME --merge SOURCE [SOURCE ...]  # one result from several results' seeds
    python -m benchmarks.learning.learning_seeds NAME --preset push_state train.env=robosuite/PushMirrored \\
        --init-from runs/learning/push_state/seed{seed}/checkpoints/last --transfer world-model   # transfer

Each seed trains in its own process (``--parallel`` at a time, one torch thread each) under
``runs/learning/NAME/seed<k>``. Re-running the same command is safe: a seed with a ``summary.json`` is done (unless a
stop signal ended it), one with a checkpoint resumes from it, one without starts afresh. Every evaluation plays the same episodes (env seeds
``train.eval_seed + i``, seeded planner noise), and a checkpoint is saved at each, so the maximum over the
evaluations is a Best (every checkpoint evaluated on the same episodes) and the final one the paper's Last. The
paper's Best picks among checkpoints saved every 10 episodes: ``--checkpoint-every 10`` saves them (16 MB each on
Lift), ``python -m benchmarks.learning.evaluate_checkpoints RUN --from-episode E --held-out 50`` scores them (and the
chosen one on 50 other episodes, since a maximum over many checkpoints is biased upwards), and the summary then reports
``best_all_checkpoints_success_any_step`` and ``best_checkpoint_held_out_success_any_step`` beside the evaluations'.

The headline of a configuration is its final checkpoint on episodes that chose nothing: as soon as a seed finishes,
its last and Best evaluated checkpoints play ``--held-out`` (default 50, the paper's trials) other episodes
(``evaluate_checkpoints.py --only-evaluated``, in the slot the seed's training frees), and the summary reports
``held_out_last`` and ``held_out_best``: the mean over seeds, its 95% bootstrap interval over seeds and episodes
and, from 3 seeds, the interquartile mean.

Writes ``docs/results/learning/NAME.json`` (``task``, ``obs``, ``config``, ``seeds``, ``eval_episodes``,
``curve`` with the mean and std over seeds, ``best_success_any_step``, ``last_success_any_step``,
``episodes_to_50`` / ``episodes_to_80``, ``episodes``, ``wall_time_s``, ``machine``, ``commit``, per-seed detail)
and ``NAME.png`` (mean and std bands over seeds). Beside the evaluation it reports ``training_curve``: the any-step
success of the training episodes themselves (sampled actions, as the authors' code measures success; warm-up
episodes of random actions left out) per window of :data:`TRAINING_WINDOW` episodes, mean over seeds, dotted in the
plot.
"""
from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import statistics
import subprocess
import sys
import time
from pathlib import Path

from benchmarks.records import ROOT, child_env, git_commit, start_logged
from torchrl_mpail2.trainers.intervals import bootstrap_ci, iqm

RESULTS = ROOT / "docs" / "results" / "learning"
THRESHOLDS = (0.5, 0.8)
#: Training episodes per point of ``training_curve``.
TRAINING_WINDOW = 25


def seed_dir(runs_root: Path, name: str, seed: int) -> Path:
    return runs_root / name / f"seed{seed}"


def _episodes_done(run_dir: Path) -> int:
    return len(_read_jsonl(run_dir / "metrics.jsonl"))


def read_summary(run_dir: Path) -> dict | None:
    """The seed's ``summary.json`` (the trainer writes it when a launch ends), None before that."""
    path = run_dir / "summary.json"
    if not path.exists():
        return None
    try:
        return json.loads(path.read_text())
    except json.JSONDecodeError as error:
        raise SystemExit(f"{path} is not valid JSON ({error}): move it aside to resume or summarise the seed")


def finished(summary: dict | None) -> bool:
    """A launch ended at its episodes or its wall-clock budget; one a stop signal ended (``stopped_by``) is
    interrupted, not finished."""
    return summary is not None and not summary.get("stopped_by")


def seed_command(run_dir: Path, seed: int, args, overrides: list[str]) -> list[str] | None:
    """The training command for one seed: None when it is done, a resume when it has a checkpoint.

    A seed that stopped at its wall-clock budget short of ``--episodes`` counts as done, unless ``--extend-min``
    asks for more time: then it resumes from its last checkpoint for that long. One a stop signal ended (its
    summary's ``stopped_by``) resumes as an interrupted one does. A resumed seed trains to ``--episodes``, so a
    finished run is extended by asking for more episodes with ``--extend-min``.
    """
    base = [sys.executable, "-m", "torchrl_mpail2.train"]
    resume = [*base, "--resume", str(run_dir), f"train.total_episodes={args.episodes}"]
    if getattr(args, "checkpoint_every", None):  # a resumed run may save its checkpoints at another spacing
        resume.append(f"train.checkpoint_every={args.checkpoint_every}")
    summary = read_summary(run_dir)
    if summary is not None:
        if (not finished(summary) or args.extend_min) and _episodes_done(run_dir) < args.episodes:
            # the earlier part's summary is kept so that the seed's wall time adds up over its parts
            (run_dir / "summary.json").rename(run_dir / f"summary.part{len(list(run_dir.glob('summary.part*.json')))}.json")
            return [*resume, f"train.max_wall_s={args.extend_min * 60}"] if args.extend_min else resume
        return None
    if (run_dir / "checkpoints" / "last").exists():
        return resume
    shutil.rmtree(run_dir, ignore_errors=True)  # nothing checkpointed yet: start afresh
    run_dir.parent.mkdir(parents=True, exist_ok=True)
    every = f"train.eval_every={args.eval_every}"
    start = []
    if getattr(args, "init_from", None):  # a transfer run: each seed starts from its own source seed's weights
        source = Path(args.init_from.format(seed=seed))
        if not source.exists():
            raise SystemExit(f"--init-from: seed {seed}'s source checkpoint {source} does not exist")
        start = ["--init-from", str(source), "--transfer", args.transfer]
    return [*base, "--preset", args.preset, *start, f"train.seed={seed}", f"train.run_dir={run_dir}", "train.threads=1",
            "train.progress=false", f"train.total_episodes={args.episodes}", f"train.max_wall_s={args.budget_min * 60}",
            every, f"train.checkpoint_every={getattr(args, 'checkpoint_every', None) or args.eval_every}",
            f"train.eval_episodes={args.eval_episodes}", *overrides]


def held_out_command(run_dir: Path, args) -> list[str] | None:
    """The command that scores a seed's Best and last evaluated checkpoints on ``--held-out`` episodes
    (``evaluate_checkpoints --only-evaluated``, one thread); None when none is asked for or the seed is not finished
    (a stop signal's seed included: half an hour a checkpoint on cameras, for a seed that is not done)."""
    if not getattr(args, "held_out", 0) or not (run_dir / "checkpoints").exists():
        return None
    if not finished(read_summary(run_dir)):
        return None
    return [sys.executable, "-m", "benchmarks.learning.evaluate_checkpoints", str(run_dir), "--only-evaluated",
            "--held-out", str(args.held_out), "--threads", "1"]


def score_held_out(args, seeds: list[tuple[int, Path]]) -> None:
    """Each finished seed's Best and last evaluated checkpoints scored on ``--held-out`` episodes that chose nothing
    (:func:`held_out_command`), ``--parallel`` seeds at a time; a score already in the run's
    ``checkpoint_evals.json`` is reused. :func:`run_seeds` does this itself for the seeds it trains."""
    running: list[tuple[int, Path, subprocess.Popen, object]] = []

    def wait_oldest() -> None:
        seed, run_dir, proc, log = running.pop(0)
        code = proc.wait()
        log.close()
        if code != 0:
            print(f"seed {seed}: held-out scoring exited with {code}\n{log_tail(run_dir.parent / f'seed{seed}.log')}")

    for seed, run_dir in seeds:
        if (cmd := held_out_command(run_dir, args)) is None:
            continue
        if len(running) >= max(1, getattr(args, "parallel", 1)):
            wait_oldest()
        running.append((seed, run_dir, *start_logged(cmd, run_dir.parent / f"seed{seed}.log", ROOT, child_env(threads=1))))
    while running:
        wait_oldest()


def log_tail(path: Path, lines: int = 15) -> str:
    """The last ``lines`` lines of a seed's log (what a failed seed printed last)."""
    if not path.exists():
        return f"(no log at {path})"
    return "\n".join(path.read_text(errors="replace").splitlines()[-lines:])


def run_seeds(args, overrides: list[str]) -> None:
    """Trains the seeds ``--parallel`` at a time and scores each on its held-out episodes as soon as its training
    ends, in the slot the training frees (before the next seed starts: a seed's headline need not wait for the
    others' training). A progress bar (on a terminal) counts the episodes of all seeds and shows each seed's latest
    evaluation; a seed that fails has its log's last lines printed."""
    from tqdm import tqdm

    seeds = [(s, seed_dir(args.runs_root, args.name, s)) for s in args.seeds]
    pending = [(seed, run_dir, "training") for seed, run_dir in seeds]
    running: list[tuple[int, Path, str, subprocess.Popen, object]] = []
    env = child_env(threads=1)
    bar = tqdm(total=len(seeds) * args.episodes, desc=args.name, unit="episode", disable=None)
    while pending or running:
        while pending and len(running) < args.parallel:
            seed, run_dir, job = pending.pop(0)
            cmd = seed_command(run_dir, seed, args, overrides) if job == "training" else held_out_command(run_dir, args)
            if cmd is None:
                if job == "training":
                    bar.write(f"seed {seed}: done already ({run_dir})")
                    pending.insert(0, (seed, run_dir, "held-out scoring"))  # its scores are reused if there
                continue
            bar.write(f"seed {seed}: {' '.join(cmd)}")
            running.append((seed, run_dir, job, *start_logged(cmd, run_dir.parent / f"seed{seed}.log", ROOT, env)))
        time.sleep(5)
        if not bar.disable:  # the run folders are read only for a bar someone sees
            bar.n = sum(min(_episodes_done(run_dir), args.episodes) for _, run_dir in seeds)
            latest = {seed: _read_jsonl(run_dir / "eval.jsonl")[-1:] for seed, run_dir in seeds}
            bar.set_postfix_str(" ".join(f"s{seed}:{e[0].get('success_rate_any_step', float('nan')):.2f}@{e[0].get('episode')}"
                                         for seed, e in latest.items() if e))
        for entry in list(running):
            seed, run_dir, job, proc, log = entry
            if proc.poll() is None:
                continue
            running.remove(entry)
            log.close()
            bar.write(f"seed {seed}: {job} exited with {proc.returncode}")
            if proc.returncode != 0:
                bar.write(log_tail(run_dir.parent / f"seed{seed}.log"))
            elif job == "training":
                pending.insert(0, (seed, run_dir, "held-out scoring"))
    bar.close()


def _read_jsonl(path: Path) -> list[dict]:
    if not path.exists():
        return []
    rows = []
    for line in path.read_text().splitlines():
        try:
            rows.append(json.loads(line))
        except json.JSONDecodeError:  # a torn last line of a killed run
            pass
    return rows


def _time_split(summaries: list[dict]) -> dict | None:
    """Seconds per stage (act, env, update, evaluate, checkpoint, log, total) summed over a seed's launches, with
    each stage's share of the total; None when no launch recorded its split."""
    splits = [s["time_split_s"] for s in summaries if s.get("time_split_s")]
    if not splits:
        return None
    seconds = {k: sum(s.get(k, 0.0) for s in splits) for k in dict.fromkeys(k for s in splits for k in s)}
    total = seconds.get("total") or sum(v for k, v in seconds.items() if k != "total")
    return {"seconds": seconds, "share": {k: v / total for k, v in seconds.items() if k != "total"} if total else {}}


def training_success(episodes: list[dict], window: int = TRAINING_WINDOW) -> list[dict]:
    """Any-step success of a seed's training episodes (``metrics.jsonl`` rows) per ``window`` episodes, from the
    first episode after the random-action warm-up: ``[{episode, success_any_step, episodes}]``, ``episode`` the
    window's last; a last window shorter than ``window`` is left out."""
    acted = [e for e in episodes if "success_any_step" in e and not e.get("random_actions", False)]
    return [{"episode": chunk[-1]["episode"], "episodes": window,
             "success_any_step": statistics.fmean(float(e["success_any_step"]) for e in chunk)}
            for chunk in (acted[i:i + window] for i in range(0, len(acted) - window + 1, window))]


def _mean_training_curve(per_seed_curves: list[list[dict]]) -> list[dict]:
    """Windows every seed completed, by position (the seeds' warm-ups are equally long): mean and std over seeds."""
    points = min((len(c) for c in per_seed_curves), default=0)
    return [{"episode": max(c[i]["episode"] for c in per_seed_curves),
             "success_any_step_mean": statistics.fmean(c[i]["success_any_step"] for c in per_seed_curves),
             "success_any_step_std": statistics.pstdev([c[i]["success_any_step"] for c in per_seed_curves])}
            for i in range(points)]


def summarize(name: str, runs_root: Path, only: list[int] | None = None) -> dict:
    """Aggregates the seeds' evaluations (every seed folder under ``runs_root/name``, or the seeds ``only``) into the
    results JSON and the curves PNG."""
    seeds = {}
    for run_dir in sorted((runs_root / name).glob("seed*")):
        if not run_dir.is_dir() or not (run_dir / "config.json").exists():
            continue
        if only is not None and int(run_dir.name.removeprefix("seed")) not in only:
            continue
        evals = [e for e in _read_jsonl(run_dir / "eval.jsonl") if "success_rate_any_step" in e]
        episodes = _read_jsonl(run_dir / "metrics.jsonl")
        summary = read_summary(run_dir) or {}
        parts = [json.loads(f.read_text()) for f in run_dir.glob("summary.part*.json")]
        # the trainer counts the run's launches itself (``run_wall_time_s``, carried in its checkpoints); older
        # summaries counted one launch, so their parts are added up (launches cut by a crash are then missing)
        wall = (summary.get("run_wall_time_s") or sum(p["wall_time_s"] for p in parts) + summary.get("wall_time_s", 0.0)
                if summary else None)
        config = json.loads((run_dir / "config.json").read_text())
        seeds[int(run_dir.name.removeprefix("seed"))] = {
            "config": config, "evals": evals, "episodes": episodes,
            "finished": finished(summary or None), "wall_time_s": wall, "parts": len(parts) + bool(summary),
            "time_split_s": _time_split(parts + [summary]),
            "all_checkpoints": all_checkpoints(run_dir, config["train"])}
    if not seeds:
        raise SystemExit(f"no runs under {runs_root / name}")
    missing = sorted(set(only or ()) - set(seeds))
    if missing:
        raise SystemExit(f"no run of seed(s) {missing} under {runs_root / name}")
    per_seed = {s: {"episodes": len(d["episodes"]), "finished": d["finished"], "wall_time_s": d["wall_time_s"],
                    "evaluations": [{k: e[k] for k in ("episode", "success_rate_any_step", "success_rate", "return")}
                                    for e in d["evals"]],
                    "training_success": training_success(d["episodes"]),
                    "mean_update_ms": statistics.fmean([e["update_ms"] for e in d["episodes"] if "update_ms" in e] or [0]),
                    "time_split": d["time_split_s"], "all_checkpoints": d["all_checkpoints"]}
                for s, d in seeds.items()}
    config = portable_config(next(iter(seeds.values()))["config"], runs_root)
    return _write_result(name, config, per_seed, git_commit(runs_root, short=False))


def portable_config(config: dict, runs_root: Path) -> dict:
    """``config`` with the paths a run saves resolved (``train.run_dir``, ``train.demos``) made relative to the
    worktree holding ``runs_root`` (its parent's parent: ``<worktree>/runs/learning``), or to ``<elsewhere>/NAME``:
    results pages must not carry one machine's folders."""
    root = Path(runs_root).resolve().parent.parent
    train = dict(config["train"])
    for key in ("run_dir", "demos"):
        value = train.get(key)
        if isinstance(value, str) and Path(value).is_absolute():
            path = Path(value)
            train[key] = str(path.relative_to(root)) if path.is_relative_to(root) else f"<elsewhere>/{path.name}"
    return {**config, "train": train}


def all_checkpoints(run_dir: Path, train: dict) -> dict | None:
    """A seed's ``checkpoint_evals.json`` (``benchmarks/learning/evaluate_checkpoints.py``) in brief, when it played the
    run's own evaluation episodes deterministically: how many checkpoints from which episode, the Best among them
    and its held-out score; None without one (or for another set of episodes)."""
    from torchrl_mpail2.trainers.evaluation import run_eval_seed

    path = run_dir / "checkpoint_evals.json"
    if not path.exists():
        return None
    evals = json.loads(path.read_text())
    if (evals.get("acting") != "deterministic" or evals.get("episodes_per_checkpoint") != train["eval_episodes"]
            or evals.get("first_eval_seed") != run_eval_seed(train)):
        return None
    rows = evals["checkpoints"]

    def brief(held):
        return None if held is None else {k: held.get(k) for k in ("checkpoint", "first_seed", "episodes",
                                                                  "success_rate_any_step", "success_rate",
                                                                  "success_any_step_per_episode")}

    return {"checkpoints": len(rows), "from_episode": evals.get("from_episode"), "episodes": [r["episode"] for r in rows],
            "only_evaluated": bool(evals.get("only_evaluated")),
            "best_success_any_step": evals["best_success_rate_any_step"], "best_episode": evals.get("best_episode"),
            "held_out": brief(evals.get("held_out")), "held_out_last": brief(evals.get("held_out_last"))}


def _mean_over_seeds(per_seed: dict[int, dict], pick) -> float | None:
    """The mean of ``pick(seed's all_checkpoints)`` when every seed has one, else None."""
    values = [pick(p["all_checkpoints"]) if p.get("all_checkpoints") else None for p in per_seed.values()]
    return None if any(v is None for v in values) else statistics.fmean(values)


def held_out_headline(per_seed: dict[int, dict], which: str) -> dict | None:
    """The mean over seeds of ``which`` (``held_out_last``: the final checkpoint, ``held_out``: the Best) on the
    held-out episodes, its 95% bootstrap interval over seeds and episodes, and the interquartile mean over seeds
    (3 or more); None unless every seed has the score with its per-episode outcomes."""
    scores = [(p.get("all_checkpoints") or {}).get(which) for p in per_seed.values()]
    if not scores or any(s is None or not s.get("success_any_step_per_episode") for s in scores):
        return None
    outcomes = [s["success_any_step_per_episode"] for s in scores]
    per_seed_mean = [statistics.fmean(o) for o in outcomes]
    return {"mean": statistics.fmean(per_seed_mean), "ci95": bootstrap_ci(outcomes), "iqm": iqm(per_seed_mean),
            "per_seed": per_seed_mean, "episodes": [len(o) for o in outcomes], "checkpoints": [s["checkpoint"] for s in scores]}


def _write_result(name: str, config: dict, per_seed: dict[int, dict], commit, extra: dict | None = None) -> dict:
    """The results JSON and curves PNG of ``per_seed`` (each seed's ``evaluations``, ``training_success``,
    ``episodes``, ``finished`` and ``wall_time_s``): means and std over the seeds at the episodes every seed was
    evaluated at, each seed's Best and Last; ``extra`` adds fields."""
    for p in per_seed.values():
        ev = p["evaluations"]
        p.update({"best_success_any_step": max((e["success_rate_any_step"] for e in ev), default=None),
                  "last_success_any_step": ev[-1]["success_rate_any_step"] if ev else None,
                  "last_success_last_step": ev[-1]["success_rate"] if ev else None,
                  "last_eval_episode": ev[-1]["episode"] if ev else None})
    common = sorted(set.intersection(*[{e["episode"] for e in p["evaluations"]} for p in per_seed.values()]))
    curve = []
    for episode in common:
        rows = [next(e for e in p["evaluations"] if e["episode"] == episode) for p in per_seed.values()]
        anys = [r["success_rate_any_step"] for r in rows]
        curve.append({"episode": episode, "success_any_step_mean": statistics.fmean(anys),
                      "success_any_step_std": statistics.pstdev(anys),
                      "success_last_step_mean": statistics.fmean(r["success_rate"] for r in rows),
                      "seeds": len(rows)})

    def first_reaching(level: float):
        return next((c["episode"] for c in curve if c["success_any_step_mean"] >= level), None)

    usable = [p for p in per_seed.values() if p["best_success_any_step"] is not None]
    t = config["train"]
    result = {
        "name": name, "task": t["env"], "obs": t["obs"], "config": config, "seeds": sorted(per_seed),
        "eval_episodes": t["eval_episodes"], "eval_seeds": f"{t['eval_seed']} .. {t['eval_seed'] + t['eval_episodes'] - 1}",
        "curve": curve,
        "training_curve": _mean_training_curve([p.get("training_success", []) for p in per_seed.values()]),
        "best_success_any_step": statistics.fmean(p["best_success_any_step"] for p in usable) if usable else None,
        "last_success_any_step": statistics.fmean(p["last_success_any_step"] for p in usable) if usable else None,
        "last_success_last_step": statistics.fmean(p["last_success_last_step"] for p in usable) if usable else None,
        "best_all_checkpoints_success_any_step": _mean_over_seeds(per_seed, lambda a: a["best_success_any_step"]),
        "best_checkpoint_held_out_success_any_step": _mean_over_seeds(
            per_seed, lambda a: a["held_out"]["success_rate_any_step"] if a["held_out"] else None),
        "held_out_last": held_out_headline(per_seed, "held_out_last"),
        "held_out_best": held_out_headline(per_seed, "held_out"),
        "episodes_to_50": first_reaching(0.5), "episodes_to_80": first_reaching(0.8),
        "episodes": [per_seed[s]["episodes"] for s in sorted(per_seed)],
        "wall_time_s": [per_seed[s]["wall_time_s"] for s in sorted(per_seed)],
        "all_finished": all(p["finished"] for p in per_seed.values()),
        "machine": {"platform": platform.platform(), "cores": os.cpu_count(), "torch_threads_per_seed": t["threads"]},
        "commit": commit, "per_seed": per_seed, **(extra or {}),
    }
    RESULTS.mkdir(parents=True, exist_ok=True)
    (RESULTS / f"{name}.json").write_text(json.dumps(result, indent=2))
    plot_curves({name: result}, RESULTS / f"{name}.png", per_seed_lines=True)
    return result


#: Training settings that may differ between the results :func:`merge` combines (they do not change what is learnt).
MERGE_FREE_FIELDS = ("seed", "run_dir", "max_wall_s", "total_episodes", "threads", "progress", "checkpoint_every")


def _config_differences(a: dict, b: dict, prefix: str = "") -> list[str]:
    """Dotted names of the fields where two resolved configurations differ (``train.seed`` and the others of
    :data:`MERGE_FREE_FIELDS` excepted)."""
    out = []
    for key in sorted(set(a) | set(b)):
        dotted = f"{prefix}{key}"
        if prefix == "train." and key in MERGE_FREE_FIELDS:
            continue
        if isinstance(a.get(key), dict) and isinstance(b.get(key), dict) and not prefix:
            out += _config_differences(a[key], b[key], f"{key}.")
        elif a.get(key, "<absent>") != b.get(key, "<absent>"):
            out.append(dotted)
    return out


def _as_read_today(config: dict) -> dict:
    """A saved configuration as this code resumes it: fields added since it was saved take their defaults (which keep
    the earlier behaviour), renamed ones their new names."""
    from torchrl_mpail2.config import ExperimentConfig

    return json.loads(json.dumps(ExperimentConfig.from_dict(config).to_dict()))


def merge(name: str, sources: list[str]) -> dict:
    """One result from the seeds of several results of the same configuration (e.g. seeds 2 and 3 run later, after
    the first seeds' run folders were gone): refuses configurations that differ beyond
    :data:`MERGE_FREE_FIELDS` and seeds that appear twice, naming them. ``commit`` becomes ``{seed: commit}`` when
    the sources ran at different commits; a source may itself be a merged result."""
    loaded = {}
    for source in sources:
        path = RESULTS / f"{source}.json"
        if not path.exists():
            raise SystemExit(f"--merge: no results file {path}")
        loaded[source] = json.loads(path.read_text())
    first_name, first = next(iter(loaded.items()))
    per_seed, commits = {}, {}
    for source, r in loaded.items():
        differ = _config_differences(_as_read_today(first["config"]), _as_read_today(r["config"]))
        if differ:
            raise SystemExit(f"--merge: {source} and {first_name} differ in {', '.join(differ)}")
        for seed, p in r["per_seed"].items():
            if int(seed) in per_seed:
                raise SystemExit(f"--merge: seed {seed} is in {source} and in an earlier source")
            per_seed[int(seed)] = p
            commit = r["commit"]  # a merged source holds {seed: commit}
            commits[int(seed)] = commit[str(seed)] if isinstance(commit, dict) else commit
    commit = next(iter(commits.values())) if len(set(commits.values())) == 1 else dict(sorted(commits.items()))
    return _write_result(name, first["config"], dict(sorted(per_seed.items())), commit, {"merged_from": list(loaded)})


def plot_curves(results: dict[str, dict], out: Path, per_seed_lines: bool = False) -> Path:
    """Any-step evaluation success (mean and std band over seeds) against training episodes, one line per name."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(7, 4.2))
    for i, (name, r) in enumerate(results.items()):
        color = f"C{i}"
        x = [c["episode"] for c in r["curve"]]
        mean = [c["success_any_step_mean"] for c in r["curve"]]
        std = [c["success_any_step_std"] for c in r["curve"]]
        ax.plot(x, mean, marker="o", color=color, label=f"{name} (any step, {len(r['seeds'])} seeds)")
        ax.fill_between(x, [m - s for m, s in zip(mean, std)], [m + s for m, s in zip(mean, std)], color=color, alpha=0.2)
        ax.plot(x, [c["success_last_step_mean"] for c in r["curve"]], ls="--", color=color, alpha=0.8,
                label=f"{name} (last step)")
        training = r.get("training_curve") or []
        if training:
            ax.plot([c["episode"] for c in training], [c["success_any_step_mean"] for c in training], ls=":",
                    color=color, alpha=0.9, label=f"{name} (training episodes, sampled actions)")
        if per_seed_lines:
            for seed, p in r["per_seed"].items():
                ev = p["evaluations"]
                ax.plot([e["episode"] for e in ev], [e["success_rate_any_step"] for e in ev], color=color, lw=0.7,
                        alpha=0.4)
    ax.set_xlabel("training episode")
    ax.set_ylabel(f"success (evaluation: {next(iter(results.values()))['eval_episodes']} fixed episodes;\n"
                  f"dotted: training episodes per {TRAINING_WINDOW})", fontsize=8)
    ax.set_ylim(-0.02, 1.02)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left")
    ax.set_title(f"{next(iter(results.values()))['task']}: mean and std over seeds", fontsize=9)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=120)
    plt.close(fig)
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("name", nargs="?")
    p.add_argument("--preset", default="lift_state")
    p.add_argument("--seeds", type=int, nargs="+",
                   help="seeds to train (default 0 1; the summary then covers every seed folder of NAME); with "
                        "--summarize, the seeds to summarise (default: every seed folder)")
    p.add_argument("--episodes", type=int, default=300)
    p.add_argument("--budget-min", type=float, default=100.0, help="wall-clock budget of each seed (per launch)")
    p.add_argument("--extend-min", type=float, default=0.0,
                   help="resume seeds that stopped at their budget short of --episodes for this many more minutes")
    p.add_argument("--eval-every", type=int, default=50)
    p.add_argument("--eval-episodes", type=int, default=20)
    p.add_argument("--checkpoint-every", type=int, default=None,
                   help="save a checkpoint every this many episodes (default: at each evaluation); the paper's Best "
                        "picks among checkpoints every 10 (benchmarks/learning/evaluate_checkpoints.py scores them)")
    p.add_argument("--init-from", metavar="CKPT", help="transfer: start each seed from this checkpoint folder, where "
                   "{seed} stands for the seed (e.g. runs/learning/push_state/seed{seed}/checkpoints/last)")
    p.add_argument("--transfer", choices=("all", "world-model"), default="all",
                   help="what --init-from carries over (python -m torchrl_mpail2.train --transfer)")
    p.add_argument("--parallel", type=int, default=2)
    p.add_argument("--held-out", type=int, default=50, metavar="N",
                   help="score each finished seed's Best and last evaluated checkpoints on N held-out episodes (the "
                        "paper's 50 trials; 0: skip); with --summarize, score seeds that lack it first")
    p.add_argument("--runs-root", type=Path, default=ROOT / "runs" / "learning")
    p.add_argument("--summarize", action="store_true", help="only rewrite the results from the run folders")
    p.add_argument("--compare", nargs="+", metavar="NAME", help="plot the curves of these results together")
    p.add_argument("--out", type=Path, help="output PNG of --compare")
    p.add_argument("--merge", nargs="+", metavar="SOURCE",
                   help="write NAME from the seeds of these results (same configuration, different seeds)")
    args, overrides = p.parse_known_args()
    if args.compare:
        results = {n: json.loads((RESULTS / f"{n}.json").read_text()) for n in args.compare}
        print(plot_curves(results, args.out or RESULTS / "compare.png"))
        return
    if not args.name:
        p.error("NAME is required")
    if args.merge:
        result = merge(args.name, args.merge)
        print(json.dumps({k: v for k, v in result.items() if k not in ("config", "per_seed")}, indent=2))
        return
    if args.summarize:  # only the seeds asked for, if any
        done = sorted((args.runs_root / args.name).glob("seed*/summary.json"))
        score_held_out(args, [(int(p.parent.name.removeprefix("seed")), p.parent) for p in done
                              if args.seeds is None or int(p.parent.name.removeprefix("seed")) in args.seeds])
        result = summarize(args.name, args.runs_root, args.seeds)
    else:  # every seed of the name, those trained now and any trained before
        args.seeds = args.seeds or [0, 1]
        run_seeds(args, overrides)  # each seed scored on its held-out episodes as its training ends
        result = summarize(args.name, args.runs_root)
    print(json.dumps({k: v for k, v in result.items() if k not in ("config", "per_seed")}, indent=2))


if __name__ == "__main__":
    main()
