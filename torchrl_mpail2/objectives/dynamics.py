r"""JEP encoder/dynamics loss :math:`\mathcal L_{e,f}(\omega, \psi)` (Eq. 2)."""
from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase

from torchrl_mpail2.modules.dynamics import LatentDynamics
from torchrl_mpail2.modules.encoder import ObservationEncoder
from torchrl_mpail2.objectives.base import MPAIL2LossBase


class JEPDynamicsLoss(MPAIL2LossBase):
    r"""Discounted multi-step latent prediction against stop-gradient encoder targets (Eq. 2).

    .. math::
        \mathcal L_{e,f} = \mathbb E_{\boldsymbol\tau\sim\mathcal B}\Big[\sum_{k=1}^{T}
        \rho^{k}\,\lVert \hat z_{t+k} - \mathrm{sg}(z_{t+k}) \rVert_2^2\Big],\quad
        \hat z_t = e_\omega(o_t),\ \hat z_{t+k} = f_\psi(\hat z_{t+k-1}, a_{t+k-1}).

    The ``k = 0`` term of Eq. 2 is identically zero and omitted. This is the only loss that
    trains the encoder. Sub-trajectories must not cross episode boundaries (use a ``SliceSampler``).

    Args:
        encoder_network (ObservationEncoder): :math:`e_\omega`.
        dynamics_network (LatentDynamics): :math:`f_\psi`.

    Keyword Args:
        rho (float): temporal discount (Table 4: 0.95).
        reduction (str): ``"mean"`` (over the batch) or ``"sum"``.

    Input: a tensordict of shape ``[*B, T]`` (time last) with observations, ``"action"`` and next observations.

    Returns: ``loss_dynamics`` and the detached diagnostic ``dynamics_error_last`` (error at the last step).

    Examples:
        >>> from torchrl_mpail2.modules import ObservationEncoder, LatentDynamics
        >>> enc = ObservationEncoder({"observation": [3]}, latent_dim=8, hidden_dims=[16], coder_dim=16, vector_coder_hidden=16)
        >>> loss = JEPDynamicsLoss(enc, LatentDynamics(8, 2, [16]))
        >>> td = TensorDict({"observation": torch.randn(4, 5, 3), "action": torch.rand(4, 5, 2),
        ...                  ("next", "observation"): torch.randn(4, 5, 3)}, [4, 5])
        >>> loss(td)["loss_dynamics"].shape
        torch.Size([])
    """

    dynamics_network: LatentDynamics

    def __init__(self, encoder_network: ObservationEncoder, dynamics_network: LatentDynamics, *, rho: float = 0.95,
                 reduction: str = "mean"):
        super().__init__(encoder_network, reduction)
        self.dynamics_network = dynamics_network
        self.rho = rho

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if tensordict.batch_dims < 1:
            raise ValueError("JEPDynamicsLoss needs a time dimension: a tensordict of shape [*B, T]")
        first = tensordict[..., 0]
        z = self.encode(first)  # gradient flows into the encoder only through the first latent
        with torch.no_grad():
            targets = self.encode(tensordict, self._prefix(self.tensor_keys.next))  # sg(z_{t+1..t+T}), [*B, T, Z]
        actions = self.require(tensordict, self.tensor_keys.action)
        steps = tensordict.shape[-1]
        dynamics = self.dynamics_network.module
        total = torch.zeros(z.shape[:-1], device=z.device, dtype=z.dtype)
        for k in range(steps):
            z = dynamics(z, actions[..., k, :])
            error = (z - targets[..., k, :]).pow(2).sum(-1)
            total = total + self.rho ** (k + 1) * error
        return TensorDict({"loss_dynamics": self.reduce(total), "dynamics_error_last": error.detach().mean()}, [])
