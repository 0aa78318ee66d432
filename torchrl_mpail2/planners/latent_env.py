r"""The learned latent MDP as a TorchRL ``ModelBasedEnvBase``: state ``z``, step :math:`f_\psi`, reward :math:`r_\theta`.

It is what :class:`~torchrl.modules.planners.MPCPlannerBase` plans in, and it lets TorchRL's own
planners (e.g. ``MPPIPlanner``) drive the very same networks.
"""
from __future__ import annotations

import torch
from tensordict import TensorDict, TensorDictBase
from tensordict.nn import TensorDictModule
from torch import Tensor, nn
from torchrl.data import Composite, Unbounded
from torchrl.envs.model_based import ModelBasedEnvBase

from torchrl_mpail2.modules.factory import MPAIL2Modules


class _LatentStep(nn.Module):
    def __init__(self, modules: MPAIL2Modules):
        super().__init__()
        self.dynamics, self.reward = modules.dynamics.module, modules.reward.module

    def forward(self, z: Tensor, a: Tensor) -> tuple[Tensor, Tensor]:
        z_next = self.dynamics(z, a)
        return z_next, self.reward(z, z_next)


class LatentWorldModelEnv(ModelBasedEnvBase):
    r"""Latent environment ``z' = f_psi(z, a)``, ``reward = r_theta(z, z')`` (never terminates).

    ``reset`` encodes the observation keys found in the given tensordict into ``"z"`` (or keeps a
    given ``"z"``). Not batch-locked: any batch size is accepted.

    Args:
        modules (MPAIL2Modules): the learned components.
        action_spec (TensorSpec): the real environment's action spec (unbatched ``[A]``).
    """

    def __init__(self, modules: MPAIL2Modules, action_spec):
        world_model = TensorDictModule(_LatentStep(modules), in_keys=["z", "action"], out_keys=["z", "reward"])
        device = next(modules.parameters()).device
        super().__init__(world_model, device=device, batch_size=torch.Size([]))
        self.__dict__["encoder"] = modules.encoder
        latent_dim = modules.cfg.latent_dim
        self.observation_spec = Composite(z=Unbounded((latent_dim,), device=device), shape=())
        self.state_spec = Composite(z=Unbounded((latent_dim,), device=device), shape=())
        self.action_spec = action_spec.clone().to(device)
        self.reward_spec = Unbounded((1,), device=device)

    def _reset(self, tensordict: TensorDictBase | None = None, **kwargs) -> TensorDictBase:
        if tensordict is None or "z" not in tensordict.keys():
            if tensordict is None:
                raise ValueError("LatentWorldModelEnv.reset needs observations (or 'z') to start from")
            z = self.encoder.encode(tensordict)
        else:
            z = tensordict.get("z")
        return TensorDict({"z": z}, batch_size=z.shape[:-1], device=z.device)
