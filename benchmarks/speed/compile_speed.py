"""What ``planner.compile=true`` (``torch.compile`` of the plan scoring) costs and saves, per configuration.

For each setting, two planners on the same networks and observations, one eager and one compiled, seeded alike:

* ``compile_s``: wall time of the compiled planner's first call (both shapes of a call are compiled then: the
  first iteration scores N candidates, the later ones N - M) minus an eager call;
* ``eager_ms`` / ``compiled_ms``: median milliseconds per planning call, the two planners called in turn;
* ``graphs_after_eval_switch``: the number of compiled graphs before and after the first evaluation-mode call
  (``ExplorationType.DETERMINISTIC``): equal means evaluation reuses the training graphs;
* ``max_action_difference``: the largest difference between the two planners' actions over the timed calls;
* ``break_even_calls``: compile time over the time saved per call.

    python -m benchmarks.speed.compile_speed                          # JSON + Markdown in docs/results/speed
    python -m benchmarks.speed.compile_speed --settings lift_state --calls 5
    python -m benchmarks.speed.compile_speed --checkpoint RUN/checkpoints/episode_000170 --calls 30 --out FILE

``--checkpoint`` measures a trained agent instead: the checkpoint's networks and planner settings, planning from
observations of a short random rollout of the run's own environment (one per call), so that the agreement of the two
planners is checked on the latents and returns a training run actually plans with.
"""
from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import torch
from tensordict import TensorDict
from torchrl.data import Bounded
from torchrl.envs.utils import ExplorationType, set_exploration_type

from benchmarks.records import ROOT
from benchmarks.speed.common import machine, median_ms, random_observations
from torchrl_mpail2 import LatentMPPIPlanner, LossConfig, ModelConfig, PlannerConfig
from torchrl_mpail2.modules import MPAIL2Modules
from torchrl_mpail2.config import preset

#: name -> (model, planner, observation shapes, action dim, description)
SETTINGS = {
    "lift_state": (preset("lift_state").model, preset("lift_state").planner,
                   {"proprio": [27], "object": [10]}, 4, "the lift_state preset (CPU networks, N 256, K 32, J 4)"),
    "paper": (ModelConfig(latent_dim=512, hidden_dims=(512, 512)), PlannerConfig(), {"proprio": [26], "object": [10]},
              4, "Table 4 networks (latent 512, hidden [512, 512]) and planner (N 512, K 64, J 5, H 7)"),
}


def _graphs() -> int:
    from torch._dynamo.utils import counters

    return int(counters["stats"]["unique_graphs"])


def setting_inputs(name: str) -> tuple:
    """Random networks of a named setting: (modules, planner config, observations per call, action dim, note)."""
    model, planner_cfg, shapes, action_dim, note = SETTINGS[name]
    torch.manual_seed(0)
    obs = TensorDict(random_observations(shapes, 1), [1])
    return MPAIL2Modules(shapes, action_dim, model), planner_cfg, lambda i: obs, action_dim, note


def checkpoint_inputs(path: str, steps: int) -> tuple:
    """A trained agent's networks and planner settings, and observations of a random rollout of its environment."""
    from torchrl_mpail2.agents.mpail2 import MPAIL2Agent
    from torchrl_mpail2.envs import make_env

    agent = MPAIL2Agent.from_checkpoint(path)
    train = agent.run_config["train"]
    env = make_env(train["env"], obs=train["obs"], seed=0, **(train.get("env_kwargs") or {}))
    try:
        rollout = env.rollout(steps, break_when_any_done=False)
    finally:
        env.close()
    keys = list(env.observation_spec.keys())
    planner_cfg = PlannerConfig(**{**vars(agent.planner.cfg), "compile": False})
    return (agent.modules, planner_cfg, lambda i: rollout[i % steps].select(*keys).unsqueeze(0),
            agent.modules.action_dim, f"checkpoint {path}")


