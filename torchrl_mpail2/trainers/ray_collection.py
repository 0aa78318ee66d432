"""Collecting on Ray with TorchRL's :class:`~torchrl.collectors.distributed.RayCollector`.

Each Ray worker holds a copy of the acting module and its own environments; after an update the learner sends
the networks' weights through Ray's object store (:class:`RayNetworkUpdater`) and waits until every worker has
loaded them, so the next batch is collected with the new weights.

The planner acts with the learner's networks but does not own them (:class:`~torchrl_mpail2.planners.
LatentMPPIPlanner` keeps them outside its parameters), so a copy of the planner alone would carry no weights to
update. :class:`NetworkOwningActor` wraps the acting module together with the networks it uses: one pickled copy
then holds both, the copy's planner acts with the copy's networks, and ``TensorDict.from_module`` of the wrapper
names every parameter and buffer the workers need (the encoder's observation normalisation included, and the
:class:`~torchrl_mpail2.planners.policy_actor.WarmupSwitch`'s random-action switch when the wrapped actor is
``agent.actor``).

Two entry points:

- :func:`make_ray_collector`: a synchronous ``RayCollector`` of fixed-size batches ``[workers, T]`` for your own
  loop; trajectory ids are made unique across workers (:func:`worker_unique_traj_ids`), so the flattened batch
  can go into a replay buffer sampled by trajectory.
- :class:`RayEpisodeCollector`: what the trainer uses with ``train.collector=ray``: each batch holds complete
  episodes from every worker, padded to the longest, shaped like :func:`~torchrl_mpail2.trainers.collection.
  make_collector`'s batches. The worker processes' acting statistics (``act_s``, the planner's elite return and
  plan std) stay in the workers and are not logged; the trainer records the whole wait for a batch as ``collect``.

Why the weights go through the object store. TorchRL 0.14's default Ray weight sync (``RayWeightSyncScheme``) sends
them over a gloo process group on a TCP store of its own, which every worker must reach on a port Ray does not
manage; on these machines it once timed out before the first update (``DistStoreError``). Checked again with ray 2.60
(one machine, 2 workers, the ``point_mass`` preset's actor) it delivered the weights, in about 33 ms per update
against about 66 ms for :class:`RayNetworkUpdater`, which waits for each worker in turn. ``ray.put`` / ``ray.get``
need nothing beyond Ray's own connections, so this path stays, although the ``WeightUpdaterBase`` it subclasses is
deprecated upstream in favour of ``WeightSyncScheme`` (``torchrl.weight_update``); when that base is removed, the same
two calls move into a scheme.

The cluster recipe (``ray start`` on each machine, the training command, what to install where) is in
``docs/ray.md``.
"""
from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterator

import torch
from tensordict import TensorDict, TensorDictBase, pad
from tensordict.nn import TensorDictModuleBase
from torch import nn
from torchrl.collectors.weight_update import WeightUpdaterBase
from torchrl.envs import Transform

from torchrl_mpail2.data import TRAJ_KEY
from torchrl_mpail2.trainers.collection import make_collector_env

__all__ = ["NetworkOwningActor", "RayEpisodeCollector", "RayNetworkUpdater", "make_ray_collector",
           "ray_init_kwargs", "worker_unique_traj_ids"]

#: The extra that installs Ray.
RAY_EXTRA = "torchrl-mpail2[ray]"


def require_ray(purpose: str = "Ray collection"):
    """The ``ray`` module, or an ImportError naming the extra that installs it."""
    try:
        import ray
    except ImportError as err:
        raise ImportError(f"{purpose} needs ray: pip install '{RAY_EXTRA}'") from err
    return ray


def ray_init_kwargs(address: str | None, workers: int) -> dict:
    """``ray.init`` arguments: a local Ray of ``workers`` CPUs for this process (``address`` None), or the cluster
    at ``address`` (``"auto"``: the one ``ray start`` runs on this machine; ``"HOST:6379"``)."""
    if address is None:
        return {"num_cpus": workers, "include_dashboard": False}
    return {"address": address}


class NetworkOwningActor(TensorDictModuleBase):
    """An acting module (the planner or the policy actor) together with the networks it acts with.

    Args:
        actor (TensorDictModuleBase): what acts, e.g. ``agent.policy`` (or ``agent.actor`` to carry the warm-up
            switch as well).
        networks (nn.Module): the networks ``actor`` uses, e.g. ``agent.modules``.
    """

    def __init__(self, actor: TensorDictModuleBase, networks: nn.Module):
        super().__init__()
        self.networks = networks
        self.actor = actor
        self.in_keys, self.out_keys = list(actor.in_keys), list(actor.out_keys)

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        return self.actor(tensordict)


