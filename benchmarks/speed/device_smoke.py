"""One planning call, one update and two point-mass training episodes on a device, checked against the CPU and
timed at the paper configuration.

    python -m benchmarks.speed.device_smoke --device cuda            # on a machine with a GPU (a few minutes)
    python -m benchmarks.speed.device_smoke --device cpu --quick     # the same code path on the CPU (smoke)

1. Agreement: the same weights on the CPU and on ``--device`` plan from the same observations with the same seeded
   noise (first-action distance reported) and take one update on the same batch (losses compared).
2. Training: two point-mass episodes with ``train.device=--device`` through the trainer (collection, replay,
   updates, evaluation, checkpoints).
3. Speed at the paper configuration (latent 512, hidden [512, 512], N 512, K 64, J 5, H 7, Lift state
   observations): planning calls per second with one env (``--env-batches`` for more at once), fp32 and bf16
   (``--compile-modes``: also with ``planner.compile`` in those modes, the first call's time reported; on a GPU the
   kernels per call and GPU-busy time from the profiler), and the update time at batch 256.
Writes ``docs/results/speed/device_smoke.json`` (``--out`` to change).
"""
from __future__ import annotations

import argparse
import contextlib
import copy
import json
import platform
import tempfile
import time
from pathlib import Path

import torch
from tensordict import TensorDict

from benchmarks.records import ROOT
from benchmarks.speed.common import SETTINGS, random_observations, replay_batch
from torchrl_mpail2 import LatentMPPIPlanner, MPAIL2Loss, MPAIL2Updater, PlannerConfig
from torchrl_mpail2.config import COMPILE_MODES, LossConfig
from torchrl_mpail2.trainers import MPAIL2Trainer, apply_overrides, preset

RESULTS = ROOT / "docs" / "results" / "speed"
#: planner variants whose kernels are profiled on a GPU
PROFILED = ("fp32", "bf16", "fp32_compiled_reduce_overhead", "bf16_compiled_reduce_overhead")


