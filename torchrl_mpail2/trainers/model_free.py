"""Updates of the model-free ablations [-PM] (DAC) and [-PMO] (AIRL)."""
from __future__ import annotations

import torch
from tensordict import TensorDictBase

from torchrl_mpail2.trainers.update import MPAIL2Updater


class ModelFreeUpdater(MPAIL2Updater):
    """reward -> value (encoder and Q, + Polyak) -> actor -> alpha on one batch, for a :class:`DACLoss`.

    With ``policy_tensordict`` (the [-PMO] ablation: the latest episode only) every stage uses that batch,
    since there is no world model to train off-policy.
    """

    def update(self, tensordict: TensorDictBase, policy_tensordict: TensorDictBase | None = None) -> TensorDictBase:
        loss = self.loss
        td = policy_tensordict if policy_tensordict is not None else tensordict
        latents = loss.replay_latents(td)
        metrics = loss.reward_loss(td, latents=latents, expert_latents=loss.expert_latents(td))
        self._step("reward", metrics["loss_reward"])
        out = loss.value_loss(td, latents=latents)
        self._step("value", out["loss_value"])
        self.target_updater.step()
        metrics.update(out)
        out = loss.actor_loss(td, latents=latents)
        self._step("actor", out["loss_actor"])
        self._step("alpha", out["loss_alpha"])
        metrics.update(out)
        metrics.set("nonfinite_skips", torch.tensor(float(sum(self.skipped.values()))))
        return metrics.apply(lambda x: x.detach())
