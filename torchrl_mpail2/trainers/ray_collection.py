"""Collecting on Ray with TorchRL's :class:`~torchrl.collectors.distributed.RayCollector`.

Each Ray worker holds a copy of the acting module and its own environments; after an update the learner sends
the networks' weights through Ray's object store (:class:`RayNetworkUpdater`) and waits until every worker has
loaded them, so the next batch is collected with the new weights.

The planner acts with the learner's networks but does not own them (:class:`~torchrl_mpail2.planners.
LatentMPPIPlanner` keeps them outside its parameters), so a copy of the planner alone would carry no weights to
update. :class:`NetworkOwningActor` wraps the acting module together with the networks it uses: one pickled copy
then holds both, the copy's planner acts with the copy's networks, and ``TensorDict.from_module`` of the wrapper
names every parameter and buffer the workers need (the encoder's observation normalisation included).

TorchRL's default Ray weight sync (``RayWeightSyncScheme``) opens a gloo process group over a TCP store; on these
machines it timed out before the first update (``DistStoreError``), so the object store is used instead.

Recipe for a cluster (``ray start --head`` on one machine, ``ray start --address HEAD:6379`` on the others):
``make_ray_collector(env_fn, agent.policy, agent.modules, num_collectors=8, frames_per_batch=...,
ray_init_config={"address": "auto"})``; ``env_fn`` must be importable on every node (a module-level function or
a ``functools.partial`` of one), and this package installed there.
"""
from __future__ import annotations

from collections.abc import Callable

from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModuleBase
from torch import nn
from torchrl.collectors.weight_update import WeightUpdaterBase

__all__ = ["NetworkOwningActor", "RayNetworkUpdater", "make_ray_collector"]


def _ray():
    try:
        import ray
    except ImportError as err:  # pragma: no cover - depends on the installation
        raise ImportError("Ray collection needs ray: pip install 'torchrl-mpail2[ray]'") from err
    return ray


class NetworkOwningActor(TensorDictModuleBase):
    """An acting module (the planner or the policy actor) together with the networks it acts with.

    Args:
        actor (TensorDictModuleBase): what acts, e.g. ``agent.policy``.
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
            parameters, so each update sends their current values).
    """

    def __init__(self, weights: TensorDictBase):
        super().__init__()
        self.weights = weights

    def _get_server_weights(self):
        return _ray().put(self.weights.data)

    def _maybe_map_weights(self, server_weights):
        return server_weights

    def all_worker_ids(self) -> list[int]:
        return list(range(len(self.collector.remote_collectors)))

    def _sync_weights_with_worker(self, *, worker_id: int | None = None, server_weights=None) -> None:
        remote = self.collector.remote_collectors[worker_id]
        _ray().get(remote.update_policy_weights_.remote(server_weights))


def make_ray_collector(env_fn: Callable, actor: TensorDictModuleBase, networks: nn.Module, *, frames_per_batch: int,
                       total_frames: int = -1, num_collectors: int = 2, ray_init_config: dict | None = None,
                       **collector_kwargs):
    """A synchronous :class:`~torchrl.collectors.distributed.RayCollector` of ``num_collectors`` workers, each
    running a :class:`~torchrl.collectors.Collector` of ``env_fn()`` with a copy of ``actor`` and ``networks``.

    Call ``collector.update_policy_weights_()`` after each update: the workers then hold the learner's weights.

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
    _ray()
    from torchrl.collectors.distributed import RayCollector

    if num_collectors < 1:
        raise ValueError(f"num_collectors must be >= 1, got {num_collectors}")
    owning = NetworkOwningActor(actor, networks)
    config = {"num_cpus": num_collectors, "include_dashboard": False} if ray_init_config is None else ray_init_config
    return RayCollector([env_fn] * num_collectors, policy=owning, collector_class="single",
                        collector_kwargs=collector_kwargs or None, frames_per_batch=frames_per_batch,
                        total_frames=total_frames, sync=True, ray_init_config=config,
                        weight_updater=RayNetworkUpdater(TensorDict.from_module(owning)))