class RayNetworkUpdater(WeightUpdaterBase):
    """Puts the weights in Ray's object store once per update and has every remote collector load them.

    Args:
        weights (TensorDictBase): ``TensorDict.from_module`` of the learner's acting module (it shares the live
            parameters and buffers, so each update sends their current values).
    """

    def __init__(self, weights: TensorDictBase):
        super().__init__()
        self.weights = weights

    def _get_server_weights(self):
        return require_ray().put(self.weights.data)

    def _maybe_map_weights(self, server_weights):
        return server_weights

    def all_worker_ids(self) -> list[int]:
        return list(range(len(self.collector.remote_collectors)))

    def _sync_weights_with_worker(self, *, worker_id: int | None = None, server_weights=None) -> None:
        remote = self.collector.remote_collectors[worker_id]
        require_ray().get(remote.update_policy_weights_.remote(server_weights))


def worker_unique_traj_ids(batch: TensorDictBase) -> TensorDictBase:
    """Relabels the trajectory ids of a batch stacked over ``W`` workers (dimension 0) as ``id * W + worker``.

    Each worker's collector counts its trajectories from 0, so the workers' ids collide; after this a replay
    buffer sampled by :data:`~torchrl_mpail2.data.TRAJ_KEY` (``SliceSampler(traj_key=...)``) keeps the workers'
    episodes apart. Negative ids (TorchRL's mark of unused steps) stay as they are.

    Examples:
        >>> ids = torch.tensor([[0, 0, 1], [0, 1, 1]])
        >>> worker_unique_traj_ids(TensorDict({TRAJ_KEY: ids}, [2, 3]))[TRAJ_KEY]
        tensor([[0, 0, 2],
                [1, 3, 3]])
    """
    ids = batch.get(TRAJ_KEY)
    workers = ids.shape[0]
    worker = torch.arange(workers, device=ids.device).reshape(workers, *([1] * (ids.ndim - 1)))
    batch.set(TRAJ_KEY, torch.where(ids >= 0, ids * workers + worker, ids))
    return batch


def make_ray_collector(env_fn: Callable, actor: TensorDictModuleBase, networks: nn.Module, *, frames_per_batch: int,
                       total_frames: int = -1, num_collectors: int = 2, ray_init_config: dict | None = None,
                       **collector_kwargs):
    """A synchronous :class:`~torchrl.collectors.distributed.RayCollector` of ``num_collectors`` workers, each
    running a :class:`~torchrl.collectors.Collector` of ``env_fn()`` with a copy of ``actor`` and ``networks``.

    Its batches are shaped ``[num_collectors, frames_per_batch // num_collectors]``, with trajectory ids unique
    across workers (:func:`worker_unique_traj_ids`). Call ``collector.update_policy_weights_()`` after each
    update: the workers then hold the learner's weights.

    Args:
        env_fn (Callable): builds one environment (importable on every Ray node).
        actor (TensorDictModuleBase): the acting module, e.g. ``agent.policy`` (its warm start then lives in each
            worker; append ``agent.planner.make_tensordict_primer()`` in ``env_fn`` to keep it in the data).
        networks (nn.Module): the networks ``actor`` uses, e.g. ``agent.modules``.

    Keyword Args:
        frames_per_batch (int): frames of one batch, over all workers.
        total_frames (int): frames in all (``-1``: endless).
        num_collectors (int): Ray workers.
        ray_init_config (dict, optional): ``ray.init`` keyword arguments (``{"address": "auto"}`` on a cluster;
            default: a local Ray with ``num_cpus=num_collectors``).
        **collector_kwargs: passed to each worker's ``Collector``.

    Returns:
        The collector; ``collector.shutdown()`` stops its workers.
    """
    require_ray()
    from torchrl.collectors.distributed import RayCollector

    if num_collectors < 1:
        raise ValueError(f"num_collectors must be >= 1, got {num_collectors}")
    owning = NetworkOwningActor(actor, networks)
    config = ray_init_kwargs(None, num_collectors) if ray_init_config is None else ray_init_config
    return RayCollector([env_fn] * num_collectors, policy=owning, collector_class="single",
                        collector_kwargs=collector_kwargs or None, frames_per_batch=frames_per_batch,
                        # RayCollector's iterator ends at total_frames as given: -1 would yield nothing
                        total_frames=math.inf if total_frames < 0 else total_frames, sync=True, ray_init_config=config,
                        postproc=worker_unique_traj_ids,
                        weight_updater=RayNetworkUpdater(TensorDict.from_module(owning)))


