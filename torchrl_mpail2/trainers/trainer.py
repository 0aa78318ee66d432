"""The MPAIL2 training loop (Algorithm 1) from TorchRL parts: a Collector driving the planner,
a TensorDictReplayBuffer with a SliceSampler, a demonstration buffer and the per-stage updater."""
from __future__ import annotations

import functools
import json
import logging
import math
import os
import shutil
import time
import warnings
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import torch
from tensordict import TensorDict
from torchrl.data import LazyMemmapStorage, TensorDictReplayBuffer
from torchrl.data.replay_buffers import SliceSampler
from tqdm.auto import tqdm

from torchrl_mpail2.agents import MPAIL2Agent
from torchrl_mpail2.config import ConfigError
from torchrl_mpail2.data import TRAJ_KEY, AttachExpertWindows, DemoBuffer, Demonstrations
from torchrl_mpail2.data import checkpoint as ckpt
from torchrl_mpail2.envs.keys import observation_keys_of
from torchrl_mpail2.planners.mppi import WARM_START_KEY
from torchrl_mpail2.planners.policy_actor import NonFiniteActionError
from torchrl_mpail2.trainers.collection import crossed_multiple, episode_bound, make_collector, split_episodes
from torchrl_mpail2.trainers.config import ExperimentConfig, apply_resume_overrides, read_run_config, resolve_for_run
from torchrl_mpail2.trainers.evaluation import (episode_outcome, evaluate_episodes, evaluate_episodes_lockstep,
                                                evaluation_seeds, summarize_outcomes)
from torchrl_mpail2.trainers.logs import RunLogger
from torchrl_mpail2.trainers.plots import plot_run
from torchrl_mpail2.trainers.ray_collection import RayEpisodeCollector, ray_init_kwargs, require_ray
from torchrl_mpail2.trainers.run_demos import load_or_record_demos
from torchrl_mpail2.trainers.run_folder import RunFolder
from torchrl_mpail2.trainers.stop_signals import StopOnSignal
from torchrl_mpail2.trainers.videos import check_can_film, write_videos

log = logging.getLogger(__name__)


