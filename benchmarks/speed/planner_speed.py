"""Milliseconds per action of ``LatentMPPIPlanner`` against TorchRL's ``MPPIPlanner`` on the same networks.

Planners timed on identical networks and observations, interleaved call after call:

* ``ours fp32`` / ``ours bf16``: :class:`~torchrl_mpail2.LatentMPPIPlanner` (Algorithm 2: N = 512 candidates of which
  M = 26 from the policy, K = 64, J = 5, H = 7, warm start), ``PlannerConfig.bf16`` False / True;
* ``initial fp32`` / ``initial bf16``: the planner before the speed work (``_reference.InitialPlanner``);
* ``torchrl TD(lambda)``: ``torchrl.modules.planners.MPPIPlanner`` stepping :class:`LatentWorldModelEnv`, scored by a
  ``TDLambdaEstimator(gamma=0.99, lmbda=0.95, shifted=True)`` whose value network is
  ``V(z) = mean over all E heads of Q(z, first step of the policy mean at z)``;
* ``torchrl terminal``: the same planner scored by the return ours uses (discounted learned rewards plus
  ``gamma^H`` times the mean of two random Q heads at ``z_H``), i.e. equal work per candidate.

TorchRL's planner has no policy prior (all N candidates Gaussian every iteration), no warm start (mean 0 / std 1 at
each call), no minimum std and multiplies the returns by its temperature (given 1 / eta); it runs here under
``torch.no_grad`` as a collector would run it, from latents encoded outside the timed call.

Also: useful GFLOP per planning call against the machine's fp32 / bf16 GEMM ceilings measured in the same run,
the cost of ``validate_observations``, and bf16 plan quality (first-action distance to the fp32 planner on the same
seed and inputs, next to the distance between two fp32 seeds; elite overlap when scoring the same candidates).

    python -m benchmarks.speed.planner_speed                      # JSON + Markdown in docs/results/speed
    python -m benchmarks.speed.planner_speed --settings state --calls 3
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torch import nn
from torchrl.data import Bounded
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules.planners import MPPIPlanner
from torchrl.objectives.value import TDLambdaEstimator

from benchmarks.records import ROOT
from benchmarks.speed.common import SETTINGS, gemm_ceiling, machine, median_ms, random_observations
from benchmarks.speed.reference import InitialPlanner
from torchrl_mpail2 import LatentMPPIPlanner, LossConfig, PlannerConfig
from torchrl_mpail2.modules.encoder import validate_observations
from torchrl_mpail2.modules.value import HEADS_PER_ESTIMATE
from torchrl_mpail2.planners.latent_env import LatentWorldModelEnv


class PolicyValue(nn.Module):
    """``V(z)``: mean over all Q heads of ``Q(z, a)``, ``a`` the first step of the policy mean at ``z``."""

    def __init__(self, modules):
        super().__init__()
        self.q, self.policy = modules.value.net, modules.policy.net

    def forward(self, z):
        a = self.policy(z, deterministic=True)[0][..., 0, :]
        return self.q(z, a).mean(0)


class TerminalReturn(nn.Module):
    """Advantage module giving TorchRL's planner our return: ``sum_k gamma^k r_k + gamma^H mean_2heads Q(z_H, a_H)``."""

    def __init__(self, modules, gamma: float):
        super().__init__()
        self.q, self.policy, self.gamma = modules.value.net, modules.policy.net, gamma

    def forward(self, td):
        r = td.get(("next", "reward")).squeeze(-1)  # [*B, N, H]
        horizon = r.shape[-1]
        z_last = td.get(("next", "z"))[..., -1, :]
        heads = torch.randperm(self.q.num_q)[:HEADS_PER_ESTIMATE]
        a_last = self.policy(z_last, deterministic=True)[0][..., 0, :]
        q = self.q(z_last, a_last, heads=heads).squeeze(-1).mean(0)
        discounts = self.gamma ** torch.arange(horizon, dtype=r.dtype)
        G = (r * discounts).sum(-1) + self.gamma ** horizon * q
        advantage = torch.zeros_like(r).unsqueeze(-1)
        advantage[..., 0, 0] = G
        td.set("advantage", advantage)
        return td


