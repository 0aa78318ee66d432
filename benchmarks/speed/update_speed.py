"""Milliseconds per MPAIL2 learner update (dynamics -> reward -> value -> policy), with a per-loss breakdown.

Each (configuration, variant) runs in its own fresh process, the variants interleaved round after round,
because the malloc setting of :func:`~torchrl_mpail2.agents.update.retain_freed_memory` is process-wide.
Variants: ``initial`` (the code before the speed work, see ``_reference.py``), ``optimised`` (the package
as it is), ``optimised_default_malloc`` (the package with ``retain_memory=False``), ``one_transition_per_window``
(``LossConfig(transitions_per_window=1)``: the reward, value and actor stages on one random transition of each
window, i.e. B transitions rather than B x T; the dynamics stage unchanged), ``optimised_mixed_bf16`` and
``one_transition_per_window_mixed_bf16`` (``MPAIL2Updater(bf16=True)``: every stage's forward pass under bf16
autocast, float32 weights, gradients and optimisers). Any variant may end in ``_compiled``: the dynamics, policy and
Q-ensemble networks compiled with ``torch.compile`` (forward and backward; the reward network stays eager, since its
gradient penalty needs a double backward, which compiled graphs do not support); its first update, which compiles,
is timed apart (``first_update_ms``). Any variant may also end in ``_sync_free`` (before ``_compiled`` where both):
``MPAIL2Updater(sync_free_skips=True)``, i.e. fused Adam (one kernel per parameter group rather than torch's
multi-tensor loop) handed each stage's not-finite flag instead of a host check per stage; variants without it keep
the updater's default (host checks on CPU, sync-free on CUDA).

    python -m benchmarks.speed.update_speed                       # all configurations, JSON + Markdown in docs/results/speed
    python -m benchmarks.speed.update_speed --settings state --rounds 1 --updates 2
"""
from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time
from pathlib import Path

import torch

from benchmarks.records import ROOT, child_env, git_commit
from benchmarks.speed.common import SETTINGS, machine, median_ms, replay_batch

COMPILED = "_compiled"
SYNC_FREE = "_sync_free"
VARIANTS = ("initial", "optimised", "optimised_default_malloc", "one_transition_per_window", "optimised_mixed_bf16",
            "one_transition_per_window_mixed_bf16")
#: (label, callable path) timed inside one update, in the order the update runs them.
STAGE_CALLS = (("dynamics loss", "loss.dynamics_loss.forward"), ("latents (replay + expert)", "loss.replay_latents"),
               ("latents (replay + expert)", "loss.expert_latents"), ("reward loss", "loss.reward_loss.forward"),
               ("value loss", "loss.value_loss.forward"), ("value Polyak", "updater.target_updater.step"),
               ("actor loss", "loss.actor_loss.forward"))


def _instrument(updater, record: dict) -> None:
    """Wraps the stage calls and ``_step`` (backward + clip + Adam) so each records its wall time."""
    loss = updater.loss
    scope = {"loss": loss, "updater": updater}

    def timed(label, fn):
        def wrapper(*args, **kwargs):
            t = time.perf_counter()
            out = fn(*args, **kwargs)
            record[label] = record.get(label, 0.0) + time.perf_counter() - t
            return out
        return wrapper

    for label, path in STAGE_CALLS:
        owner_path, attr = path.rsplit(".", 1)
        owner = eval(owner_path, {}, scope)  # noqa: S307 - fixed strings above
        setattr(owner, attr, timed(f"{label}: forward" if "loss" in label else label, getattr(owner, attr)))
    step = updater._step
    updater._step = lambda stage, value: timed(f"{stage} backward + step", step)(stage, value)


def split_variant(variant: str) -> tuple[str, bool, bool]:
    """``NAME[_sync_free][_compiled]`` -> ``(NAME, sync_free, compiled)``."""
    compiled = variant.endswith(COMPILED)
    variant = variant.removesuffix(COMPILED)
    sync_free = variant.endswith(SYNC_FREE)
    return variant.removesuffix(SYNC_FREE), sync_free, compiled


