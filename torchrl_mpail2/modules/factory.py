"""Builds the five MPAIL2 networks from environment specs and a :class:`ModelConfig`."""
from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import torch
from tensordict import TensorDictBase
from torch import Tensor, nn

from torchrl_mpail2.config import ModelConfig
from torchrl_mpail2.envs.keys import observation_keys_of
from torchrl_mpail2.modules.dynamics import LatentDynamics
from torchrl_mpail2.modules.encoder import ObservationEncoder
from torchrl_mpail2.modules.policy import MultiStepPolicy
from torchrl_mpail2.modules.reward import TransitionReward
from torchrl_mpail2.modules.value import QEnsemble, draw_heads
from torchrl_mpail2.modules.world_model import chain_rewards, rollout_latents

if TYPE_CHECKING:  # the modules only read the demonstrations; they do not depend on the data package
    from torchrl_mpail2.data import Demonstrations


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

    Its verbs, as TD-MPC2's world model has them, are what planners, returns and diagnostics call: :meth:`encode`,
    :meth:`next`, :meth:`imagine`, :meth:`rewards`, :meth:`q`, :meth:`pi` and :meth:`draw_heads`. The losses keep
    the single networks (TorchRL's functional parameters, target copies), and walk latents forward with the same
    functions (:mod:`~torchrl_mpail2.modules.world_model`).
    """

    def __init__(self, observation_shapes: Mapping[str, Sequence[int]], action_dim: int, cfg: ModelConfig | None = None):
        super().__init__()
        cfg = cfg or ModelConfig()
        self.cfg, self.action_dim = cfg, action_dim
        self.encoder = ObservationEncoder(
            observation_shapes, cfg.latent_dim, cfg.hidden_dims, vector_coder_hidden=cfg.vector_coder_hidden,
            coder_dim=cfg.coder_dim, cnn_channels=cfg.cnn_channels, fuse_latent=cfg.fuse_latent, obs_clip=cfg.obs_clip,
            cnn_init=cfg.cnn_init, image_head=cfg.image_head, keypoints=cfg.keypoints)
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

    def demo_keys_missing(self, demos: Demonstrations) -> list[str]:
        """The encoder's observation keys that ``demos`` lack, checked against what the reward reads.

        Demonstrations may lack keys (the paper's video-only setting: the table camera alone) only when the latent is
        compartmentalised and the reward reads only the blocks of keys they hold (``ModelConfig.reward_latent_keys``):
        the expert's latents are then those blocks, and nothing else reads them.

        Raises:
            KeyError: demos lack keys the reward would read (the message names the keys, both key sets and the
                settings that allow partial demonstrations).
        """
        missing = [key for key in self.encoder.observation_shapes if key not in demos.observation_keys]
        read = self.cfg.reward_latent_keys
        if missing and (self.cfg.fuse_latent or read is None or any(key in missing for key in read)):
            needed = [key for key in (read or self.encoder.observation_shapes) if key in missing]
            raise KeyError(
                f"the reward reads observation keys {needed} that the demonstrations ({demos.env_id}, keys "
                f"{demos.observation_keys}) do not hold; demonstrations may lack encoder keys only with "
                f"model.fuse_latent=false and model.reward_latent_keys among their keys")
        return missing

    def normalize_from_demos(self, demos: Demonstrations) -> MPAIL2Modules:
        """Sets the encoder's fixed observation normalisation from demonstration statistics.

        Each vector key is normalised by the per-dimension mean and std of the demonstrations'
        observations (:meth:`~torchrl_mpail2.data.Demonstrations.observation_stats`); image keys per pixel and
        channel likewise with ``image_norm="demos"`` (else centred). Keys the demonstrations lack are left as they
        are (see :meth:`demo_keys_missing`). This is what :func:`make_mpail2_modules` does when given ``demos``.

        Args:
            demos (Demonstrations): holding the encoder's observation keys (all of them, or those the reward reads
                in the compartmentalised setting), with the same shapes.

        Returns:
            MPAIL2Modules: ``self``.

        Raises:
            KeyError: see :meth:`demo_keys_missing`.
            ValueError: a key has another shape in the demonstrations (the message names the key and both shapes).
        """
        missing = self.demo_keys_missing(demos)
        shapes = {key: shape for key, shape in self.encoder.observation_shapes.items() if key not in missing}
        for key, shape in shapes.items():
            stored = tuple(demos.observations.get(key).shape[1:])
            if stored != shape:
                raise ValueError(f"observation {key!r} has shape {list(stored)} in the demonstrations "
                                 f"({demos.env_id}) but {list(shape)} in the encoder")
        net = self.encoder.net
        net.set_normalization(demos.observation_stats([key for key in net.vector_keys if key in shapes]))
        if self.cfg.image_norm == "demos":
            images = {key: demos.observations.get(key).float() / 255.0 for key in shapes if key not in net.vector_keys}
            net.set_normalization({key: (x.mean(0), x.std(0, unbiased=False)) for key, x in images.items()})
        return self

    # ---- the world model's verbs: what planners, returns and diagnostics call ---------------------------------
    def encode(self, tensordict: TensorDictBase) -> Tensor:
        r""":math:`z = e_\omega(o)` of the observations in ``tensordict`` -> ``[*B, Z]``."""
        return self.encoder.encode(tensordict)

    def next(self, z: Tensor, a: Tensor) -> Tensor:
        r""":math:`z' = f_\psi(z, a)`: ``[*B, Z]``, ``[*B, A]`` -> ``[*B, Z]``."""
        return self.dynamics.module(z, a)

    def imagine(self, z0: Tensor, plan: Tensor) -> Tensor:
        """The latents a plan reaches: ``z0 [M, Z]``, ``plan [M, H, A]`` -> ``[H + 1, M, Z]`` (``z0`` first)."""
        return rollout_latents(self.dynamics.module, z0, plan)

    def rewards(self, latents: Tensor) -> Tensor:
        r""":math:`r_\theta(z_k, z_{k+1})` along a latent path ``[T + 1, *B, Z]`` -> ``[T, *B]``."""
        return chain_rewards(self.reward.module, latents)

    def q(self, z: Tensor, a: Tensor, heads: Tensor | None = None) -> Tensor:
        r""":math:`Q_\zeta(z, a)` of the ensemble's heads (``heads``: indices, default all) -> ``[E, *B]``."""
        return self.value.net(z, a, heads=heads).squeeze(-1)

    def pi(self, z: Tensor, deterministic: bool = False, generator: torch.Generator | None = None
           ) -> tuple[Tensor, Tensor]:
        r"""A plan of :math:`\pi_\phi(\cdot | z)`: ``z [*B, Z]`` -> ``(plan [*B, H, A], log_prob [*B])``."""
        return self.policy.net(z, deterministic=deterministic, generator=generator)

    def draw_heads(self, device: torch.device | str, generator: torch.Generator | None = None) -> Tensor:
        """Two distinct Q heads for one estimate (:func:`~torchrl_mpail2.modules.value.draw_heads`)."""
        return draw_heads(self.value.net.num_q, device, generator)

    @property
    def horizon(self) -> int:
        return self.cfg.horizon

    @property
    def observation_shapes(self) -> dict[str, tuple[int, ...]]:
        return self.encoder.observation_shapes


def make_mpail2_modules(observation_spec, action_spec, cfg: ModelConfig | None = None,
                        observation_keys: Sequence[str] | None = None, *,
                        demos: Demonstrations | None = None) -> MPAIL2Modules:
    """Builds :class:`MPAIL2Modules` from an environment's specs.

    Args:
        observation_spec (Composite): ``env.observation_spec``.
        action_spec (TensorSpec): ``env.action_spec``; a flat ``[A]`` action bounded to ``[-1, 1]``.
        cfg (ModelConfig, optional): network sizes (paper defaults).
        observation_keys (Sequence[str], optional): observation keys to encode (default: the keys of
            ``demos`` if given, else all observations).

    Keyword Args:
        demos (Demonstrations, optional): the expert demonstrations. When given, the encoder's observation
            normalisation is set from their statistics (:meth:`MPAIL2Modules.normalize_from_demos`), as the
            trainer does; without them it stays the identity (mean 0, std 1).

    Examples:
        >>> from torchrl_mpail2.data import record_demos
        >>> from torchrl_mpail2.envs import make_env
        >>> from torchrl_mpail2.experts import PointMassExpert
        >>> env = make_env("point_mass")
        >>> demos = record_demos(env, PointMassExpert(), episodes=2, progress=False)
        >>> cfg = ModelConfig(latent_dim=8, hidden_dims=(16,), coder_dim=16, vector_coder_hidden=16)
        >>> modules = make_mpail2_modules(env.observation_spec, env.action_spec, cfg, demos=demos)
        >>> mean, std = demos.observation_stats()["observation"]
        >>> torch.equal(modules.encoder.net.obs_mean_observation, mean)
        True
    """
    if observation_keys is None and demos is not None and (cfg is None or cfg.fuse_latent or cfg.reward_latent_keys is None):
        observation_keys = demos.observation_keys  # otherwise every observation: demos may lack what the reward skips
    shapes = observation_shapes_from_spec(observation_spec, observation_keys)
    modules = MPAIL2Modules(shapes, check_action_spec(action_spec), cfg)
    if demos is not None:
        modules.normalize_from_demos(demos)
    return modules


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