def useful_macs(setting, cfg: PlannerConfig, horizon: int) -> dict:
    """Multiply-adds one planning call needs per environment (only what the returns need)."""
    Z, h, A = setting.latent_dim, setting.hidden, setting.action_dim
    dynamics = (Z + A) * h + h * h + h * Z
    reward = 2 * Z * h + h * h + h  # first layer on [z, z'] (projected once per latent, used by two steps)
    policy = Z * h + h * h + h * 2 * horizon * A
    q_head = (Z + A) * h + h * h + h
    per_candidate = horizon * (dynamics + reward) + policy + HEADS_PER_ESTIMATE * q_head
    candidates = cfg.iterations * (cfg.num_candidates - cfg.num_policy_samples) + cfg.num_policy_samples
    return {"per_candidate": per_candidate, "candidates": candidates, "total": per_candidate * candidates}


def build(setting, num_envs: int, seed: int = 0) -> dict:
    modules = setting.modules(seed)
    spec = Bounded(-1, 1, (setting.action_dim,))
    cfg = PlannerConfig()
    torch.manual_seed(seed + 1)
    obs = TensorDict(random_observations(setting.observations, num_envs), [num_envs])
    env = LatentWorldModelEnv(modules, spec)
    common = dict(temperature=1.0 / cfg.temperature, planning_horizon=modules.horizon, optim_steps=cfg.iterations,
                  num_candidates=cfg.num_candidates, top_k=cfg.num_elites)
    value = TensorDictModule(PolicyValue(modules), in_keys=["z"], out_keys=["state_value"])
    tdl = TDLambdaEstimator(gamma=LossConfig.gamma, lmbda=0.95, value_network=value, shifted=True)
    with torch.no_grad():
        z = modules.encoder.encode(obs)
    planners = {
        "ours fp32": LatentMPPIPlanner(modules, spec, PlannerConfig(), gamma=LossConfig.gamma, generator=torch.Generator().manual_seed(0)),
        "ours bf16": LatentMPPIPlanner(modules, spec, PlannerConfig(bf16=True), gamma=LossConfig.gamma, generator=torch.Generator().manual_seed(0)),
        "initial fp32": InitialPlanner(modules, spec, PlannerConfig(), gamma=LossConfig.gamma, generator=torch.Generator().manual_seed(0)),
        "initial bf16": InitialPlanner(modules, spec, PlannerConfig(bf16=True), gamma=LossConfig.gamma,
                                       generator=torch.Generator().manual_seed(0)),
        "torchrl TD(lambda)": MPPIPlanner(env, tdl, **common),
        "torchrl terminal": MPPIPlanner(env, TerminalReturn(modules, LossConfig.gamma), **common),
    }
    inputs = {name: (TensorDict({"z": z}, [num_envs]) if name.startswith("torchrl") else obs) for name in planners}
    return {"modules": modules, "cfg": cfg, "planners": planners, "inputs": inputs, "obs": obs}


def time_planners(built: dict, calls: int, names: list[str]) -> dict:
    planners, inputs = built["planners"], built["inputs"]
    samples = {n: [] for n in names}
    with torch.no_grad():  # TorchRL's planner builds a graph otherwise; ours disables gradients itself
        for n in names:
            planners[n](inputs[n].clone())  # warm-up
        for _ in range(calls):
            for n in names:
                td = inputs[n].clone()
                t = time.perf_counter()
                planners[n](td)
                samples[n].append(time.perf_counter() - t)
    return {n: median_ms(s) for n, s in samples.items()}


def validation_cost(obs: TensorDict, shapes: dict, repeats: int = 200) -> float:
    t = time.perf_counter()
    for _ in range(repeats):
        validate_observations(obs, shapes)
    return 1e6 * (time.perf_counter() - t) / repeats


