"""The implementation as it was before the speed work (commit 6fad0f8), kept for side-by-side timings.

``InitialPlanner`` is the former ``LatentMPPIPlanner.planning`` (``torch.no_grad``, bf16 through autocast);
``initial_behaviour()`` puts back, for its duration, the former encoding (``2T`` encodes per window, NCHW
images), the former ``frozen`` (detached copies that still required gradients, so the actor's backward
also computed the frozen networks' weight gradients) and the former Q-ensemble layers. The former updater
did not touch malloc: build ``MPAIL2Updater(loss, retain_memory=False)`` in a fresh process to time it.
"""
from __future__ import annotations

import contextlib
from contextlib import contextmanager
from unittest import mock

import torch
import torch.nn.functional as F
from tensordict import TensorDict, TensorDictBase
from torch import Tensor, nn

from torchrl_mpail2.functional import mppi_weights
from torchrl_mpail2.modules import value as value_module
from torchrl_mpail2.modules.encoder import validate_observations
from torchrl_mpail2.modules.policy import is_deterministic
from torchrl_mpail2.objectives import actor, base
from torchrl_mpail2.modules.value import HEADS_PER_ESTIMATE
from torchrl_mpail2.planners.mppi import LatentMPPIPlanner


class InitialPlanner(LatentMPPIPlanner):
    """``LatentMPPIPlanner`` with the former scoring and planning loop."""

    def score(self, z: Tensor, plans: Tensor, heads: Tensor) -> Tensor:
        m, cfg = self.components, self.cfg
        batch, num = plans.shape[:2]
        dynamics, reward = m.dynamics.module, m.reward.module
        h_now0, _ = reward.project(z)
        h_now = h_now0.unsqueeze(1).expand(batch, num, -1).reshape(batch * num, -1)
        zk = z.unsqueeze(1).expand(batch, num, -1).reshape(batch * num, -1)
        actions = plans.reshape(batch * num, self.horizon, self.action_dim)
        total = torch.zeros(batch * num, dtype=z.dtype, device=z.device)
        for k in range(self.horizon):
            zk = dynamics(zk, actions[:, k])
            h_now_next, h_next = reward.project(zk)
            total = total + self.gamma ** k * reward.from_projection(h_now, h_next).squeeze(-1).float()
            h_now = h_now_next
        last_action = m.policy.net(zk, deterministic=True)[0][:, 0]
        q = m.value.net(zk, last_action, heads=heads).squeeze(-1).float().mean(0)
        return (total + self.gamma ** self.horizon * q).view(batch, num)

    @torch.no_grad()
    def planning(self, td: TensorDictBase) -> Tensor:
        cfg, m = self.cfg, self.components
        validate_observations(td, m.encoder.observation_shapes)
        batch_shape = td.batch_size
        flat = td.reshape(-1) if len(batch_shape) != 1 else td
        num_envs = flat.shape[0]
        autocast = torch.autocast("cpu", dtype=torch.bfloat16) if cfg.bf16 else contextlib.nullcontext()
        with autocast:
            z = m.encoder.encode(flat)
            num_pi = cfg.num_policy_samples
            num_gauss = cfg.num_candidates - num_pi
            heads = torch.randperm(m.value.net.num_q, generator=self.generator)[:HEADS_PER_ESTIMATE].to(z.device)
            mean = self._initial_mean(flat, num_envs, z.float())
            std = torch.full_like(mean, cfg.std_max)
            if num_pi:
                pi_plans = m.policy.net(z.unsqueeze(1).expand(num_envs, num_pi, z.shape[-1]), generator=self.generator)[0].float()
                pi_returns = self.score(z, pi_plans, heads)
            for _ in range(cfg.iterations):
                noise = self._noise((num_envs, num_gauss, self.horizon, self.action_dim), mean)
                plans = (mean.unsqueeze(1) + std.unsqueeze(1) * noise).clamp(-1.0, 1.0)
                returns = self.score(z, plans, heads)
                if num_pi:
                    plans, returns = torch.cat([plans, pi_plans], 1), torch.cat([returns, pi_returns], 1)
                weights, elite_index = mppi_weights(returns, cfg.num_elites, cfg.temperature)
                elites = plans.gather(1, elite_index[..., None, None].expand(-1, -1, self.horizon, self.action_dim))
                w = weights[..., None, None]
                mean = (w * elites).sum(1)
                std = (w * (elites - mean.unsqueeze(1)).pow(2)).sum(1).sqrt().clamp(cfg.std_min, cfg.std_max)
        influence = (weights * (elite_index >= num_gauss)).sum(-1, keepdim=True)
        self._prev_mean = mean
        plan = mean if is_deterministic() else (mean + std * self._noise(mean.shape, mean)).clamp(-1.0, 1.0)
        td.set("plan", plan.reshape(*batch_shape, self.horizon, self.action_dim))
        td.set("policy_influence", influence.reshape(*batch_shape, 1))
        return plan[:, 0].reshape(*batch_shape, self.action_dim)


# ---- the former loss plumbing ------------------------------------------------------------------------
def _encode(self, td, prefix=()):
    return self.encoder_network.net(*(self.require(td, (*prefix, k)) for k in self.encoder_network.in_keys))


@torch.no_grad()
def _replay_latents(self, td):
    return self.encode(td), self.encode(td, self._prefix(self.tensor_keys.next))


@torch.no_grad()
def _expert_latents(self, td):
    prefix = self._prefix(self.tensor_keys.expert)
    return self.encode(td, prefix), self.encode(td, prefix + self._prefix(self.tensor_keys.next))


@contextmanager
def _frozen(*modules: nn.Module):
    contexts = [TensorDict.from_module(m).detach().to_module(m) for m in modules]
    try:
        for c in contexts:
            c.__enter__()
        yield
    finally:
        for c in reversed(contexts):
            c.__exit__(None, None, None)


def _stacked_linear(self, x, heads=None):
    w, b = self.weight, self.bias
    if heads is not None:
        w, b = w.index_select(0, heads), b.index_select(0, heads)
    num, in_dim, out_dim = w.shape
    if x.dim() == 2:
        y = x @ w.permute(1, 0, 2).reshape(in_dim, num * out_dim)
        return y.view(x.shape[0], num, out_dim).transpose(0, 1) + b.unsqueeze(1)
    return torch.baddbmm(b.unsqueeze(1), x, w)


def _stacked_layer_norm(self, x, heads=None):
    w, b = self.weight, self.bias
    if heads is not None:
        w, b = w.index_select(0, heads), b.index_select(0, heads)
    return F.layer_norm(x, x.shape[-1:]) * w.unsqueeze(1) + b.unsqueeze(1)


@contextmanager
def initial_behaviour():
    """Runs the losses and the Q-ensemble as they were before the speed work."""
    with contextlib.ExitStack() as stack:
        stack.enter_context(mock.patch.object(base.MPAIL2LossBase, "encode", _encode))
        stack.enter_context(mock.patch.object(base.MPAIL2LossBase, "replay_latents", _replay_latents))
        stack.enter_context(mock.patch.object(base.MPAIL2LossBase, "expert_latents", _expert_latents))
        stack.enter_context(mock.patch.object(actor, "frozen", _frozen))
        stack.enter_context(mock.patch.object(value_module.StackedLinear, "forward", _stacked_linear))
        stack.enter_context(mock.patch.object(value_module.StackedLayerNorm, "forward", _stacked_layer_norm))
        yield
