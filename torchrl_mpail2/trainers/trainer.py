"""The MPAIL2 training loop (Algorithm 1) from TorchRL parts: a Collector driving the planner, the replay buffer of
:mod:`.replay`, a demonstration buffer and the agent's per-stage update; checkpoints and resume in
:mod:`.run_checkpoints`."""
from __future__ import annotations

import functools
import json
import logging
import math
import os
import time
import warnings
from collections.abc import Callable
from pathlib import Path

import torch
from tensordict import TensorDict
from torchrl.data import TensorDictReplayBuffer
from tqdm.auto import tqdm

from torchrl_mpail2.agents import MPAIL2Agent
from torchrl_mpail2.config import ConfigError, ExperimentConfig, resolve_for_run
from torchrl_mpail2.data import DemoBuffer, Demonstrations
from torchrl_mpail2.envs.keys import observation_keys_of
from torchrl_mpail2.planners.mppi import WARM_START_KEY
from torchrl_mpail2.planners.policy_actor import NonFiniteActionError
from torchrl_mpail2.trainers.collection import (EpisodeStream, crossed_multiple, episode_bound, make_collector,
                                                split_episodes)
from torchrl_mpail2.trainers.evaluation import (evaluate_episodes, evaluate_episodes_lockstep, evaluation_seeds,
                                                summarize_outcomes)
from torchrl_mpail2.trainers.logs import RunLogger, episode_records
from torchrl_mpail2.trainers.plots import plot_run
from torchrl_mpail2.trainers.ray_collection import RayEpisodeCollector, ray_init_kwargs, require_ray
from torchrl_mpail2.trainers.replay import make_replay, store_episodes
from torchrl_mpail2.trainers.run_checkpoints import RunCheckpoints
from torchrl_mpail2.trainers.run_demos import load_or_record_demos
from torchrl_mpail2.trainers.run_folder import RunFolder
from torchrl_mpail2.trainers.stage_timer import StageTimer
from torchrl_mpail2.trainers.stop_signals import StopOnSignal
from torchrl_mpail2.trainers.videos import check_can_film, write_videos

log = logging.getLogger(__name__)


