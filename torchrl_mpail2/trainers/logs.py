"""Run logging: JSON lines for plots and resume, plus a TorchRL logger (CSV, wandb offline, tensorboard)."""
from __future__ import annotations

import json
from pathlib import Path

from torchrl_mpail2.trainers.plots import EVAL_FILE, METRICS_FILE, read_jsonl

#: Metric name -> log group, so that dashboards show the paper's groups.
GROUPS = {
    "loss_": "losses", "reward_": "reward", "grad_penalty": "reward", "expert_accuracy": "reward",
    "q_": "value", "learned_reward_mean": "value", "alpha": "policy", "entropy": "policy", "target_entropy": "policy",
    "imagined_return": "policy",
    "policy_influence": "planner", "elite_return": "planner", "plan_std": "planner", "elite_ess": "planner",
    "success": "environment", "task_return": "environment", "normalized_return": "environment", "length": "environment",
    "update_ms": "speed", "env_steps_per_s": "speed", "actions_per_s": "speed", "act_s": "speed", "collect_s": "speed",
    "dynamics_error_last": "losses", "nonfinite_skips": "losses",
}


def group_of(name: str) -> str:
    for prefix, group in GROUPS.items():
        if name.startswith(prefix):
            return group
    return "counters"


def make_torchrl_logger(kind: str, run_dir: Path, config: dict):
    if kind == "none":
        return None
    if kind == "csv":
        from torchrl.record.loggers import CSVLogger
        return CSVLogger(exp_name="logs", log_dir=str(run_dir))
    if kind == "wandb":
        from torchrl.record.loggers import WandbLogger
        return WandbLogger(exp_name=run_dir.name, offline=True, save_dir=str(run_dir), config=config)
    if kind == "tensorboard":
        from torchrl.record.loggers import TensorboardLogger
        return TensorboardLogger(exp_name=run_dir.name, log_dir=str(run_dir / "tensorboard"))
    raise ValueError(f"unknown logger {kind!r}")


class RunLogger:
    """Appends per-episode and per-evaluation records to ``metrics.jsonl`` / ``eval.jsonl`` and a TorchRL logger."""

    def __init__(self, run_dir: Path, kind: str, config: dict):
        self.run_dir = Path(run_dir)
        self.logger = make_torchrl_logger(kind, self.run_dir, config)
        self.successes = [float(r["success"]) for r in read_jsonl(self.run_dir / METRICS_FILE)]

    def _scalars(self, record: dict, step: int, prefix: str = "") -> None:
        if self.logger is None:
            return
        for name, value in record.items():
            if isinstance(value, (int, float)) and not isinstance(value, bool):
                self.logger.log_scalar(f"{prefix}{group_of(name)}/{name}", float(value), step=step)

    def log_episode(self, record: dict) -> None:
        with open(self.run_dir / METRICS_FILE, "a") as f:
            f.write(json.dumps(record) + "\n")
        self.successes.append(float(record["success"]))
        self._scalars(record, record["episode"])

    def log_eval(self, record: dict) -> None:
        with open(self.run_dir / EVAL_FILE, "a") as f:
            f.write(json.dumps(record) + "\n")
        self._scalars(record, record["episode"], prefix="eval/")

    def log_video(self, path: Path, step: int) -> None:
        """Sends an evaluation video (an mp4 in the run folder) to the logger, where it takes media (wandb)."""
        if self.logger is not None and type(self.logger).__name__ == "WandbLogger":
            import wandb

            self.logger.experiment.log({"eval/video": wandb.Video(str(path), format="mp4")}, step=step)

    def eval_at(self, episode: int) -> dict | None:
        """The evaluation ``eval.jsonl`` holds at ``episode`` (None if there is none)."""
        return next((r for r in read_jsonl(self.run_dir / EVAL_FILE) if r.get("episode") == episode), None)

    def success_rate(self, window: int) -> float:
        recent = self.successes[-window:]
        return sum(recent) / len(recent) if recent else 0.0

    def truncate_after(self, episodes: int) -> None:
        """Drops records of episodes after the checkpoint a resumed run restarts from."""
        for name in (METRICS_FILE, EVAL_FILE):
            path = self.run_dir / name
            kept = [r for r in read_jsonl(path) if r["episode"] <= episodes]
            path.write_text("".join(json.dumps(r) + "\n" for r in kept))
        self.successes = [float(r["success"]) for r in read_jsonl(self.run_dir / METRICS_FILE)]
