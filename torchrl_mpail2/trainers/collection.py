"""Collecting training episodes with TorchRL's :class:`~torchrl.collectors.Collector`: from one environment, or from
``num_envs`` at once as a :class:`~torchrl.envs.SerialEnv` (one process) or :class:`~torchrl.envs.ParallelEnv` (one
worker process each), the planner acting on all of them in one batched call."""
from __future__ import annotations

import functools
import warnings
from collections.abc import Callable

from tensordict import TensorDictBase
from torchrl.collectors import Collector
from torchrl.envs import ParallelEnv, SerialEnv, Transform

from torchrl_mpail2.planners.policy_actor import NonFiniteActionError

__all__ = ["EpisodeStream", "crossed_multiple", "episode_bound", "make_collector", "make_collector_env",
           "split_episodes"]

MASK_KEY = ("collector", "mask")
#: Episode length assumed when an environment does not tell (gymnasium MuJoCo's limit).
DEFAULT_EPISODE_BOUND = 1000


def episode_bound(env) -> int:
    """Longest possible episode, read from the environment or the ones it wraps (``horizon``,
    ``max_episode_steps``); :data:`DEFAULT_EPISODE_BOUND` when none tells."""
    while env is not None:
        for name in ("horizon", "max_episode_steps", "_max_episode_steps"):
            value = getattr(env, name, None)
            if isinstance(value, int) and value > 0:
                return value
        env = getattr(env, "base_env", None) or getattr(env, "_env", None)
    return DEFAULT_EPISODE_BOUND


def make_collector_env(env_fn: Callable, first_seed: int, num_envs: int = 1, parallel: bool = False,
                       state: Transform | None = None):
    """The environment a collector of :func:`make_collector` steps: ``env_fn(seed=first_seed)`` alone, or
    ``num_envs`` of them seeded ``first_seed + i`` in a ``ParallelEnv`` (``parallel``; ``env_fn`` must then be
    picklable: a module-level function or a ``functools.partial`` of one) or a ``SerialEnv``, with ``state``
    appended (e.g. the planner's :meth:`~torchrl_mpail2.planners.LatentMPPIPlanner.make_tensordict_primer`)."""
    if num_envs < 1:
        raise ValueError(f"num_envs must be >= 1, got {num_envs}")
    if num_envs == 1:
        env = env_fn(seed=first_seed)
    else:
        batched = ParallelEnv if parallel else SerialEnv
        env = batched(num_envs, [functools.partial(env_fn, seed=first_seed + i) for i in range(num_envs)])
    return env if state is None else env.append_transform(state)


def make_collector(env_fn: Callable, actor, first_seed: int, num_envs: int = 1, parallel: bool = False,
                   state: Transform | None = None) -> Collector:
    """A collector yielding ``num_envs`` complete episodes at a time, padded to ``[num_envs, T]``, from
    :func:`make_collector_env` (environment ``i`` built with ``env_fn(seed=first_seed + i)``; with one environment
    no batched wrapper)."""
    env = make_collector_env(env_fn, first_seed, num_envs, parallel, state)
    return Collector(env, actor, frames_per_batch=1, total_frames=-1, trajs_per_batch=num_envs, traj_format="padded")


def split_episodes(batch: TensorDictBase, drop: tuple = ()) -> list[TensorDictBase]:
    """The episodes of a padded ``[N, T]`` collector batch, each cut to its own length, without the mask and
    without the keys in ``drop`` (at the root and under ``"next"``)."""
    dropped = [MASK_KEY, *drop, *(("next", key) for key in drop)]
    return [row[row.get(MASK_KEY)].exclude(*dropped) for row in batch.unbind(0)]


def crossed_multiple(done: int, added: int, every: int) -> bool:
    """Whether the counts ``done - added + 1 .. done`` hold a multiple of ``every`` (an evaluation or checkpoint
    falls due when a batch of several episodes steps over it).

    Examples:
        >>> crossed_multiple(52, 4, 50), crossed_multiple(48, 4, 50), crossed_multiple(50, 1, 50)
        (True, False, True)
    """
    return every > 0 and done // every > (done - added) // every


class EpisodeStream:
    """Batches of complete episodes from the collectors ``make`` builds, surviving simulator errors.

    A simulator exception (``RuntimeError``, ``ValueError``, ``FloatingPointError``) ends the batch under way with a
    warning; a fresh collector (and environment) takes over. Past ``max_restarts`` restarts in a run (``restarts``
    counts the earlier launches' too) the exception is raised. A :class:`NonFiniteActionError` of the learner's own
    actor is raised at once: a new environment would not help.

    Args:
        make (Callable[[], Collector]): builds a collector (called again after each restart).
        restarts (int): restarts the run has already had (a resumed run's count). Defaults to 0.
        max_restarts (int): restarts allowed in the whole run. Defaults to 100.
    """

    def __init__(self, make: Callable, restarts: int = 0, max_restarts: int = 100):
        self.make, self.restarts, self.max_restarts = make, restarts, max_restarts
        self._collector = self._iterator = None

    def next(self, episode: int) -> TensorDictBase:
        """The next ``[episodes, T]`` batch; ``episode`` (the run's number of the first) goes into warnings."""
        while True:
            if self._iterator is None:
                self._collector = self.make()
                self._iterator = iter(self._collector)
            try:
                return next(self._iterator)
            except NonFiniteActionError:
                raise
            except (RuntimeError, ValueError, FloatingPointError) as err:
                self.restarts += 1
                if self.restarts > self.max_restarts:
                    raise
                warnings.warn(f"episode {episode} aborted by the environment ({err!r}); restarting the collector",
                              RuntimeWarning, stacklevel=2)
                self.shutdown()

    def shutdown(self) -> None:
        """Stops the current collector (the next :meth:`next` builds a new one)."""
        if self._collector is not None:
            self._collector.shutdown()
        self._collector = self._iterator = None
