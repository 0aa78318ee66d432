r"""MPAIL2's inferred reward :math:`r_\theta(e_\omega(o_t), e_\omega(o_{t+1}))` as a TorchRL transform.

Any TorchRL algorithm (``SACLoss``, ``TD3Loss``, ``ClipPPOLoss``) can then train on the reward that MPAIL2 inferred
from observation-only demonstrations: append :class:`LearnedRewardTransform` to an env (it scores each step) or to
a replay buffer (it scores sampled transitions), and point the loss's ``reward`` key at its ``out_key``.
"""
from __future__ import annotations

from pathlib import Path

import torch
from tensordict import TensorDictBase
from torchrl.data import Composite, Unbounded
from torchrl.envs import Transform

from torchrl_mpail2.modules.encoder import ObservationEncoder, validate_observations
from torchrl_mpail2.modules.reward import TransitionReward

__all__ = ["LearnedRewardTransform"]


class LearnedRewardTransform(Transform):
    r"""Writes :math:`r_\theta(e_\omega(o_t), e_\omega(o_{t+1}))` (Eq. 3's critic) under ``out_key``.

    The reward is the one MPAIL2's planner maximises: the critic divided by its running scale where the run kept
    one (``loss.reward_scale_momentum``). Encoder and reward are frozen copies' references: their parameters are
    set to ``requires_grad=False``, so a downstream loss cannot move them.

    In an env (``TransformedEnv(env, transform)``) each step's ``("next", out_key)`` is scored from the step's
    observations and the next ones; ``out_key`` joins the env's reward spec (``[*B, 1]``), so it is never taken for
    an observation. On a replay buffer (``rb.append_transform(transform)``) or called on a tensordict of
    transitions ``[*B]`` holding the observation keys and ``("next", key)``, it writes ``("next", out_key)``.

    Args:
        encoder (ObservationEncoder): :math:`e_\omega`.
        reward (TransitionReward): :math:`r_\theta`.

    Keyword Args:
        out_key (str): where the reward goes (default ``"learned_reward"``, beside the env's own reward, which is
            never overwritten unless you name it here).

    Examples:
        >>> from torchrl.envs import TransformedEnv
        >>> from torchrl_mpail2.config import ModelConfig
        >>> from torchrl_mpail2.envs import make_env
        >>> from torchrl_mpail2.modules import make_mpail2_modules
        >>> env = make_env("point_mass")
        >>> m = make_mpail2_modules(env.observation_spec, env.action_spec,
        ...                         ModelConfig(latent_dim=8, hidden_dims=(16,), coder_dim=16, vector_coder_hidden=16))
        >>> env = TransformedEnv(env, LearnedRewardTransform(m.encoder, m.reward))
        >>> env.rollout(5)["next", "learned_reward"].shape
        torch.Size([5, 1])
    """

    def __init__(self, encoder: ObservationEncoder, reward: TransitionReward, *, out_key: str = "learned_reward"):
        super().__init__(in_keys=list(encoder.in_keys), out_keys=[out_key])
        if not isinstance(encoder, ObservationEncoder) or not isinstance(reward, TransitionReward):
            raise TypeError("LearnedRewardTransform needs an ObservationEncoder and a TransitionReward, got "
                            f"{type(encoder).__name__} and {type(reward).__name__}")
        self.encoder, self.reward = encoder, reward
        for p in (*encoder.parameters(), *reward.parameters()):
            p.requires_grad_(False)
        self.out_key = out_key

    @classmethod
    def from_checkpoint(cls, path: str | Path, env=None, *, out_key: str = "learned_reward") -> "LearnedRewardTransform":
        """The encoder and reward of an MPAIL2 training checkpoint (see :meth:`MPAIL2Agent.from_checkpoint`)."""
        from torchrl_mpail2.agents.mpail2 import MPAIL2Agent

        modules = MPAIL2Agent.from_checkpoint(path, env).modules
        return cls(modules.encoder, modules.reward, out_key=out_key)

    @torch.no_grad()
    def score(self, observations: TensorDictBase, next_observations: TensorDictBase) -> torch.Tensor:
        """``r [*B, 1]`` of the transitions from ``observations`` to ``next_observations`` (each holding the keys)."""
        shapes = self.encoder.net.shapes
        validate_observations(observations, shapes, where="LearnedRewardTransform: observation")
        validate_observations(next_observations, shapes, where="LearnedRewardTransform: next observation")
        z, z_next = self.encoder.encode(observations), self.encoder.encode(next_observations)
        return self.reward.module(z, z_next)

    def _step(self, tensordict: TensorDictBase, next_tensordict: TensorDictBase) -> TensorDictBase:
        next_tensordict.set(self.out_key, self.score(tensordict, next_tensordict))
        return next_tensordict

    def _reset(self, tensordict: TensorDictBase, tensordict_reset: TensorDictBase) -> TensorDictBase:
        return tensordict_reset  # a reward belongs to a step, not to a reset

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if "next" not in tensordict.keys():
            raise KeyError("LearnedRewardTransform scores transitions: the tensordict needs a 'next' entry with the "
                           f"next observations {list(self.in_keys)}; present: {list(tensordict.keys())}")
        tensordict.set(("next", self.out_key), self.score(tensordict, tensordict.get("next")))
        return tensordict

    def transform_reward_spec(self, reward_spec: Composite) -> Composite:
        reward_spec[self.out_key] = Unbounded(shape=(*reward_spec.shape, 1), device=reward_spec.device)
        return reward_spec