def seeded_worker_env(env_fn: Callable, first_seed: int, num_envs: int, state: Transform | None):
    """A Ray worker's environments (:func:`~torchrl_mpail2.trainers.collection.make_collector_env`, seeded
    ``first_seed + i``); it also seeds the worker process's torch generator with ``first_seed``, from which the
    warm-up's random actions and the planner's noise are drawn, so that workers draw apart and runs repeat."""
    torch.manual_seed(first_seed)
    return make_collector_env(env_fn, first_seed, num_envs, state=state)


def stack_episode_batches(batches: list[TensorDictBase]) -> TensorDictBase:
    """Padded ``[N_w, T_w]`` episode batches of ``W`` workers as one ``[sum N_w, max T_w]`` batch (the padding's
    ``("collector", "mask")`` is False), trajectory ids made unique across workers as ``id * W + worker``."""
    length = max(batch.shape[1] for batch in batches)
    workers = len(batches)
    out = []
    for worker, batch in enumerate(batches):
        batch = pad(batch, [0, 0, 0, length - batch.shape[1]]) if batch.shape[1] < length else batch
        batch.set(TRAJ_KEY, batch.get(TRAJ_KEY) * workers + worker)
        out.append(batch)
    return torch.cat(out, 0)


class RayEpisodeCollector:
    """Complete episodes from ``workers`` Ray workers, one batch of ``num_envs`` episodes from each at a time.

    Worker ``w`` runs a :class:`~torchrl.collectors.Collector` of ``num_envs`` complete episodes at a time (as
    :func:`~torchrl_mpail2.trainers.collection.make_collector`) over its environments seeded
    ``first_seed + w * num_envs + i`` (:func:`seeded_worker_env`), with a copy of ``actor`` and ``networks``.
    Iterating yields ``[workers * num_envs, T]`` batches padded to the longest episode, with
    ``("collector", "mask")``, that :func:`~torchrl_mpail2.trainers.collection.split_episodes` cuts; episodes of
    different lengths (early terminations) are padded, not stacked. Before each batch every worker loads the
    learner's current weights (:class:`RayNetworkUpdater`), so a batch is collected with the weights of the last
    update and the warm-up switch as the learner set it.

    The workers wait while the learner updates, and a batch waits for its slowest worker (as ``num_envs``
    environments do in one process), so the run's order of episodes and its seeds repeat.

    Args:
        env_fn (Callable): builds one environment from ``seed=...`` (importable on every Ray node: a
            module-level function or a ``functools.partial`` of one).
        actor (TensorDictModuleBase): what acts, e.g. ``agent.actor`` (the warm-up switch around the planner).
        networks (nn.Module): the networks ``actor`` uses, e.g. ``agent.modules``.

    Keyword Args:
        first_seed (int): seed of worker 0's first environment.
        workers (int): Ray workers (one CPU each).
        num_envs (int): environments per worker, stepped together (a ``SerialEnv`` above 1).
        state (Transform, optional): appended to each worker's env, e.g. the planner's
            :meth:`~torchrl_mpail2.planners.LatentMPPIPlanner.make_tensordict_primer` (each env's warm start).
        ray_init_config (dict, optional): ``ray.init`` keyword arguments when Ray is not running in this process
            yet (default: :func:`ray_init_kwargs` of a local Ray with ``workers`` CPUs).
    """

    def __init__(self, env_fn: Callable, actor: TensorDictModuleBase, networks: nn.Module, *, first_seed: int,
                 workers: int = 2, num_envs: int = 1, state: Transform | None = None,
                 ray_init_config: dict | None = None):
        require_ray()
        from torchrl.collectors.distributed import RayCollector

        if workers < 1 or num_envs < 1:
            raise ValueError(f"workers and num_envs must be >= 1, got {workers} and {num_envs}")
        owning = NetworkOwningActor(actor, networks)
        env_makers = [functools.partial(seeded_worker_env, env_fn, first_seed + w * num_envs, num_envs, state)
                      for w in range(workers)]
        init = ray_init_kwargs(None, workers) if ray_init_config is None else ray_init_config
        self.collector = RayCollector(
            # one CPU each and no GPU share (TorchRL's default takes a fifth of a GPU wherever the learner sees one)
            env_makers, policy=owning, collector_class="single", frames_per_batch=workers, sync=True,
            remote_configs={"num_cpus": 1},
            collector_kwargs={"trajs_per_batch": num_envs, "traj_format": "padded"}, ray_init_config=init,
            weight_updater=RayNetworkUpdater(TensorDict.from_module(owning)))

    def __iter__(self) -> Iterator[TensorDictBase]:
        while True:
            self.collector.update_policy_weights_()
            yield stack_episode_batches(self.collector.map_fn("next"))

    def shutdown(self, *args, **kwargs) -> None:
        """Stops the workers (and the local Ray this collector started, if it did)."""
        self.collector.shutdown()
