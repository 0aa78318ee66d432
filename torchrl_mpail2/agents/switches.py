"""The paper's ablations (Table 2) as three orthogonal switches, resolved here and nowhere else.

Each ablation name is a preset of :class:`AgentSwitches`; the agent and the training loop read the switches, never
the name.
"""
from __future__ import annotations

from dataclasses import dataclass

__all__ = ["ABLATIONS", "AgentSwitches", "UPDATE_PRECISIONS", "switches_for"]

#: What an agent may act with: the latent MPPI planner (Algorithm 2) or the first step of the policy's plan.
ACTORS = ("planner", "policy")
#: What the reward, value and policy stages train on: the whole replay buffer or the latest episode only.
POLICY_DATA = ("replay", "latest_episode")
#: Precisions of the model-based update (see :class:`~torchrl_mpail2.agents.update.MPAIL2Updater`).
UPDATE_PRECISIONS = ("float32", "bf16_stop_gradient", "bf16")


@dataclass(frozen=True)
class AgentSwitches:
    """Which parts of MPAIL2 an agent uses.

    Args:
        act_with (str): ``"planner"`` (latent MPPI seeded by the policy) or ``"policy"`` (its plan's first action).
        world_model (bool): learn latent dynamics and plan through them; without it the agent is model-free
            (single-step policy, soft Q on real transitions, encoder trained by the value loss) and must act with
            the policy.
        policy_data (str): ``"replay"`` (off-policy, the paper's MPAIL2) or ``"latest_episode"`` (the reward, value
            and policy stages see the latest episode only; the world model stays off-policy).
        description (str): what the combination is called in the paper.
    """

    act_with: str = "planner"
    world_model: bool = True
    policy_data: str = "replay"
    description: str = ""

    def __post_init__(self) -> None:
        if self.act_with not in ACTORS:
            raise ValueError(f"AgentSwitches.act_with must be one of {ACTORS}, got {self.act_with!r}")
        if self.policy_data not in POLICY_DATA:
            raise ValueError(f"AgentSwitches.policy_data must be one of {POLICY_DATA}, got {self.policy_data!r}")
        if not self.world_model and self.act_with == "planner":
            raise ValueError("AgentSwitches: the planner plans through the world model; world_model=False "
                             "needs act_with='policy'")

    @property
    def latest_episode_only(self) -> bool:
        return self.policy_data == "latest_episode"


#: The paper's Table 2 names, as presets of the switches.
ABLATIONS: dict[str, AgentSwitches] = {
    "none": AgentSwitches(description="MPAIL2: planner, world model, off-policy reward/value/policy"),
    "P": AgentSwitches(act_with="policy",
                       description="[-P] MAIRL: act with the policy (first step of its plan), no planner"),
    "O": AgentSwitches(policy_data="latest_episode",
                       description="[-O] MPAIL: reward, value and policy trained on the latest episode only; "
                                   "world model off-policy"),
    "PM": AgentSwitches(act_with="policy", world_model=False,
                        description="[-PM] DAC: no planner, no dynamics model; single-step policy, model-free soft Q, "
                                    "encoder trained by the value loss"),
    "PMO": AgentSwitches(act_with="policy", world_model=False, policy_data="latest_episode",
                         description="[-PMO] AIRL: DAC trained on the latest episode only"),
}


def switches_for(ablation: str) -> AgentSwitches:
    """The switches of a Table 2 name (``"none"`` is MPAIL2 itself)."""
    if ablation not in ABLATIONS:
        raise ValueError(f"unknown ablation {ablation!r}; choose from {sorted(ABLATIONS)}")
    return ABLATIONS[ablation]
