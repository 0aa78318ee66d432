"""Builds the five MPAIL2 networks from environment specs and a :class:`ModelConfig`."""
from __future__ import annotations

from collections.abc import Mapping, Sequence

import torch
from torch import nn

from torchrl_mpail2.config import ModelConfig
from torchrl_mpail2.envs.keys import observation_keys_of
from torchrl_mpail2.modules.dynamics import LatentDynamics
from torchrl_mpail2.modules.encoder import ObservationEncoder
from torchrl_mpail2.modules.policy import MultiStepPolicy
from torchrl_mpail2.modules.reward import TransitionReward
from torchrl_mpail2.modules.value import QEnsemble



def observation_shapes_from_spec(observation_spec, keys: Sequence[str] | None = None) -> dict[str, tuple[int, ...]]:
    """Per-key shapes of the observations in a torchrl ``Composite`` spec.

    Args:
        observation_spec (Composite): the environment's ``observation_spec``.
        keys (Sequence[str], optional): keys to use; by default those of
            :func:`~torchrl_mpail2.envs.keys.observation_keys_of`.
    """
    batch_dims = len(observation_spec.shape)
    shapes = {key: tuple(observation_spec[key].shape[batch_dims:]) for key in observation_keys_of(observation_spec, keys)}
    if not shapes:
        raise ValueError("no observation keys found in the observation spec")
    return shapes


class MPAIL2Modules(nn.Module):
    r"""The five learned components of MPAIL2 in one container.

    Attributes:
        encoder (ObservationEncoder): :math:`e_\omega`.
        dynamics (LatentDynamics): :math:`f_\psi`.
        reward (TransitionReward): :math:`r_\theta`.
        value (QEnsemble): :math:`Q_\zeta`.
        policy (MultiStepPolicy): :math:`\pi_\phi`.
    """

    def __init__(self, observation_shapes: Mapping[str, Sequence[int]], action_dim: int, cfg: ModelConfig | None = None):
        super().__init__()
        cfg = cfg or ModelConfig()
        self.cfg, self.action_dim = cfg, action_dim
        self.encoder = ObservationEncoder(
            observation_shapes, cfg.latent_dim, cfg.hidden_dims, vector_coder_hidden=cfg.vector_coder_hidden,
            coder_dim=cfg.coder_dim, cnn_channels=cfg.cnn_channels, fuse_latent=cfg.fuse_latent, obs_clip=cfg.obs_clip)
        latent_index = None
        if cfg.reward_latent_keys is not None:
            slices = self.encoder.net.latent_slices
            missing = [k for k in cfg.reward_latent_keys if k not in slices]
            if missing:
                raise KeyError(f"reward_latent_keys {missing} are not observation keys {list(slices)}")
            latent_index = [i for k in cfg.reward_latent_keys for i in range(slices[k].start, slices[k].stop)]
        self.dynamics = LatentDynamics(cfg.latent_dim, action_dim, cfg.hidden_dims)
        self.reward = TransitionReward(cfg.latent_dim, cfg.hidden_dims, latent_index)
        self.value = QEnsemble(cfg.latent_dim, action_dim, cfg.hidden_dims, cfg.num_q)
        self.policy = MultiStepPolicy(cfg.latent_dim, action_dim, cfg.horizon, cfg.hidden_dims, cfg.log_std_min, cfg.log_std_max)

    @property
    def horizon(self) -> int:
        return self.cfg.horizon

    @property
    def observation_shapes(self) -> dict[str, tuple[int, ...]]:
        return self.encoder.observation_shapes


def make_mpail2_modules(observation_spec, action_spec, cfg: ModelConfig | None = None,
                        observation_keys: Sequence[str] | None = None) -> MPAIL2Modules:
    """Builds :class:`MPAIL2Modules` from an environment's specs.

    Args:
        observation_spec (Composite): ``env.observation_spec``.
        action_spec (TensorSpec): ``env.action_spec``; a flat ``[A]`` action bounded to ``[-1, 1]``.
        cfg (ModelConfig, optional): network sizes (paper defaults).
        observation_keys (Sequence[str], optional): observation keys to encode (default: all observations).
    """
    shapes = observation_shapes_from_spec(observation_spec, observation_keys)
    return MPAIL2Modules(shapes, check_action_spec(action_spec), cfg)


def check_action_spec(action_spec, action_dim: int | None = None) -> int:
    """Checks that ``action_spec`` is a flat ``[A]`` action bounded to ``[-1, 1]`` (and ``A == action_dim`` if given).

    Returns:
        int: ``A``.

    Raises:
        ValueError: naming the spec's shape or bounds.
    """
    batch_dims = len(action_spec.shape) - 1
    action_shape = tuple(action_spec.shape[batch_dims:])
    if len(action_shape) != 1:
        raise ValueError(f"MPAIL2 needs a flat action [A]; the action spec has shape {list(action_spec.shape)}")
    if action_dim is not None and action_shape[0] != action_dim:
        raise ValueError(f"the action spec has {action_shape[0]} dimensions (shape {list(action_spec.shape)}), "
                         f"the networks act in {action_dim}")
    space = getattr(action_spec, "space", None)
    low, high = getattr(space, "low", None), getattr(space, "high", None)
    if low is None or not (torch.allclose(low.float(), torch.tensor(-1.0)) and torch.allclose(high.float(), torch.tensor(1.0))):
        raise ValueError("MPAIL2 plans in [-1, 1]: wrap the environment so that its actions are bounded to [-1, 1] "
                         f"(got low={None if low is None else low.tolist()}, high={None if high is None else high.tolist()})")
    return action_shape[0]