def bf16_quality(setting, num_obs: int = 8) -> dict:
    """First actions of the fp32 and bf16 planners on the same seed and inputs (deterministic mode)."""
    modules = setting.modules(0)
    spec = Bounded(-1, 1, (setting.action_dim,))
    torch.manual_seed(5)
    obs = TensorDict(random_observations(setting.observations, num_obs), [num_obs])

    def first_action(bf16: bool, seed: int) -> torch.Tensor:
        planner = LatentMPPIPlanner(modules, spec, PlannerConfig(bf16=bf16), gamma=LossConfig.gamma,
                                    generator=torch.Generator().manual_seed(seed))
        with set_exploration_type(ExplorationType.DETERMINISTIC):
            return planner(obs.clone())["action"]

    a32, a16, a32_other = first_action(False, 0), first_action(True, 0), first_action(False, 1)
    # the same candidates scored in both precisions: relative error and overlap of the K best
    planner = LatentMPPIPlanner(modules, spec, PlannerConfig(), gamma=LossConfig.gamma)
    cfg = planner.cfg
    with torch.inference_mode():
        z = modules.encoder.encode(obs)
        plans = (torch.randn(num_obs, cfg.num_candidates, modules.horizon, setting.action_dim,
                             generator=torch.Generator().manual_seed(3)) * cfg.std_max).clamp(-1, 1)
        heads = torch.tensor([0, 1])
        r32 = planner.score(z, plans, heads)
        planner.cfg = PlannerConfig(bf16=True)
        with planner._low_precision() as dtype:
            r16 = planner.score(z.to(dtype), plans, heads)
    top32 = r32.topk(cfg.num_elites, -1).indices
    top16 = r16.topk(cfg.num_elites, -1).indices
    overlap = torch.tensor([len(set(a.tolist()) & set(b.tolist())) / cfg.num_elites for a, b in zip(top32, top16)])
    return {
        "first_action_distance_bf16_vs_fp32_same_seed": (a16 - a32).norm(dim=-1).mean().item(),
        "first_action_distance_fp32_seed0_vs_seed1": (a32_other - a32).norm(dim=-1).mean().item(),
        "return_error_over_return_spread": ((r16 - r32).abs().mean(-1) / r32.std(-1)).mean().item(),
        "elite_overlap": overlap.mean().item(),
        "num_observations": num_obs,
    }