def synchronize(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def plan_once(modules, obs: TensorDict, cfg: PlannerConfig, seed: int) -> torch.Tensor:
    spec = _action_spec(modules.action_dim, obs.device)
    planner = LatentMPPIPlanner(modules, spec, cfg, gamma=LossConfig.gamma)
    planner.generator = torch.Generator(device=obs.device).manual_seed(seed)
    return planner(obs.clone())["action"]


def _action_spec(action_dim: int, device) -> "Bounded":
    from torchrl.data import Bounded

    return Bounded(-1.0, 1.0, shape=(action_dim,), device=device)


def agreement(device: torch.device, setting_name: str, planner_cfg: PlannerConfig, batch: int) -> dict:
    setting = SETTINGS[setting_name]
    cpu_modules = setting.modules(seed=0)
    dev_modules = copy.deepcopy(cpu_modules).to(device)
    obs = TensorDict(random_observations(setting.observations, 1), [1])
    a_cpu = plan_once(cpu_modules, obs, planner_cfg, seed=7)
    a_dev = plan_once(dev_modules, obs.to(device), planner_cfg, seed=7).cpu()
    td = replay_batch(setting, batch, steps=dev_modules.cfg.horizon)
    losses = {}
    for name, modules, data in (("cpu", cpu_modules, td), ("device", dev_modules, td.to(device))):
        torch.manual_seed(3)
        out = MPAIL2Updater(MPAIL2Loss(modules, LossConfig()), retain_memory=False).update(data)
        losses[name] = {k: float(v) for k, v in out.items() if k.startswith("loss_")}
    return {"first_action_distance": float((a_cpu - a_dev).norm()),
            "note": "different devices draw different random numbers from the same seed: the plans agree only as "
                    "far as MPPI's result does not depend on the noise drawn",
            "losses_cpu": losses["cpu"], "losses_device": losses["device"]}


def train_two_episodes(device: torch.device, utd: float = 1.0) -> dict:
    """Two point-mass episodes (one of warm-up) at ``utd`` updates per step, then an evaluation of two episodes."""
    with tempfile.TemporaryDirectory() as scratch, contextlib.chdir(scratch):  # scripted demos go to scratch/demos
        cfg = apply_overrides(preset("point_mass"), {
            "train.progress": False, "train.logger": "none", "train.num_demos": 2, "train.total_episodes": 2,
            "train.warmup_episodes": 1, "train.eval_every": 2, "train.eval_episodes": 2, "train.device": str(device),
            "train.utd": utd,
            "train.run_dir": f"{scratch}/run"})
        start = time.perf_counter()
        summary = MPAIL2Trainer(cfg).train()
        return {"episodes": summary["episodes"], "updates": summary["updates"],
                "eval_success_any_step": summary["last_eval"]["success_rate_any_step"],
                "seconds": time.perf_counter() - start, "time_split_s": summary["time_split_s"]}


def _calls_per_s(planner, obs: TensorDict, calls: int, device: torch.device) -> float:
    for _ in range(3):
        planner(obs.clone())
    synchronize(device)
    start = time.perf_counter()
    for _ in range(calls):
        planner(obs.clone())
    synchronize(device)
    return calls / (time.perf_counter() - start)


def kernel_profile(planner, obs: TensorDict, calls: int = 5) -> dict:
    """GPU kernels launched and GPU-busy time per planning call of a warmed-up planner against its wall time (is the
    call launch-bound?)."""
    from torch.profiler import ProfilerActivity, profile

    with profile(activities=[ProfilerActivity.CPU, ProfilerActivity.CUDA]) as prof:
        start = time.perf_counter()
        for _ in range(calls):
            planner(obs.clone())
        synchronize(obs.device)
        wall = time.perf_counter() - start
    kernels = [e for e in prof.events() if e.device_type == torch.autograd.DeviceType.CUDA]
    busy_us = sum(e.device_time for e in kernels)
    return {"kernels_per_call": len(kernels) / calls, "gpu_busy_ms_per_call": busy_us / 1000 / calls,
            "wall_ms_per_call_profiled": 1000 * wall / calls}


def speed(device: torch.device, calls: int, updates: int, batch: int, compile_modes: tuple[str, ...] = (),
          env_batches: tuple[int, ...] = (1,)) -> dict:
    """The update time and planning calls per second at the paper configuration: fp32 and bf16, also compiled in
    each of ``compile_modes``, for each number of envs planned for at once in ``env_batches``."""
    setting = SETTINGS["paper"]
    modules = setting.modules(seed=0).to(device)
    spec = _action_spec(setting.action_dim, device)
    out = {}
    td = replay_batch(setting, batch, steps=modules.cfg.horizon).to(device)
    # the default (on a GPU: stages skipped on NaN without a host synchronisation) and a host check per stage
    for label, sync_free in (("update_ms", None), ("update_ms_host_checks", False)):
        updater = MPAIL2Updater(MPAIL2Loss(modules, LossConfig(transitions_per_window=1)), retain_memory=False,
                                sync_free_skips=sync_free)
        updater.update(td)
        synchronize(device)
        start = time.perf_counter()
        for _ in range(updates):
            updater.update(td)
        synchronize(device)
        out[label] = 1000 * (time.perf_counter() - start) / updates
    out["update_batch"] = batch
    print(json.dumps(out), flush=True)
    variants = [("fp32", False, None), ("bf16", True, None)]
    for mode in compile_modes:
        tag = "compiled" if mode == "default" else f"compiled_{mode.replace('-', '_')}"
        variants += [(f"fp32_{tag}", False, mode), (f"bf16_{tag}", True, mode)]
    for num_envs in env_batches:
        obs = TensorDict(random_observations(setting.observations, num_envs), [num_envs]).to(device)
        suffix = "" if num_envs == 1 else f"_{num_envs}envs"
        for label, bf16, mode in variants:
            compiled = mode is not None
            if compiled:
                # every variant compiles afresh: the compiled scorer's cache is per code object, shared by all
                # planners of the process, and past torch._dynamo's recompile limit (8 shapes and modes here)
                # it would silently run eagerly
                torch._dynamo.reset()
            planner = LatentMPPIPlanner(modules, spec, PlannerConfig(bf16=bf16, compile=compiled,
                                                                     compile_mode=mode or "default"),
                                        gamma=LossConfig.gamma)
            start = time.perf_counter()
            planner(obs.clone())  # compiles here with compile=True
            synchronize(device)
            if compiled:
                out[f"first_call_s_{label}{suffix}"] = time.perf_counter() - start
            out[f"planning_calls_per_s_{label}{suffix}"] = _calls_per_s(planner, obs, calls, device)
            if device.type == "cuda" and label in PROFILED:
                out[f"profile_{label}{suffix}"] = kernel_profile(planner, obs)
            print(json.dumps({k: v for k, v in out.items() if k.endswith(f"{label}{suffix}")}), flush=True)
    return out


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    p.add_argument("--quick", action="store_true", help="small planner and few timed calls (a smoke run)")
    p.add_argument("--out", type=Path, default=RESULTS / "device_smoke.json")
    p.add_argument("--compile-modes", nargs="*", default=[], choices=COMPILE_MODES,
                   help="also time the planner with PlannerConfig.compile in these modes (first call's time reported)")
    p.add_argument("--env-batches", type=int, nargs="+", default=[1],
                   help="numbers of envs planned for in one call (each timed)")
    args = p.parse_args()
    device = torch.device(args.device)
    small = PlannerConfig(num_candidates=64, num_elites=8, iterations=2)
    result = {"device": str(device), "device_name": torch.cuda.get_device_name(device) if device.type == "cuda"
              else platform.processor() or platform.machine(), "torch": torch.__version__, "quick": args.quick}
    result["agreement"] = agreement(device, "state", small if args.quick else PlannerConfig(), 16 if args.quick else 256)
    print(json.dumps(result["agreement"]), flush=True)
    result["training"] = train_two_episodes(device, utd=0.2 if args.quick else 1.0)
    print(json.dumps(result["training"]), flush=True)
    result["speed_paper_config"] = speed(device, calls=3 if args.quick else 50, updates=2 if args.quick else 20,
                                         batch=32 if args.quick else 256, compile_modes=tuple(args.compile_modes),
                                         env_batches=tuple(args.env_batches))
    print(json.dumps(result["speed_paper_config"]), flush=True)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(result, indent=2))


if __name__ == "__main__":
    main()
