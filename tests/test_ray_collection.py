"""Ray collection: a worker's copy of the actor acts with its own copy of the networks, and receives the learner's
weights after each update."""
from __future__ import annotations

import functools
import pickle

import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_mpail2.agents import MPAIL2Agent
from torchrl_mpail2.config import ModelConfig, PlannerConfig
from torchrl_mpail2.envs import make_env
from torchrl_mpail2.trainers.ray_collection import NetworkOwningActor, make_ray_collector

TINY_MODEL = ModelConfig(latent_dim=8, hidden_dims=(16,), coder_dim=16, vector_coder_hidden=16, horizon=3)
TINY_PLANNER = PlannerConfig(num_candidates=16, num_elites=4, iterations=2)


#: Ray workers unpickle the env builder: it must live in an importable module, not in this test file.
point_mass = functools.partial(make_env, "point_mass")


def _agent():
    env = point_mass()
    return MPAIL2Agent(env.observation_spec, env.action_spec, TINY_MODEL, planner=TINY_PLANNER), env


def _act(actor, td, seed=0):
    actor.actor.generator = torch.Generator().manual_seed(seed)
    actor.actor.reset()
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        return actor(td.clone())["action"]


def test_a_pickled_actor_plans_with_its_own_copy_of_the_networks():
    agent, env = _agent()
    owning = NetworkOwningActor(agent.policy, agent.modules)
    weights = TensorDict.from_module(owning)
    shared = {p.data_ptr() for p in weights.values(True, True)}
    assert all(p.data_ptr() in shared for p in agent.modules.parameters()), "every network parameter is sent"

    copy = pickle.loads(pickle.dumps(owning))
    assert copy.actor.components is copy.networks  # the copy's planner uses the copy's networks
    td = env.reset()
    assert torch.equal(_act(owning, td), _act(copy, td))
    with torch.no_grad():
        for p in copy.networks.parameters():
            p.mul_(3.0)
    assert not torch.equal(_act(owning, td), _act(copy, td)), "the copy acts with its own weights"
    TensorDict.from_module(owning).data.to_module(copy)  # what a worker does with received weights
    assert torch.equal(_act(owning, td), _act(copy, td))


@pytest.mark.slow
def test_ray_workers_collect_and_receive_the_learners_weights():
    ray = pytest.importorskip("ray")
    agent, _ = _agent()
    collector = make_ray_collector(point_mass, agent.policy, agent.modules, frames_per_batch=20, total_frames=60,
                                   ray_init_config={"num_cpus": 2, "include_dashboard": False,
                                                    "log_to_driver": False})
    owning_state = NetworkOwningActor(agent.policy, agent.modules).state_dict

    def largest_difference(worker):
        remote = ray.get(collector.remote_collectors[worker].state_dict.remote())["policy_state_dict"]
        local = owning_state()
        return max((remote[k] - v).abs().max().item() for k, v in local.items()
                   if isinstance(v, torch.Tensor) and v.is_floating_point())

    try:
        batches = 0
        for batch in collector:
            assert batch.numel() == 20 and torch.isfinite(batch["action"]).all()
            batches += 1
            with torch.no_grad():
                for p in agent.modules.parameters():
                    p.add_(0.5)  # stands in for an update
            assert largest_difference(0) == pytest.approx(0.5), "the workers still hold the old weights"
            collector.update_policy_weights_()
            assert largest_difference(0) == 0.0 and largest_difference(1) == 0.0
        assert batches == 3
    finally:
        collector.shutdown()
        ray.shutdown()