def worker(setting_name: str, variant: str, batch: int, steps: int, updates: int, profile: bool) -> dict:
    from torchrl_mpail2 import LossConfig, MPAIL2Loss, MPAIL2Updater

    setting = SETTINGS[setting_name]
    modules = setting.modules()
    variant, sync_free, compiled = split_variant(variant)
    if compiled:
        import torch._dynamo
        torch._dynamo.config.cache_size_limit = 64  # several call shapes per network (windows, rollouts)
        for net in (modules.dynamics.module.net, modules.policy.net.net, modules.value.net):
            net.compile(dynamic=False)
    # one_transition_per_window*: reward, value and actor on one random transition of each window (B of them)
    loss = MPAIL2Loss(modules, LossConfig(transitions_per_window=1 if variant.startswith("one_transition") else None))
    td = replay_batch(setting, batch, steps)
    if variant == "initial":
        from benchmarks.speed.reference import initial_behaviour
        context = initial_behaviour()
    else:
        import contextlib
        context = contextlib.nullcontext()
    with context:
        updater = MPAIL2Updater(loss, retain_memory=variant != "initial" and variant != "optimised_default_malloc",
                                bf16=variant.endswith("mixed_bf16"), sync_free_skips=True if sync_free else None)
        t = time.perf_counter()
        updater.update(td)  # warm-up: optimiser state, allocator (and compilation)
        compile_s = time.perf_counter() - t
        totals, stages = [], []
        record: dict = {}
        _instrument(updater, record)
        for _ in range(updates):
            record.clear()
            t = time.perf_counter()
            updater.update(td)
            totals.append(time.perf_counter() - t)
            stages.append(dict(record))
        peak_rss_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024  # Linux: KiB
        out = {"update_s": totals, "stages_s": stages, "peak_rss_mb": peak_rss_mb, "machine": machine(),
               "first_update_s": compile_s}
        if profile:
            from torch.profiler import ProfilerActivity, profile as torch_profile
            with torch_profile(activities=[ProfilerActivity.CPU]) as prof:
                updater.update(td)
            rows = sorted(prof.key_averages(), key=lambda e: e.self_cpu_time_total, reverse=True)
            total = sum(e.self_cpu_time_total for e in rows)
            out["profile"] = [{"op": e.key, "self_ms": e.self_cpu_time_total / 1000, "share": e.self_cpu_time_total / total,
                               "calls": e.count} for e in rows[:15]]
    return out


def run_worker(args, setting: str, variant: str, profile: bool) -> dict:
    cmd = [sys.executable, "-m", "benchmarks.speed.update_speed", "--worker", setting, variant, "--batch", str(args.batch),
           "--steps", str(args.steps), "--updates", str(args.updates), "--threads", str(args.threads),
           *(["--profile"] if profile else [])]
    proc = subprocess.run(cmd, capture_output=True, text=True, env=child_env(), cwd=ROOT)
    if proc.returncode != 0:
        raise RuntimeError(f"worker {setting}/{variant} failed:\n{proc.stderr[-3000:]}")
    return json.loads(proc.stdout.strip().splitlines()[-1])


def summarise(results: dict) -> dict:
    summary = {}
    for setting, per_variant in results.items():
        summary[setting] = {}
        for variant, runs in per_variant.items():
            updates = [s for run in runs for s in run["update_s"]]
            stage_names = list(dict.fromkeys(k for run in runs for rec in run["stages_s"] for k in rec))  # call order
            stages = {k: median_ms([rec.get(k, 0.0) for run in runs for rec in run["stages_s"]]) for k in stage_names}
            summary[setting][variant] = {"update_ms": median_ms(updates), "update_ms_all": [1000 * s for s in updates],
                                         "stages_ms": stages, "peak_rss_mb": max(run["peak_rss_mb"] for run in runs),
                                         "first_update_ms": median_ms([run["first_update_s"] for run in runs])}
        base = summary[setting].get("initial", {}).get("update_ms")
        for variant, entry in summary[setting].items():
            entry["speedup_vs_initial"] = base / entry["update_ms"] if base else None
    return summary