class MPAIL2Trainer(RunCheckpoints):
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
        # a batch of several episodes may step past total_episodes by up to one batch less one episode
        capacity = t.replay_size or (t.total_episodes + t.episodes_per_batch - 1) * episode_bound(self.env)
        if not t.replay_size and t.total_env_steps is not None:  # the step budget, passed by at most one batch
            capacity = min(capacity, t.total_env_steps + t.episodes_per_batch * episode_bound(self.env))
        replay = functools.partial(make_replay, capacity, t.batch_size, cfg.model.horizon, self.demo_buffer)
        self.replay = replay(self.run_dir / "replay_storage")
        self.latest = replay() if agent.switches.latest_episode_only else None
        self.counters = {"episodes": 0, "env_steps": 0, "updates": 0, "warnings": 0}
        self.best_eval = (-math.inf, -math.inf)  # (any-step, last-step) success of the best evaluation
        self._last_written = None  # episode count of the newest checkpoints/last
        #: wall seconds of this launch by stage: act (planning), env, update, evaluate, checkpoint, log
        self.timer = StageTimer()
        #: wall seconds of the run's earlier launches (up to the checkpoint this one resumed) and this launch's start
        self._earlier_wall_s, self._launch_start = 0.0, None
        self._eval_frames: list = []  # the filmed episodes of the latest evaluation (train.video)
        (self.run_dir / "config.json").write_text(cfg.to_json())
        self.logger = RunLogger(self.run_dir, t.logger, cfg.to_dict(), video=t.video)

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
            metrics = self.agent.update(td, td_policy)
            if metrics is None:  # a batch holding NaN or Inf, skipped whole
                nonfinite_keys.update(self.agent.last_nonfinite_keys)
                continue
            applied += 1
            sums = metrics if sums is None else sums + metrics  # stays on device: one transfer per episode
        self.counters["updates"] += applied
        out = {k: float(v) / max(applied, 1) for k, v in ({} if sums is None else sums).items()}
        out["nonfinite_skips"] = float(sum(self.agent.skipped.values()))  # a running count, not a mean
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

    def _train(self) -> dict:
        with StopOnSignal() as stop:
            return self._train_until(stop)

    def _train_until(self, stop: StopOnSignal) -> dict:
        """Algorithm 1: interact, store, update; evaluate and checkpoint on schedule. It ends at ``total_episodes`` or
        ``total_env_steps``, at the wall-clock budget or at a stop signal (``stop``)."""
        t, timer = self.cfg.train, self.timer
        bar = tqdm(total=t.total_episodes, initial=self.counters["episodes"], disable=not t.progress, desc="MPAIL2")
        start = self._launch_start = time.perf_counter()
        evaluation, evaluates_at_end = None, self._evaluates_at_end()
        stream = EpisodeStream(self._collector, restarts=self.counters["warnings"])
        if t.eval_at_start and self.counters["episodes"] == 0 and not stop.requested:
            evaluation = self.logger.eval_at(0) or self._evaluate_and_checkpoint()  # the starting weights
        try:
            while not self._budget_spent() and not self._should_stop(stop, start):
                # interact using the planner (Algorithm 2), random actions for the warm-up episodes
                self.agent.random_actions = self.counters["episodes"] < t.warmup_episodes
                episodes, records, steps = self._collect(stream)
                record = records[-1]  # the batch's own figures (timing, updates, counters) go with its last episode
                # B <- B u {(o_t, a_t, o_t+1)}
                store_episodes(episodes, self.counters["episodes"], self.replay, self.latest)
                self.counters["episodes"] += len(episodes)
                self.counters["env_steps"] += steps
                # updates per episode: encoder and dynamics, reward, value, policy
                if self.counters["episodes"] >= t.warmup_episodes:
                    with timer("update"):
                        record.update(self.update(max(1, round(t.utd * steps))))
                record.update(self.counters)
                with timer("log"):
                    for each in records:
                        self.logger.log_episode(each)
                done, added = self.counters["episodes"], len(episodes)
                periodic = crossed_multiple(done, added, t.eval_every) and (t.eval_until is None
                                                                            or done - added < t.eval_until)
                if periodic or (evaluates_at_end and self._budget_spent()):
                    evaluation = self._evaluate_and_checkpoint()
                with timer("checkpoint"):
                    if crossed_multiple(done, added, t.checkpoint_every):
                        self.save(f"episode_{done:06d}")
                    if crossed_multiple(done, added, t.last_every) and self._last_written != done:
                        self.save("last", with_replay=True)  # bounds what a crash loses to last_every episodes
                bar.update(added)
                bar.set_postfix(success=f"{self.logger.success_rate(t.success_window):.2f}",
                                eval="-" if evaluation is None else f"{evaluation['success_rate_any_step']:.2f}",
                                sps=f"{record['env_steps_per_s']:.1f}")
        finally:
            bar.close()
            stream.shutdown()
        # after a stop signal: no evaluation, the checkpoint only (a second signal stops at once)
        if evaluates_at_end and not stop.requested and (evaluation is None or evaluation["episode"] != self.counters["episodes"]):
            # stopped early: evaluate where it stopped, unless a launch before this one did
            evaluation = self.logger.eval_at(self.counters["episodes"]) or self._evaluate_and_checkpoint()
        with timer("checkpoint"):
            if self._last_written != self.counters["episodes"]:
                self.save("last", with_replay=True)
        if evaluation is None or evaluation["episode"] != self.counters["episodes"]:  # else the evaluation drew them
            self._draw_figures()
        return self._write_summary(start, evaluation, stop.requested)

    def _should_stop(self, stop: StopOnSignal, start: float) -> bool:
        """A stop signal came, or this launch has used its wall-clock budget ``train.max_wall_s``."""
        max_wall_s = self.cfg.train.max_wall_s
        if max_wall_s is not None and time.perf_counter() - start > max_wall_s:
            log.warning("stopping at the wall-clock budget of %.0f s", max_wall_s)
            return True
        return stop.requested

    def _collect(self, stream: EpisodeStream) -> tuple[list[TensorDict], list[dict], int]:
        """The next batch of complete episodes, their log records and their number of env steps. Acting is timed
        under ``act`` and the rest of collecting under ``env`` (under ``collect`` with Ray, whose workers act)."""
        tick = time.perf_counter()
        try:
            batch = stream.next(self.counters["episodes"] + 1)
        except NonFiniteActionError as err:
            raise NonFiniteActionError(f"episode {self.counters['episodes'] + 1}, after {self.counters['updates']} "
                                       f"updates: {err} Non-finite skips so far: {self.agent.skipped or 'none'}.") from err
        finally:
            self.counters["warnings"] = stream.restarts
        episodes = split_episodes(batch, drop=(WARM_START_KEY,))  # the planner's warm start is not data
        collect_s = time.perf_counter() - tick
        records = episode_records(episodes, self.counters["episodes"], self.agent.stats(), self.agent.random_actions,
                                  self.normalized_return)
        steps = sum(episode.shape[0] for episode in episodes)
        records[-1].update(env_steps_per_s=steps / collect_s, collect_s=collect_s)
        if self.cfg.train.collector == "ray":  # acting is timed in the workers, and not logged
            self.timer.add("collect", collect_s)
        else:
            act_s = records[-1].get("act_s", 0.0)
            self.timer.add("act", act_s)
            self.timer.add("env", collect_s - act_s)
        return episodes, records, steps

    def _write_summary(self, start: float, evaluation: dict | None, stopped_by: str | None) -> dict:
        best_any, best_last = self.best_eval
        summary = {"episodes": self.counters["episodes"], "env_steps": self.counters["env_steps"],
                   "updates": self.counters["updates"], "wall_time_s": time.perf_counter() - start,
                   "run_wall_time_s": self.run_wall_s(),
                   "best_eval_success_any_step": best_any if best_any > -math.inf else None,
                   "best_eval_success": best_last if best_any > -math.inf else None,
                   "last_eval": evaluation, "stopped_by": stopped_by,
                   "time_split_s": {**self.time_split, "total": time.perf_counter() - start}}
        (self.run_dir / "summary.json").write_text(json.dumps(summary, indent=2))
        self._earlier_wall_s, self._launch_start = summary["run_wall_time_s"], None  # a later train() adds to it
        return summary

    @property
    def time_split(self) -> dict[str, float]:
        """Wall seconds of this launch by stage (:attr:`timer`'s)."""
        return self.timer.seconds

    def _evaluates_at_end(self) -> bool:
        """Whether the run evaluates where it ends: evaluations are on and its budget reaches ``eval_every``.
        A run shorter than that (a smoke run of a few episodes) would reach no evaluation, and ends without one."""
        t = self.cfg.train
        return bool(t.eval_every) and t.total_episodes >= t.eval_every

    def _evaluate_and_checkpoint(self) -> dict:
        self._eval_frames = []  # an evaluate() replaced by a caller films nothing
        with self.timer("evaluate"):
            evaluation = self.evaluate()
        evaluation["episode"], evaluation["env_steps"] = self.counters["episodes"], self.counters["env_steps"]
        self.logger.log_eval(evaluation)
        frames, self._eval_frames = self._eval_frames, []  # not held in memory until the next evaluation
        self.logger.log_videos(frames, [Path(p) for p in evaluation.get("videos", [])], self.counters["episodes"])
        score = (evaluation["success_rate_any_step"], evaluation["success_rate"])
        with self.timer("checkpoint"):
            if score > self.best_eval:
                self.best_eval = score
                self.save("best")
            self.save("last", with_replay=True)
        self._draw_figures()  # the figures follow a long run, not just its end
        return evaluation

    def _draw_figures(self) -> None:
        """Redraw the run folder's figures (``curves.png``, ``learner.png``) unless ``train.figures`` is off; their time
        counts under ``log``."""
        if self.cfg.train.figures:
            with self.timer("log"):
                plot_run(self.run_dir, self.cfg.train.success_window)
