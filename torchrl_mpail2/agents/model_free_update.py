"""Updates of the model-free ablations [-PM] (DAC) and [-PMO] (AIRL)."""
from __future__ import annotations

from tensordict import TensorDictBase

from torchrl_mpail2.agents.update import MPAIL2Updater


class ModelFreeUpdater(MPAIL2Updater):
    """reward -> value (encoder and Q, + Polyak) -> actor -> alpha on one batch, for a :class:`DACLoss`.

    With ``policy_tensordict`` (the [-PMO] ablation: the latest episode only) every stage uses that batch,
    since there is no world model to train off-policy.
    """

    def update(self, tensordict: TensorDictBase, policy_tensordict: TensorDictBase | None = None) -> TensorDictBase | None:
        td = policy_tensordict if policy_tensordict is not None else tensordict
        if self.skip_nonfinite(td):
            return None
        return self._reward_value_actor(td).apply(lambda x: x.detach())