def measure(inputs: tuple, calls: int) -> dict:
    modules, planner_cfg, observation, action_dim, note = inputs
    spec = Bounded(-1, 1, (action_dim,))
    obs = observation(0)
    planners = {
        compiled: LatentMPPIPlanner(modules, spec, PlannerConfig(**{**vars(planner_cfg), "compile": compiled}),
                                    gamma=LossConfig.gamma, generator=torch.Generator().manual_seed(0))
        for compiled in (False, True)
    }
    start = time.perf_counter()
    planners[False](obs.clone())
    eager_first = time.perf_counter() - start
    start = time.perf_counter()
    planners[True](obs.clone())
    compiled_first = time.perf_counter() - start
    graphs_before = _graphs()
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        start = time.perf_counter()
        planners[True](obs.clone())
        eval_first_ms = (time.perf_counter() - start) * 1e3
    graphs_after = _graphs()
    for planner in planners.values():
        planner.reset()
        planner.generator.manual_seed(1)
    samples, difference = {False: [], True: []}, 0.0
    for call in range(calls):
        actions = {}
        for compiled, planner in planners.items():
            td = observation(call).clone()
            start = time.perf_counter()
            actions[compiled] = planner(td)["action"]
            samples[compiled].append(time.perf_counter() - start)
        difference = max(difference, float((actions[True] - actions[False]).abs().max()))
    eager_ms, compiled_ms = median_ms(samples[False]), median_ms(samples[True])
    compile_s = compiled_first - eager_first
    saved_ms = eager_ms - compiled_ms
    return {"note": note, "compile_s": round(compile_s, 1), "eager_ms": round(eager_ms, 1),
            "compiled_ms": round(compiled_ms, 1), "speedup": round(eager_ms / compiled_ms, 2),
            "eval_first_call_ms": round(eval_first_ms, 1),
            "graphs_after_eval_switch": [graphs_before, graphs_after],
            "max_action_difference": difference,
            "break_even_calls": round(compile_s * 1e3 / saved_ms) if saved_ms > 0 else None}


def markdown(results: dict, meta: dict) -> str:
    lines = ["# torch.compile of the plan scoring (`planner.compile=true`)", "",
             "| setting | compile (s) | eager ms/call | compiled ms/call | speedup | break-even calls | "
             "first eval call (ms) | graphs before / after eval | max action difference |",
             "|---|---:|---:|---:|---:|---:|---:|---|---:|"]
    for name, r in results.items():
        lines.append(f"| {name} | {r['compile_s']} | {r['eager_ms']} | {r['compiled_ms']} | {r['speedup']} | "
                     f"{r['break_even_calls']} | {r['eval_first_call_ms']} | "
                     f"{r['graphs_after_eval_switch'][0]} / {r['graphs_after_eval_switch'][1]} | "
                     f"{r['max_action_difference']:.1e} |")
    lines += ["", f"{meta['threads']} thread(s), {meta['calls']} timed calls per planner, one environment. "
              f"{meta['load']}", ""]
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--settings", nargs="+", default=list(SETTINGS), choices=list(SETTINGS))
    parser.add_argument("--checkpoint", help="measure this training checkpoint's agent instead of --settings")
    parser.add_argument("--calls", type=int, default=10)
    parser.add_argument("--threads", type=int, default=1)
    parser.add_argument("--load", default="", help="what else ran on the machine (written into the results)")
    parser.add_argument("--out", default=str(ROOT / "docs" / "results" / "speed" / "compile_speed"))
    args = parser.parse_args()
    torch.set_num_threads(args.threads)
    results = {}
    named = {"checkpoint": lambda: checkpoint_inputs(args.checkpoint, args.calls)} if args.checkpoint else {
        name: (lambda name=name: setting_inputs(name)) for name in args.settings}
    for name, inputs in named.items():
        results[name] = measure(inputs(), args.calls)
        print(name, results[name], flush=True)
    meta = {"threads": args.threads, "calls": args.calls, "load": args.load, "machine": machine(),
            "torch": torch.__version__}
    out = Path(args.out)
    out.with_suffix(".json").write_text(json.dumps({"meta": meta, "results": results}, indent=2) + "\n")
    out.with_suffix(".md").write_text(markdown(results, meta))
    print(f"wrote {out.with_suffix('.json')} and {out.with_suffix('.md')}")


if __name__ == "__main__":
    main()