class MPAIL2Trainer:
    """Trains MPAIL2 online from observation-only demonstrations.

    Args:
        cfg (ExperimentConfig): run configuration.

    Keyword Args:
        env_fn (Callable, optional): builds one environment (default: ``make_env(cfg.train.env, ...)``).
        demos (Demonstrations, optional): expert observations (default: ``cfg.train.demos`` or scripted demos).
        run_dir (str or Path, optional): overrides ``cfg.train.run_dir``.
        agent (MPAIL2Agent, optional): the agent to train (default: built from ``cfg`` and the demos, with the
            observation normalisation set from the demos). Its networks must match ``cfg.model``: checkpoints
            record ``cfg`` as the run's config.
        if_exists (str): what to do with a run folder that already holds files: ``"refuse"`` (default),
            ``"overwrite"`` them, or ``"resume"`` (what :meth:`resume` passes). The folder is locked while the
            trainer uses it, so that two trainings cannot share it.

    Examples:
        >>> from torchrl_mpail2.trainers import ExperimentConfig, MPAIL2Trainer, preset  # doctest: +SKIP
        >>> trainer = MPAIL2Trainer(preset("point_mass"))  # doctest: +SKIP
        >>> summary = trainer.train()  # doctest: +SKIP
    """

    def __init__(self, cfg: ExperimentConfig, *, env_fn: Callable | None = None, demos: Demonstrations | None = None,
                 run_dir: str | Path | None = None, if_exists: str = "refuse", agent: MPAIL2Agent | None = None):
        t = cfg.train
        run_dir = Path(run_dir or t.run_dir or f"runs/{t.env.replace('/', '_')}-s{t.seed}-{time.strftime('%Y%m%d-%H%M%S')}")
        self.run_folder = RunFolder(run_dir, if_exists)
        try:
            self._build(resolve_for_run(cfg, run_dir), env_fn, demos, agent)
        except BaseException:
            self.run_folder.discard()  # a run that fails to start leaves nothing behind
            raise

    def _build(self, cfg: ExperimentConfig, env_fn: Callable | None, demos: Demonstrations | None,
               agent: MPAIL2Agent | None) -> None:
        self.cfg = cfg
        t = cfg.train
        if torch.device(t.device).type == "cuda" and not torch.cuda.is_available():
            raise ConfigError(f"TrainConfig.device={t.device!r}, but torch sees no CUDA device here")
        if t.collector == "ray":
            require_ray("train.collector='ray'")  # before anything is built or recorded
        if t.threads:
            torch.set_num_threads(t.threads)
        torch.manual_seed(t.seed)
        if env_fn is None:
            from torchrl_mpail2.envs import make_env

            # a partial of a module-level function: picklable, so that ParallelEnv workers can build it
            env_fn = functools.partial(make_env, t.env, obs=t.obs, device=t.device, **(t.env_kwargs or {}))
        self.env_fn = env_fn
        self.run_dir = Path(t.run_dir)
        if t.parallel_envs and t.num_envs > (os.cpu_count() or 1):
            warnings.warn(f"train.num_envs={t.num_envs} worker processes (train.parallel_envs) on {os.cpu_count()} "
                          "cores: they will take turns, and starting them takes long", RuntimeWarning, stacklevel=3)
        self.env = env_fn(seed=t.seed)
        if t.video:
            check_can_film(self.env)
        self.demos = demos if demos is not None else load_or_record_demos(cfg, self.env, env_fn)
        if agent is None:
            agent = MPAIL2Agent(self.env.observation_spec, self.env.action_spec, cfg.model, cfg.loss, cfg.planner,
                                ablation=t.ablation, update_precision=t.update_precision, demos=self.demos,
                                # with partial demos (train.demo_keys) the learner still observes every key
                                observation_keys=None if t.demo_keys is None else observation_keys_of(self.env),
                                device=t.device)
        self.agent = agent
        self.demo_buffer = DemoBuffer(self.demos, generator=torch.Generator().manual_seed(t.seed))
        horizon = cfg.model.horizon
        self.replay = self._make_replay(self.run_dir / "replay_storage", horizon)
        self.latest = self._make_replay(None, horizon) if agent.switches.latest_episode_only else None
        self.counters = {"episodes": 0, "env_steps": 0, "updates": 0, "warnings": 0}
        self.best_eval = (-math.inf, -math.inf)  # (any-step, last-step) success of the best evaluation
        self._last_written = None  # episode count of the newest checkpoints/last
        #: wall seconds of this training session by stage: act (planning), env, update, evaluate, checkpoint, log
        self.time_split: dict[str, float] = {}
        #: wall seconds of the run's earlier launches (up to the checkpoint this one resumed) and this launch's start
        self._earlier_wall_s, self._launch_start = 0.0, None
        self._eval_frames: list = []  # the filmed episodes of the latest evaluation (train.video)
        (self.run_dir / "config.json").write_text(cfg.to_json())
        self.logger = RunLogger(self.run_dir, t.logger, cfg.to_dict(), video=t.video)

    # ---- setup -----------------------------------------------------------------------------------
    def _make_replay(self, scratch: Path | None, horizon: int) -> TensorDictReplayBuffer:
        t = self.cfg.train
        # a batch of several episodes may step past total_episodes by up to one batch less one episode
        capacity = t.replay_size or (t.total_episodes + t.episodes_per_batch - 1) * episode_bound(self.env)
        if scratch is not None:
            # the live storage is a working copy; what survives a crash is the copy in checkpoints/last
            shutil.rmtree(scratch, ignore_errors=True)
        storage = LazyMemmapStorage(capacity, scratch_dir=scratch)
        sampler = SliceSampler(slice_len=horizon, traj_key=TRAJ_KEY, strict_length=True)
        replay = TensorDictReplayBuffer(storage=storage, sampler=sampler, batch_size=t.batch_size * horizon)
        replay.append_transform(AttachExpertWindows(self.demo_buffer, horizon))
        return replay

    # ---- one batch -------------------------------------------------------------------------------
    def sample_batch(self, replay: TensorDictReplayBuffer) -> TensorDict:
        """``[B, H]`` sub-trajectories from ``replay`` with expert windows under ``"expert"`` (its transform's)."""
        batch = replay.sample().reshape(self.cfg.train.batch_size, self.cfg.model.horizon)
        return batch.to(self.cfg.train.device)  # replay and demos stay in host memory

    def update(self, num_updates: int) -> dict:
        """``num_updates`` learner updates; returns the mean of each logged metric and the update time."""
        sums, applied, nonfinite_keys = None, 0, set()
        start = time.perf_counter()
        for _ in range(num_updates):
            td = self.sample_batch(self.replay)
            td_policy = self.sample_batch(self.latest) if self.latest is not None else None
            metrics = self.agent.updater.update(td, td_policy)
            if metrics is None:  # a batch holding NaN or Inf, skipped whole
                nonfinite_keys.update(self.agent.updater.last_nonfinite_keys)
                continue
            applied += 1
            sums = metrics if sums is None else sums + metrics  # stays on device: one transfer per episode
        self.counters["updates"] += applied
        out = {k: float(v) / max(applied, 1) for k, v in ({} if sums is None else sums).items()}
        out["nonfinite_skips"] = float(sum(self.agent.updater.skipped.values()))  # a running count, not a mean
        if nonfinite_keys:
            out["nonfinite_batch_keys"] = sorted(nonfinite_keys)
        out["update_ms"] = 1000 * (time.perf_counter() - start) / max(num_updates, 1)
        return out

    # ---- evaluation ------------------------------------------------------------------------------
    def evaluation_seeds(self, episodes: int | None = None) -> list[int]:
        """Seeds of the fixed evaluation episodes (``eval_seed + i``), the same in every run."""
        t = self.cfg.train
        return evaluation_seeds(t.eval_seed, episodes or t.eval_episodes)

    def evaluate(self, episodes: int | None = None) -> dict:
        """Episodes from a fixed set of initial states, acting as ``train.eval_acting`` says (see :mod:`.evaluation`).

        ``success_rate_any_step`` (success at any step of the episode, the paper's definition) is the headline
        figure; ``success_rate`` counts episodes whose last step is a success. With ``train.video`` the filmed
        episodes are written to ``videos/`` (their paths under ``"videos"``) and their frames kept for the logger
        until :meth:`_evaluate_and_checkpoint` sends them.
        """
        t = self.cfg.train
        seeds, videos = self.evaluation_seeds(episodes), [] if t.video else None
        env = self.eval_env = getattr(self, "eval_env", None) or self.env_fn(seed=t.eval_seed)
        if t.eval_envs == 1:
            outcomes = evaluate_episodes(env, self.agent.policy, seeds, self.agent.planner, videos=videos,
                                         video_episodes=t.video_episodes, acting=t.eval_acting)
        else:
            envs = self.eval_env_batch = getattr(self, "eval_env_batch", None) or [env]
            envs += [self.env_fn(seed=t.eval_seed + i) for i in range(len(envs), min(t.eval_envs, len(seeds)))]
            outcomes = evaluate_episodes_lockstep(envs, self.agent.policy, seeds, self.agent.planner, videos=videos,
                                                  video_episodes=t.video_episodes, acting=t.eval_acting)
        summary = summarize_outcomes(outcomes)
        self._eval_frames = videos or []  # [T, H, W, 3] arrays, for the logger
        if videos:
            summary["videos"] = [str(p) for p in write_videos(videos, self.run_dir / "videos",
                                                              f"eval_{self.counters['episodes']:06d}")]
        return {**summary, "normalized_return": self.normalized_return(summary["return"])}

    def normalized_return(self, task_return: float) -> float:
        """``task_return`` over the demonstrations' mean return (``nan`` where the demos hold no usable mean)."""
        demo_return = self.demos.mean_return
        return task_return / demo_return if math.isfinite(demo_return) and demo_return != 0 else math.nan

    # ---- checkpoints -----------------------------------------------------------------------------
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
        starts over. ``overrides`` may change the fields of :data:`~torchrl_mpail2.trainers.config.RESUME_FIELDS`,
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

    # ---- the loop --------------------------------------------------------------------------------
    def _collector(self):
        """This process's collector, or Ray workers' (``train.collector``), seeded ``seed + episodes`` on. The
        planner's warm start travels in the tensordict (each env its own), so that batched envs work."""
        t = self.cfg.train
        planner = self.agent.planner if self.agent.policy is self.agent.planner else None
        state = None if planner is None else planner.make_tensordict_primer()
        first_seed = t.seed + self.counters["episodes"]
        if t.collector == "ray":
            return RayEpisodeCollector(self.env_fn, self.agent.actor, self.agent.modules, first_seed=first_seed,
                                       workers=t.ray_workers, num_envs=t.num_envs, state=state,
                                       ray_init_config=ray_init_kwargs(t.ray_address, t.ray_workers))
        return make_collector(self.env_fn, self.agent.actor, first_seed, t.num_envs, t.parallel_envs, state=state)

    def _store(self, episodes: list[TensorDict]) -> None:
        """Into the replay, one episode after another; the latest-episode buffer ([-O]) keeps this batch's.

        Each episode's trajectory id becomes its run-wide index (episodes done before it): a collector counts its
        episodes from 0, again when it is rebuilt after an env error or a resume and in each Ray worker, and two
        neighbouring episodes under one id would be sampled as one trajectory.
        """
        first = self.counters["episodes"]
        episodes = [episode.set(TRAJ_KEY, torch.full_like(episode.get(TRAJ_KEY), first + i))
                    for i, episode in enumerate(episodes)]
        for episode in episodes:
            self.replay.extend(episode)
        if self.latest is not None:
            self.latest.empty()
            for episode in episodes:
                self.latest.extend(episode)

    def _next_episode(self, state: dict) -> TensorDict:
        """Next ``[episodes_per_batch, T]`` batch of complete episodes from the collector. A simulator exception ends that batch with a
        warning; a fresh collector (and environment) takes over and training goes on. Non-finite actions
        of the learner's own actor stop training at once (a new environment would not help)."""
        while True:
            if state.get("iterator") is None:
                state["collector"] = self._collector()
                state["iterator"] = iter(state["collector"])
            try:
                return next(state["iterator"])
            except NonFiniteActionError as err:
                skipped = dict(self.agent.updater.skipped)
                raise NonFiniteActionError(f"episode {self.counters['episodes'] + 1}, after {self.counters['updates']} "
                                           f"updates: {err} Non-finite skips so far: {skipped or 'none'}.") from err
            except (RuntimeError, ValueError, FloatingPointError) as err:
                self.counters["warnings"] += 1
                if self.counters["warnings"] > 100:
                    raise
                warnings.warn(f"episode {self.counters['episodes'] + 1} aborted by the environment ({err!r}); "
                              "restarting the collector", RuntimeWarning)
                state["collector"].shutdown()
                state["iterator"] = None

    def train(self) -> dict:
        """Runs until ``total_episodes``; returns a summary (best/last evaluation, counters, wall time).

        The run folder is locked meanwhile (released when training ends, by an error too; a new run that fails
        before its first episode is removed, a resumed one kept). A resumed run that
        has already finished changes nothing: a warning says how to extend it, and its summary is returned.
        """
        finished = self._finished_summary()
        if finished is not None:
            return finished
        self.run_folder.acquire()
        try:
            return self._train()
        except BaseException:
            if self.counters["episodes"] == 0:  # a run that fails before its first episode leaves no folder
                self.run_folder.discard()
            raise
        finally:
            self.close()

    def _finished_summary(self) -> dict | None:
        """The stored summary of a run that has already done its ``total_episodes`` (None for one to go on)."""
        t, done = self.cfg.train, self.counters["episodes"]
        summary = self.run_dir / "summary.json"
        if done < t.total_episodes or not summary.exists():
            return None
        warnings.warn(f"{self.run_dir} has already finished its {done} episodes: nothing to do. Extend it with "
                      f"--resume {self.run_dir} train.total_episodes=N (N > {done})", RuntimeWarning, stacklevel=3)
        return json.loads(summary.read_text())

    def _train(self) -> dict:
        with StopOnSignal() as stop:
            return self._train_until(stop)

    def _train_until(self, stop: StopOnSignal) -> dict:
        """The loop; it ends at ``total_episodes``, at the wall-clock budget or at a stop signal (``stop``)."""
        t = self.cfg.train
        bar = tqdm(total=t.total_episodes, initial=self.counters["episodes"], disable=not t.progress, desc="MPAIL2")
        start, evaluation, state = time.perf_counter(), None, {}
        self._launch_start = start
        evaluates_at_end = self._evaluates_at_end()
        try:
            while self.counters["episodes"] < t.total_episodes:
                if t.max_wall_s is not None and time.perf_counter() - start > t.max_wall_s:
                    log.warning("stopping at the wall-clock budget of %.0f s", t.max_wall_s)
                    break
                if stop.requested:
                    break
                # the first step of an episode may already be in flight when the previous one is yielded
                self.agent.actor.random_actions = self.counters["episodes"] < t.warmup_episodes
                tick = time.perf_counter()
                episodes = split_episodes(self._next_episode(state), drop=(WARM_START_KEY,))  # not data
                collect_s = time.perf_counter() - tick
                self._store(episodes)
                steps = sum(episode.shape[0] for episode in episodes)
                records = self._episode_records(episodes)
                record = records[-1]  # the batch's own figures (timing, updates, counters) go with its last episode
                record["env_steps_per_s"] = steps / collect_s
                record["collect_s"] = collect_s
                if t.collector == "ray":  # acting is timed in the workers, and not logged
                    self._time("collect", collect_s)
                else:
                    self._time("act", record.get("act_s", 0.0))
                    self._time("env", collect_s - record.get("act_s", 0.0))
                self.counters["episodes"] += len(episodes)
                self.counters["env_steps"] += steps
                if self.counters["episodes"] >= t.warmup_episodes:
                    tick = time.perf_counter()
                    record.update(self.update(max(1, round(t.utd * steps))))
                    self._time("update", time.perf_counter() - tick)
                record.update(self.counters)
                tick = time.perf_counter()
                for each in records:
                    self.logger.log_episode(each)
                self._time("log", time.perf_counter() - tick)
                done, added = self.counters["episodes"], len(episodes)
                if crossed_multiple(done, added, t.eval_every) or (evaluates_at_end and done >= t.total_episodes):
                    evaluation = self._evaluate_and_checkpoint()
                tick = time.perf_counter()
                if crossed_multiple(done, added, t.checkpoint_every):
                    self.save(f"episode_{done:06d}")
                if crossed_multiple(done, added, t.last_every) and self._last_written != done:
                    self.save("last", with_replay=True)  # bounds what a crash loses to last_every episodes
                self._time("checkpoint", time.perf_counter() - tick)
                bar.update(added)
                bar.set_postfix(success=f"{self.logger.success_rate(t.success_window):.2f}",
                                eval="-" if evaluation is None else f"{evaluation['success_rate_any_step']:.2f}",
                                sps=f"{record['env_steps_per_s']:.1f}")
        finally:
            bar.close()
            if state.get("collector") is not None:
                state["collector"].shutdown()
        # after a stop signal: no evaluation, the checkpoint only (a second signal stops at once)
        if evaluates_at_end and not stop.requested and (evaluation is None or evaluation["episode"] != self.counters["episodes"]):
            # stopped early: evaluate where it stopped, unless a launch before this one did
            evaluation = self.logger.eval_at(self.counters["episodes"]) or self._evaluate_and_checkpoint()
        tick = time.perf_counter()
        if self._last_written != self.counters["episodes"]:
            self.save("last", with_replay=True)
        self._time("checkpoint", time.perf_counter() - tick)
        if evaluation is None or evaluation["episode"] != self.counters["episodes"]:  # else the evaluation drew them
            self._draw_figures()
        summary = {"episodes": self.counters["episodes"], "env_steps": self.counters["env_steps"],
                   "updates": self.counters["updates"], "wall_time_s": time.perf_counter() - start,
                   "run_wall_time_s": self.run_wall_s(),
                   "best_eval_success_any_step": self.best_eval[0] if self.best_eval[0] > -math.inf else None,
                   "best_eval_success": self.best_eval[1] if self.best_eval[0] > -math.inf else None,
                   "last_eval": evaluation, "stopped_by": stop.requested,
                   "time_split_s": {**self.time_split, "total": time.perf_counter() - start}}
        (self.run_dir / "summary.json").write_text(json.dumps(summary, indent=2))
        self._earlier_wall_s, self._launch_start = summary["run_wall_time_s"], None  # a later train() adds to it
        return summary

    def _evaluates_at_end(self) -> bool:
        """Whether the run evaluates where it ends: evaluations are on and its budget reaches ``eval_every``.
        A run shorter than that (a smoke run of a few episodes) would reach no evaluation, and ends without one."""
        t = self.cfg.train
        return bool(t.eval_every) and t.total_episodes >= t.eval_every

    def _time(self, stage: str, seconds: float) -> None:
        self.time_split[stage] = self.time_split.get(stage, 0.0) + seconds

    def _evaluate_and_checkpoint(self) -> dict:
        tick = time.perf_counter()
        self._eval_frames = []  # an evaluate() replaced by a caller films nothing
        evaluation = self.evaluate()
        self._time("evaluate", time.perf_counter() - tick)
        evaluation["episode"] = self.counters["episodes"]
        self.logger.log_eval(evaluation)
        frames, self._eval_frames = self._eval_frames, []  # not held in memory until the next evaluation
        self.logger.log_videos(frames, [Path(p) for p in evaluation.get("videos", [])], self.counters["episodes"])
        score = (evaluation["success_rate_any_step"], evaluation["success_rate"])
        tick = time.perf_counter()
        if score > self.best_eval:
            self.best_eval = score
            self.save("best")
        self.save("last", with_replay=True)
        self._time("checkpoint", time.perf_counter() - tick)
        self._draw_figures()  # the figures follow a long run, not just its end
        return evaluation

    def _draw_figures(self) -> None:
        """Redraw the run folder's figures (``curves.png``, ``learner.png``) unless ``train.figures`` is off; their time
        counts under ``log``."""
        if not self.cfg.train.figures:
            return
        tick = time.perf_counter()
        plot_run(self.run_dir, self.cfg.train.success_window)
        self._time("log", time.perf_counter() - tick)

    def _episode_records(self, episodes: list[TensorDict]) -> list[dict]:
        """One log record per episode of a batch; the planner statistics (means over the batch) go with each,
        the batch's acting seconds with its last."""
        random_actions = bool(self.agent.actor.random_actions)
        acting = self.agent.actor.pop_stats()
        act_s = acting.pop("act_s", None)
        records = []
        for i, episode in enumerate(episodes):
            record = {"episode": self.counters["episodes"] + i + 1, "length": episode.shape[0],
                      **episode_outcome(episode), "random_actions": random_actions}
            if "policy_influence" in episode.keys() and not random_actions:
                record["policy_influence"] = float(episode["policy_influence"].mean())
            normalized = self.normalized_return(record["task_return"])
            if math.isfinite(normalized):
                record["normalized_return"] = normalized
            if not random_actions:
                record.update(acting)
            records.append(record)
        if act_s is not None and not random_actions:
            records[-1]["act_s"] = act_s
        return records
