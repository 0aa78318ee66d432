"""Run logging: JSON lines for plots and resume, plus a TorchRL logger (CSV, wandb, tensorboard) that also takes
the evaluation videos."""
from __future__ import annotations

import importlib.util
import json
import math
import os
import secrets
import string
import warnings
from collections.abc import Callable
from pathlib import Path

import numpy as np
from tensordict import TensorDictBase

from torchrl_mpail2.trainers.evaluation import episode_outcome
from torchrl_mpail2.trainers.plots import EVAL_FILE, METRICS_FILE, read_jsonl
from torchrl_mpail2.trainers.videos import VIDEO_FPS, video_tensor

#: The wandb project of a run whose environment names none (``WANDB_PROJECT``).
WANDB_PROJECT = "torchrl-mpail2"
#: The run folder's file holding its wandb run id, so that a resumed run logs into the same wandb run.
WANDB_ID_FILE = "wandb_run_id"
#: Where an evaluation's videos go in the TorchRL logger.
VIDEO_TAG = "eval/video"

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
    """The TorchRL logger ``kind`` (``TrainConfig.logger``) writing into ``run_dir``; None for ``"none"``.

    wandb goes online where it is logged in and follows its own environment variables: ``WANDB_MODE`` (``offline``,
    ``disabled``), ``WANDB_PROJECT`` (default :data:`WANDB_PROJECT`), ``WANDB_ENTITY``, ``WANDB_RUN_GROUP``,
    ``WANDB_NAME`` (default: the run folder's name), ``WANDB_DIR`` (default: the run folder; wandb writes under
    its ``wandb/``) and ``WANDB_RUN_ID`` (default: the id kept in the run folder's :data:`WANDB_ID_FILE`, made on the
    first launch, so that a resumed run goes on in the same wandb run). The CSV logger writes each evaluation's videos under ``logs/videos/eval/`` as mp4 where
    torchcodec is installed, as the uint8 tensor saved by ``torch.save`` (``.pt``) elsewhere.
    """
    if kind == "none":
        return None
    if kind == "csv":
        from torchrl.record.loggers import CSVLogger
        return CSVLogger(exp_name="logs", log_dir=str(run_dir), video_format=_csv_video_format(), video_fps=VIDEO_FPS)
    if kind == "wandb":
        import wandb
        from torchrl.record.loggers import WandbLogger
        # TorchRL passes name, dir and project to wandb.init, where they would override wandb's own variables
        try:
            return WandbLogger(exp_name=os.environ.get("WANDB_NAME") or run_dir.name,
                               save_dir=os.environ.get("WANDB_DIR") or str(run_dir),
                               id=os.environ.get("WANDB_RUN_ID") or wandb_run_id(run_dir),
                               project=os.environ.get("WANDB_PROJECT") or WANDB_PROJECT, config=config,
                               video_fps=VIDEO_FPS)
        except wandb.errors.UsageError as error:  # not logged in, most often
            raise RuntimeError(f"train.logger=wandb: {error} Or log offline with WANDB_MODE=offline "
                               "(wandb sync uploads the run later).") from error
    if kind == "tensorboard":
        from torchrl.record.loggers import TensorboardLogger
        return TensorboardLogger(exp_name=run_dir.name, log_dir=str(run_dir / "tensorboard"))
    raise ValueError(f"unknown logger {kind!r}")


def wandb_run_id(run_dir: Path) -> str:
    """The wandb run id of the run in ``run_dir``: read from its :data:`WANDB_ID_FILE`, or made (8 random lowercase
    letters and digits, as wandb's own) and written there on the first launch (not where ``run_dir`` is no folder
    yet: the logger creates none)."""
    file = Path(run_dir) / WANDB_ID_FILE
    if file.exists() and file.read_text().strip():
        return file.read_text().strip()
    alphabet = string.ascii_lowercase + string.digits
    run_id = "".join(secrets.choice(alphabet) for _ in range(8))
    if file.parent.is_dir():
        file.write_text(run_id + "\n")
    return run_id


def _csv_video_format() -> str:
    """mp4 where TorchRL's CSV logger can encode it (torchcodec), its own ``pt`` format elsewhere."""
    try:
        importlib.import_module("torchcodec.encoders")
    except Exception:  # missing, or built for another torch: both leave mp4 unwritable
        return "pt"
    return "mp4"


def video_blocker(logger) -> str | None:
    """Why ``logger`` cannot take videos here (None when it can)."""
    if type(logger).__name__ != "TensorboardLogger":
        return None
    try:  # torch's add_video encodes a GIF with moviepy 1 (moviepy.editor, gone from moviepy 2)
        found = importlib.util.find_spec("moviepy.editor") is not None
    except ImportError:
        found = False
    if found:
        return None
    return ("train.logger=tensorboard gets no videos here: torch's add_video needs moviepy 1 "
            "(pip install 'moviepy<2'); the mp4 files are in the run folder's videos/")


def episode_records(episodes: list[TensorDictBase], first: int, acting: dict[str, float], random_actions: bool,
                    normalize: Callable[[float], float]) -> list[dict]:
    """One log record per episode of a collected batch, numbered from ``first + 1``: its outcome, the planner's
    statistics ``acting`` (means over the batch, left out for random warm-up actions; its ``act_s``, the batch's
    acting seconds, goes with the last record alone) and the return ``normalize``\ d where that is finite."""
    acting = dict(acting)
    act_s = acting.pop("act_s", None)
    records = []
    for i, episode in enumerate(episodes):
        record = {"episode": first + i + 1, "length": episode.shape[0], **episode_outcome(episode),
                  "random_actions": random_actions}
        if "policy_influence" in episode.keys() and not random_actions:
            record["policy_influence"] = float(episode["policy_influence"].mean())
        normalized = normalize(record["task_return"])
        if math.isfinite(normalized):
            record["normalized_return"] = normalized
        if not random_actions:
            record.update(acting)
        records.append(record)
    if act_s is not None and not random_actions:
        records[-1]["act_s"] = act_s
    return records


class RunLogger:
    """Appends per-episode and per-evaluation records to ``metrics.jsonl`` / ``eval.jsonl`` and a TorchRL logger."""

    def __init__(self, run_dir: Path, kind: str, config: dict, video: bool = False):
        self.run_dir = Path(run_dir)
        self.logger = make_torchrl_logger(kind, self.run_dir, config)
        self.successes = [float(r["success"]) for r in read_jsonl(self.run_dir / METRICS_FILE)]
        #: why the logger gets no videos (None when it does, or when the run films nothing)
        self.video_blocker = video_blocker(self.logger) if video else None
        if self.video_blocker:
            warnings.warn(self.video_blocker, RuntimeWarning, stacklevel=2)

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

    def log_videos(self, videos: list[np.ndarray], paths: list[Path], step: int) -> None:
        """Sends an evaluation's videos (``[T, H, W, 3]`` uint8 frames, written to ``paths``) to the logger under
        :data:`VIDEO_TAG`: TorchRL's ``log_video`` takes them as one ``[B, T, C, H, W]`` tensor (CSV, tensorboard);
        wandb takes the mp4 files themselves, which need no moviepy, at the step of the evaluation's scalars."""
        if self.logger is None or self.video_blocker or not videos:
            return
        if type(self.logger).__name__ == "WandbLogger":
            import wandb

            self.logger.log_metrics({VIDEO_TAG: [wandb.Video(str(p), format="mp4") for p in paths]}, step=step)
        else:
            self.logger.log_video(VIDEO_TAG, video_tensor(videos), step=step, fps=VIDEO_FPS)

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