def markdown(summary: dict, profiles: dict, metas: dict) -> str:
    lines = ["# MPAIL2 update speed", "",
             "One `MPAIL2Updater.update` (dynamics -> reward -> value + Polyak -> actor + alpha) on a `[B, T]` replay batch "
             "with expert windows, laid out as the trainer samples it (contiguous windows). Each variant runs in a fresh "
             "process, variants interleaved round after round; medians. The machine is shared: compare ratios within a "
             "setting (measured in one run).", ""]
    for setting, per_variant in summary.items():
        meta = metas[setting]
        lines += [f"## {setting}: {SETTINGS[setting].note}", "",
                  f"Batch `[{meta['batch']}, {meta['steps']}]`, {meta['threads']} thread(s), {meta['rounds']} round(s) x "
                  f"{meta['updates']} update(s) per variant; load average at start / end {meta['load_start']} / {meta['load_end']}.",
                  "", "| variant | ms / update | speed-up vs initial | peak RSS (MB) |", "|---|---:|---:|---:|"]
        for variant, entry in per_variant.items():
            speedup = "-" if entry["speedup_vs_initial"] is None else f"{entry['speedup_vs_initial']:.2f}x"
            lines.append(f"| {variant} | {entry['update_ms']:.0f} | {speedup} | "
                         f"{entry.get('peak_rss_mb', float('nan')):.0f} |")
        stage_names = list(dict.fromkeys(k for e in per_variant.values() for k in e["stages_ms"]))
        lines += ["", "Per-stage breakdown (ms, median; forward = the loss's forward incl. its encodes, "
                  "backward + step = backward, clip and Adam):", "",
                  "| stage | " + " | ".join(per_variant) + " |", "|---|" + "---:|" * len(per_variant)]
        for name in stage_names:
            lines.append(f"| {name} | " + " | ".join(f"{e['stages_ms'].get(name, 0.0):.0f}" for e in per_variant.values()) + " |")
        if setting in profiles:
            lines += ["", f"torch.profiler, one optimised update ({setting}), top ops by self CPU time:", "",
                      "| op | self ms | share | calls |", "|---|---:|---:|---:|"]
            for row in profiles[setting]:
                lines.append(f"| `{row['op']}` | {row['self_ms']:.0f} | {100 * row['share']:.1f}% | {row['calls']} |")
        lines.append("")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--worker", nargs=2, metavar=("SETTING", "VARIANT"), help=argparse.SUPPRESS)
    p.add_argument("--settings", default="paper,state,cameras")
    p.add_argument("--variants", default=",".join(VARIANTS))
    p.add_argument("--batch", type=int, default=256)
    p.add_argument("--steps", type=int, default=7)
    p.add_argument("--updates", type=int, default=3)
    p.add_argument("--rounds", type=int, default=2)
    p.add_argument("--threads", type=int, default=torch.get_num_threads())
    p.add_argument("--profile", action="store_true")
    p.add_argument("--out", default=str(ROOT / "docs" / "results" / "speed"))
    p.add_argument("--merge", action="store_true", help="keep the other settings already in update_speed.json")
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    if args.worker:
        print(json.dumps(worker(*args.worker, args.batch, args.steps, args.updates, args.profile)))
        return
    settings, variants = args.settings.split(","), args.variants.split(",")
    for variant in variants:
        if split_variant(variant)[0] not in VARIANTS:
            p.error(f"unknown variant {variant!r}; variants: {', '.join(VARIANTS)}, each optionally + {SYNC_FREE!r} "
                    f"and/or {COMPILED!r}")
    for setting in settings:
        if setting not in SETTINGS:
            p.error(f"unknown setting {setting!r}; settings: {', '.join(SETTINGS)}")
    load_start = [round(x, 2) for x in os.getloadavg()]
    results = {s: {v: [] for v in variants} for s in settings}
    profiles = {}
    for round_index in range(args.rounds):
        for setting in settings:
            for variant in variants:
                run = run_worker(args, setting, variant, profile=round_index == 0 and variant == "optimised")
                results[setting][variant].append(run)
                if "profile" in run:
                    profiles[setting] = run["profile"]
                print(f"round {round_index} {setting:8s} {variant:26s} "
                      f"{statistics.median(run['update_s']) * 1000:8.0f} ms/update", flush=True)
    meta = {"batch": args.batch, "steps": args.steps, "updates": args.updates, "rounds": args.rounds, "threads": args.threads,
            "load_start": load_start, "load_end": [round(x, 2) for x in os.getloadavg()], "machine": machine()}
    summary = summarise(results)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "update_speed.json"
    data = {"summary": {}, "profiles": {}, "meta": {}}
    if args.merge and path.exists():  # settings measured in separate runs (each run under ~10 minutes)
        data = json.loads(path.read_text())
    data["summary"].update(summary)
    data["profiles"].update(profiles)
    data["meta"].update({s: meta for s in settings})
    path.write_text(json.dumps(data, indent=2))
    text = (markdown(data["summary"], data["profiles"], data["meta"]).rstrip("\n")
            + f"\n\nCommit {git_commit(ROOT, short=True)}.\n\nData: [update_speed.json](update_speed.json)\n")
    (out / "update_speed.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