def markdown(results: dict, meta: dict) -> str:
    lines = ["# Planner speed", "",
             f"ms per planning call (one action for every environment), median of {meta['calls']} interleaved calls, "
             f"{meta['threads']} thread(s). Machine load average at start/end: {meta['load_start']} / {meta['load_end']} "
             "(shared machine: compare ratios within this run). Planner: N = 512, M = 26 policy samples, K = 64, "
             "J = 5, H = 7, 5 Q heads (2 used).", "",
             f"GEMM ceilings measured in this run ({meta['ceiling_shape']}): fp32 {meta['ceiling_fp32']:.0f} GFLOP/s, "
             f"bf16 {meta['ceiling_bf16']:.0f} GFLOP/s; at the planner's 486-row GEMMs: fp32 {meta['ceiling_fp32_486']:.0f}, "
             f"bf16 {meta['ceiling_bf16_486']:.0f}.", ""]
    for key, entry in results.items():
        setting, envs = entry["setting"], entry["num_envs"]
        times = entry["ms"]
        lines += [f"## {setting}, {envs} environment(s): {SETTINGS[setting].note}", "",
                  f"Useful work: {entry['gflop']:.1f} GFLOP per call ({entry['macs']['per_candidate'] / 1e6:.2f} M multiply-adds "
                  f"per candidate x {entry['macs']['candidates']} candidates x {envs} env(s)); lower bound at the fp32 "
                  f"ceiling {entry['bound_ms_fp32']:.0f} ms, at the bf16 ceiling {entry['bound_ms_bf16']:.0f} ms.", "",
                  "| planner | ms / call | ms / env | vs torchrl TD(lambda) | vs torchrl terminal | GFLOP/s | % of ceiling |",
                  "|---|---:|---:|---:|---:|---:|---:|"]
        for name, ms in times.items():
            ceiling = meta["ceiling_bf16"] if "bf16" in name else meta["ceiling_fp32"]
            useful = entry["gflop"] if not name.startswith("torchrl") else None
            rate = f"{useful / ms * 1000:.0f}" if useful else "-"
            share = f"{100 * useful / ms * 1000 / ceiling:.0f}%" if useful else "-"
            against = " | ".join(f"{times[ref] / ms:.1f}x" if ref in times else "-"  # a reference left out by --skip
                                 for ref in ("torchrl TD(lambda)", "torchrl terminal"))
            lines.append(f"| {name} | {ms:.0f} | {ms / envs:.0f} | {against} | {rate} | {share} |")
        if "batching" in entry:
            lines += ["", "Batched planning, time for 8 environments over time for one: " +
                      ", ".join(f"{n} {r:.1f}x" for n, r in entry["batching"].items())]
        lines.append("")
    lines += ["## Other measurements", "",
              "`validate_observations` (one host sync, NaN/Inf check) per call: " +
              ", ".join(f"{k}: {v:.0f} us" for k, v in meta["validation_us"].items()), ""]
    lines += ["bf16 plan quality (random, untrained networks; deterministic first action, 8 observations):", "",
              "| setting | first-action distance bf16 vs fp32 (same seed) | fp32 seed 0 vs seed 1 | "
              "mean return error / return spread | elite overlap (same candidates) |", "|---|---:|---:|---:|---:|"]
    for setting, q in meta["bf16_quality"].items():
        lines.append(f"| {setting} | {q['first_action_distance_bf16_vs_fp32_same_seed']:.3f} | "
                     f"{q['first_action_distance_fp32_seed0_vs_seed1']:.3f} | {q['return_error_over_return_spread']:.3f} | "
                     f"{q['elite_overlap']:.2f} |")
    lines.append("")
    return "\n".join(lines)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--settings", default="paper,state")
    p.add_argument("--envs", default="1,8")
    p.add_argument("--calls", type=int, default=5)
    p.add_argument("--threads", type=int, default=torch.get_num_threads())
    p.add_argument("--skip", default="", help="comma-separated planner names not to time")
    p.add_argument("--out", default=str(ROOT / "docs" / "results" / "speed"))
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    load_start = [round(x, 2) for x in os.getloadavg()]
    shape = (3584, 516, 512)
    meta = {"calls": args.calls, "threads": args.threads, "load_start": load_start, "ceiling_shape": "x".join(map(str, shape)),
            "ceiling_fp32": gemm_ceiling(*shape, torch.float32), "ceiling_bf16": gemm_ceiling(*shape, torch.bfloat16),
            "ceiling_fp32_486": gemm_ceiling(486, 516, 512, torch.float32),
            "ceiling_bf16_486": gemm_ceiling(486, 516, 512, torch.bfloat16), "validation_us": {}, "bf16_quality": {}}
    print({k: v for k, v in meta.items() if k.startswith("ceiling")}, flush=True)
    skip = set(filter(None, args.skip.split(",")))
    results = {}
    for setting_name in args.settings.split(","):
        setting = SETTINGS[setting_name]
        for envs in map(int, args.envs.split(",")):
            built = build(setting, envs)
            names = [n for n in built["planners"] if n not in skip]
            ms = time_planners(built, args.calls, names)
            macs = useful_macs(setting, built["cfg"], built["modules"].horizon)
            gflop = 2 * macs["total"] * envs / 1e9
            entry = {"setting": setting_name, "num_envs": envs, "ms": ms, "macs": macs, "gflop": gflop,
                     "bound_ms_fp32": 1000 * gflop / meta["ceiling_fp32"], "bound_ms_bf16": 1000 * gflop / meta["ceiling_bf16"]}
            one = results.get(f"{setting_name}/1")
            if envs > 1 and one is not None:
                entry["batching"] = {n: ms[n] / one["ms"][n] for n in ms if n in one["ms"]}
            results[f"{setting_name}/{envs}"] = entry
            meta["validation_us"][f"{setting_name}, {envs} env(s)"] = validation_cost(built["obs"], built["modules"].observation_shapes)
            print(setting_name, envs, {n: round(v) for n, v in ms.items()}, flush=True)
        meta["bf16_quality"][setting_name] = bf16_quality(setting)
        print(setting_name, meta["bf16_quality"][setting_name], flush=True)
    meta["load_end"] = [round(x, 2) for x in os.getloadavg()]
    meta["machine"] = machine()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    (out / "planner_speed.json").write_text(json.dumps({"meta": meta, "results": results}, indent=2))
    (out / "planner_speed.md").write_text(markdown(results, meta))
    print(markdown(results, meta))


if __name__ == "__main__":
    main()
