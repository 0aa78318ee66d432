r"""Inferred transition reward :math:`r_\theta : (z, z') \mapsto \mathbb R` (Eq. 3), a WGAN critic."""
from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from tensordict.nn import TensorDictModule
from torch import Tensor, nn

from torchrl_mpail2.modules._mlp import check_last_dim, mlp


#: Initial running-scale state of :class:`RewardNet`: the raw critic (scale 1) with no history.
_SCALE_STATE = {"reward_scale": 1.0, "scale_ema": 0.0, "scale_updates": 0}


class RewardNet(nn.Module):
    r"""MLP critic :math:`r_\theta(z, z')` with no LayerNorm and no output bias (Table 4, Fig. 14).

    The first Linear acts on ``[z, z']``; it is applied as ``W_z z + W_{z'} z' + b`` so that a caller
    scoring a chain of latents can project each latent once (:meth:`project` / :meth:`from_projection`).

    Two outputs: :meth:`critic` is the raw WGAN critic (what the reward loss and its gradient penalty
    see); :meth:`forward` and :meth:`from_projection` give the reward the value, the actor and the planner
    use, the critic divided by ``reward_scale`` (a buffer, 1 unless the reward loss keeps it as a running
    scale of the critic's outputs; see :class:`~torchrl_mpail2.objectives.AdversarialRewardLoss`).

    Args:
        latent_dim (int): ``Z`` of the full latent.
        hidden_dims (Sequence[int]): hidden widths.
        latent_index (Sequence[int], optional): latent coordinates the reward reads
            (the compartmentalised encoder's reward-visible blocks); ``None`` reads all of them.
    """

    def __init__(self, latent_dim: int, hidden_dims: Sequence[int], latent_index: Sequence[int] | None = None):
        super().__init__()
        self.latent_dim = latent_dim
        if latent_index is not None:
            self.register_buffer("latent_index", torch.as_tensor(list(latent_index), dtype=torch.long), persistent=False)
        else:
            self.latent_index = None
        in_dim = latent_dim if latent_index is None else len(latent_index)
        self.in_dim = in_dim
        self.net = mlp(2 * in_dim, hidden_dims, 1, layer_norm=False, out_bias=False)
        for name, value in _SCALE_STATE.items():
            self.register_buffer(name, torch.tensor(value))

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        # checkpoints written before the running scale existed load as the raw critic (scale 1, no history)
        for name, value in _SCALE_STATE.items():
            state_dict.setdefault(prefix + name, torch.tensor(value))
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    @torch.no_grad()
    def track_scale(self, scores: Tensor, momentum: float) -> None:
        """Sets ``reward_scale`` to a bias-corrected running mean of the standard deviation of ``scores``.

        ``scores`` are raw critic outputs (expert and replayed transitions pooled); the scale is floored
        at ``1e-3``. With ``momentum`` m the running mean forgets with time constant ``1 / (1 - m)`` updates.
        Scores holding NaN or Inf change nothing.
        """
        if scores.numel() < 2:  # no spread to measure
            return
        # scores holding NaN or Inf leave the running scale as it was (without a host sync)
        finite = torch.isfinite(scores).all()
        self.scale_updates += finite.to(self.scale_updates.dtype)
        std = torch.where(finite, scores.detach().float().std(), self.scale_ema)
        self.scale_ema.lerp_(std, 1.0 - momentum)
        corrected = self.scale_ema / (1.0 - torch.pow(momentum, self.scale_updates.float()))  # no host sync
        self.reward_scale.copy_(torch.where(finite, corrected.clamp_min(1e-3), self.reward_scale))

    def _select(self, z: Tensor) -> Tensor:
        check_last_dim("reward input latent", z, self.latent_dim)
        return z if self.latent_index is None else z.index_select(-1, self.latent_index)

    def project(self, z: Tensor) -> tuple[Tensor, Tensor]:
        """First-layer projections of ``z`` as the current (``W_z z + b``) and the next (``W_{z'} z``) latent."""
        first: nn.Linear = self.net[0]
        z = self._select(z)
        w_now, w_next = first.weight[:, : self.in_dim], first.weight[:, self.in_dim :]
        return F.linear(z, w_now, first.bias), F.linear(z, w_next)

    def from_projection(self, h_now: Tensor, h_next: Tensor) -> Tensor:
        """Finishes the (scaled) reward from ``project(z)[0] + project(z')[1]`` -> ``[*B, 1]``."""
        return self.net[1:](h_now + h_next) / self.reward_scale.to(h_now.dtype)

    def critic(self, z: Tensor, z_next: Tensor) -> Tensor:
        """Raw critic ``z, z' [*B, Z]`` -> ``[*B, 1]`` (the quantity the WGAN-GP loss trains)."""
        return self.net(torch.cat([self._select(z), self._select(z_next)], dim=-1))

    def forward(self, z: Tensor, z_next: Tensor) -> Tensor:
        """Reward ``z, z' [*B, Z]`` -> ``r [*B, 1]``: the critic over ``reward_scale``."""
        return self.critic(z, z_next) / self.reward_scale.to(z.dtype)

    def score_pairs(self, x: Tensor) -> Tensor:
        """Raw critic of concatenated, already selected pairs ``[*B, 2 * in_dim]`` (for the gradient penalty)."""
        return self.net(x)


class TransitionReward(TensorDictModule):
    r"""Inferred reward :math:`r_\theta(z_t, z_{t+1})` written under its own key ``"learned_reward"``.

    Trained adversarially (expert transitions up, replayed ones down, WGAN-GP). It never
    overwrites the environment's ``"reward"``.

    Examples:
        >>> from tensordict import TensorDict
        >>> r = TransitionReward(8, [16])
        >>> td = TensorDict({"z": torch.zeros(3, 8), ("next", "z"): torch.ones(3, 8)}, [3])
        >>> r(td)["learned_reward"].shape
        torch.Size([3, 1])
    """

    def __init__(self, latent_dim: int, hidden_dims: Sequence[int], latent_index=None, *, in_keys=None, out_keys=None):
        super().__init__(
            RewardNet(latent_dim, hidden_dims, latent_index),
            in_keys=list(in_keys or ["z", ("next", "z")]),
            out_keys=list(out_keys or ["learned_reward"]),
        )
