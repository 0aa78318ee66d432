"""Success rate and speed of the scripted robosuite experts (state observations).

Runs seeded episodes of Lift, Push and PushMirrored with :class:`LiftExpert` / :class:`PushExpert`, prints a
table and writes ``docs/results/diagnostics/scripted_experts.json``. An episode counts as a success when the env's
``"success"`` flag is set at its last step (the cube is still lifted / still past the line at the horizon).

Usage::

    python -m benchmarks.learning.scripted_experts                 # 50 episodes per task
    python -m benchmarks.learning.scripted_experts --episodes 5 --tasks Push --no-write
"""

from __future__ import annotations

import argparse
import json
import platform
import time

import torch

from benchmarks.records import ROOT
from torchrl_mpail2.envs.names import ROBOSUITE_TASKS as TASKS
from torchrl_mpail2.envs.robosuite_env import make_robosuite_env
from torchrl_mpail2.experts.scripted import LiftExpert, PushExpert

RESULTS_PATH = ROOT / "docs" / "results" / "diagnostics" / "scripted_experts.json"
WARMUP_STEPS = 20  # robosuite's first steps include numba compilation


def evaluate_task(task: str, episodes: int, first_seed: int) -> dict:
    """Run ``episodes`` episodes, each on its own seed, and summarise them."""
    env = make_robosuite_env(task, obs="state", seed=first_seed)
    expert = (LiftExpert if task == "Lift" else PushExpert)(env)
    with torch.no_grad():
        env.rollout(WARMUP_STEPS, expert, break_when_any_done=False)
    successes, ever_successes, first_success_steps, step_seconds = [], [], [], []
    for episode in range(episodes):
        env.set_seed(first_seed + episode)
        start = time.perf_counter()
        with torch.no_grad():
            rollout = env.rollout(env.base_env.horizon, expert)
        step_seconds.append((time.perf_counter() - start) / rollout.shape[0])
        success = rollout["next", "success"].squeeze(-1)
        successes.append(bool(success[-1]))
        ever_successes.append(bool(success.any()))
        if success.any():
            first_success_steps.append(int(success.float().argmax()) + 1)
    env.close()
    return {
        "episodes": episodes,
        "seeds": [first_seed, first_seed + episodes - 1],
        "success_rate": sum(successes) / episodes,
        "success_rate_any_step": sum(ever_successes) / episodes,
        "mean_steps_to_success": sum(first_success_steps) / max(len(first_success_steps), 1),
        "mean_episode_length": env.base_env.horizon,
        "seconds_per_step": sum(step_seconds) / episodes,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=50)
    parser.add_argument("--first-seed", type=int, default=1000)
    parser.add_argument("--tasks", nargs="+", default=list(TASKS), choices=TASKS)
    parser.add_argument("--no-write", action="store_true", help="print only, leave the JSON alone")
    args = parser.parse_args()

    torch.set_num_threads(1)
    results = {}
    for task in args.tasks:
        results[task] = evaluate_task(task, args.episodes, args.first_seed)
        r = results[task]
        print(
            f"{task:13s} success {r['success_rate']:.2f} (any step {r['success_rate_any_step']:.2f}) "
            f"steps to success {r['mean_steps_to_success']:.1f}/{r['mean_episode_length']} "
            f"{1e3 * r['seconds_per_step']:.1f} ms/step",
            flush=True,
        )
    if not args.no_write:
        RESULTS_PATH.parent.mkdir(parents=True, exist_ok=True)
        payload = {
            "description": (
                "Scripted experts, state observations, one seed per episode. success_rate: success flag set at the "
                "last step (episodes never terminate, so every episode lasts the horizon); seconds_per_step: "
                "wall time of env.rollout per step (robosuite + transforms + expert) on a shared 2-core CPU"
            ),
            "machine": f"{platform.processor() or platform.machine()}, {torch.get_num_threads()} torch thread(s)",
            "results": results,
        }
        RESULTS_PATH.write_text(json.dumps(payload, indent=2) + "\n")
        print(f"wrote {RESULTS_PATH}")


if __name__ == "__main__":
    main()
