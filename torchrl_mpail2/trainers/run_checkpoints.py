"""What a training run saves and restores: the agent, the counters, the random states and the replay buffer, in
``checkpoints/<tag>`` of the run folder; resuming a run from its newest complete checkpoint; starting one from
another run's weights."""
from __future__ import annotations

import functools
import json
import math
import time
import warnings
from collections.abc import Mapping
from pathlib import Path
from typing import Any

from torchrl_mpail2.config import ConfigError, apply_resume_overrides, read_run_config
from torchrl_mpail2.data import checkpoint as ckpt

__all__ = ["RunCheckpoints"]


class RunCheckpoints:
    """The checkpoint half of :class:`~torchrl_mpail2.trainers.MPAIL2Trainer` (which sets the attributes it reads:
    ``agent``, ``cfg``, ``demos``, ``demo_buffer``, ``replay``, ``counters``, ``best_eval``, ``run_dir``,
    ``run_folder``, ``logger``, ``_earlier_wall_s``, ``_launch_start``, ``_last_written``)."""

    def state_dict(self) -> dict:
        return {**self.agent.state_dict(), "demo_rng": self.demo_buffer.generator.get_state(), "rng": ckpt.rng_state(),
                "counters": dict(self.counters), "best_eval": self.best_eval, "config": self.cfg.to_dict(),
                "run_wall_s": self.run_wall_s(), "demos_sha256": self.demos_digest}

    @functools.cached_property
    def demos_digest(self) -> str:
        """sha256 of the demonstrations' observations (:meth:`Demonstrations.content_digest`), kept in checkpoints."""
        return self.demos.content_digest()

    def run_wall_s(self) -> float:
        """Wall seconds the run has trained over all its launches: the earlier ones up to the checkpoint this
        launch resumed (what a crash cut after it is not counted: it is trained again) and this one so far."""
        running = time.perf_counter() - self._launch_start if self._launch_start is not None else 0.0
        return self._earlier_wall_s + running

    def save(self, tag: str, with_replay: bool = False) -> Path:
        if tag == "last":
            self._last_written = self.counters["episodes"]
        return ckpt.write_checkpoint(self.run_dir / "checkpoints" / tag, self.state_dict(),
                                     self.replay if with_replay else None)

    def load(self, path: str | Path, with_replay: bool = True, allow_other_demos: bool = False) -> None:
        """Restores everything a checkpoint holds (the replay buffer too, when present and asked for).

        Args:
            path: the checkpoint folder.
            with_replay (bool): restore the stored replay buffer too. Defaults to True.
            allow_other_demos (bool): go on with demonstrations other than those the checkpoint was trained on
                (their sha256 is kept in the checkpoint). Defaults to False.

        Raises:
            CheckpointError: the checkpoint is missing, truncated or corrupted, was written for other
                networks (the message names the file, or the config fields that differ), or was trained on other
                demonstrations than this run holds (unless ``allow_other_demos``).
        """
        state = ckpt.read_checkpoint(path)
        ckpt.check_compatible(state["config"], self.cfg.to_dict(), Path(path))
        saved_demos = state.get("demos_sha256")  # older checkpoints did not record it
        if saved_demos is not None and saved_demos != self.demos_digest and not allow_other_demos:
            source = self.cfg.train.demos or "the demonstrations recorded for this run"
            raise ckpt.CheckpointError(
                f"{path} was trained on other demonstrations than {source} holds now (sha256 {saved_demos[:12]}... "
                f"then, {self.demos_digest[:12]}... now): were they replaced? Resume with --allow-other-demos "
                "(MPAIL2Trainer.resume(..., allow_other_demos=True)) to go on with these")
        self.agent.load_state_dict(state)
        self.demo_buffer.generator.set_state(state["demo_rng"])
        ckpt.set_rng_state(state["rng"])
        self.counters.update(state["counters"])
        self._earlier_wall_s = float(state.get("run_wall_s", 0.0))  # older checkpoints did not count it
        best = state["best_eval"]
        # older checkpoints kept the last-step success alone
        self.best_eval = tuple(best) if isinstance(best, (list, tuple)) else (-math.inf, best)
        if with_replay and ckpt.has_replay(path):
            ckpt.load_replay(self.replay, path)

    def init_from(self, path: str | Path, transfer: str = "all") -> None:
        """Copies weights of another run's checkpoint (:meth:`MPAIL2Agent.transfer_from`), before the first episode.

        Raises:
            CheckpointError: the checkpoint is damaged or was written for other networks (the message names the
                config fields or parameters that differ); the run folder is then discarded as a failed start.
        """
        if self.counters["episodes"]:
            raise ValueError(f"init_from({path!s}) after {self.counters['episodes']} episodes: weights are "
                             "transferred before training starts, not into a run under way")
        try:
            self.agent.transfer_from(path, transfer, config=self.cfg.to_dict())
        except BaseException:
            self.run_folder.discard()  # a run that fails to start leaves nothing behind
            raise

    @classmethod
    def resume(cls, run_dir: str | Path, overrides: list[str] | Mapping[str, Any] | None = None, *,
               allow_other_demos: bool = False, **kwargs) -> "MPAIL2Trainer":
        """Rebuilds a run from its ``config.json`` and continues from its newest complete checkpoint.

        That is ``checkpoints/last`` unless a crash left it missing or damaged (see
        :func:`~torchrl_mpail2.data.checkpoint.find_resumable`); a run killed before its first checkpoint
        starts over. ``overrides`` may change the fields of :data:`~torchrl_mpail2.config.RESUME_FIELDS`,
        e.g. ``["train.total_episodes=400"]`` or ``{"train.total_episodes": 400}`` to extend a finished run
        (:meth:`train` on a finished run changes nothing). Demonstrations other than those the checkpoint was
        trained on are refused unless ``allow_other_demos``.
        """
        run_dir = Path(run_dir)
        cfg = apply_resume_overrides(read_run_config(run_dir), overrides or [])
        trainer = cls(cfg, run_dir=run_dir, if_exists="resume", **kwargs)
        try:
            checkpoint = ckpt.find_resumable(run_dir / "checkpoints")
            if checkpoint is None:
                warnings.warn(f"{run_dir} holds no checkpoint yet: the run starts over", RuntimeWarning, stacklevel=2)
            else:
                done = ckpt.checkpoint_episodes(checkpoint)
                if cfg.train.total_episodes < done:  # before the replay is loaded into a smaller buffer
                    raise ConfigError(f"train.total_episodes={cfg.train.total_episodes}: {run_dir} has already run "
                                      f"{done} episodes (checkpoint {checkpoint.name}); a budget cannot go below "
                                      "them (a larger one extends the run)")
                trainer.load(checkpoint, allow_other_demos=allow_other_demos)
            trainer.logger.truncate_after(trainer.counters["episodes"])
        except BaseException:
            trainer.close()
            raise
        return trainer

    def close(self) -> None:
        """Releases the run folder (the next :meth:`train` takes it again)."""
        self.run_folder.release()

    def _budget_spent(self) -> bool:
        """The run has played ``train.total_episodes`` or collected ``train.total_env_steps``."""
        t = self.cfg.train
        return self.counters["episodes"] >= t.total_episodes or (t.total_env_steps is not None
                                                                 and self.counters["env_steps"] >= t.total_env_steps)

    def _finished_summary(self) -> dict | None:
        """The stored summary of a run that has already spent its budget (``total_episodes`` or ``total_env_steps``;
        None for one to go on)."""
        done, steps = self.counters["episodes"], self.counters["env_steps"]
        summary = self.run_dir / "summary.json"
        if not self._budget_spent() or not summary.exists():
            return None
        warnings.warn(f"{self.run_dir} has already finished its {done} episodes ({steps} env steps): nothing to do. "
                      f"Extend it with --resume {self.run_dir} train.total_episodes=N (N > {done}) or "
                      f"train.total_env_steps=N (N > {steps})", RuntimeWarning, stacklevel=3)
        return json.loads(summary.read_text())
