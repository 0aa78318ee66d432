"""The paper's ablations (Table 2) as three orthogonal switches, resolved here and nowhere else.

Each ablation name is a preset of :class:`AgentSwitches`; the agent and the training loop read the switches, never
the name.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass

import torch

__all__ = ["ABLATIONS", "AgentSwitches", "UPDATE_PRECISIONS", "resolve_update_precision", "runs_bf16_natively",
           "switches_for", "warn_if_bf16_emulated"]

#: What an agent may act with: the latent MPPI planner (Algorithm 2) or the first step of the policy's plan.
ACTORS = ("planner", "policy")
#: What the reward, value and policy stages train on: the whole replay buffer or the latest episode only.
POLICY_DATA = ("replay", "latest_episode")
#: Precisions of the model-based update (see :class:`~torchrl_mpail2.agents.update.MPAIL2Updater`); ``auto`` is
#: ``bf16`` where the device runs bfloat16 natively and ``float32`` elsewhere (:func:`resolve_update_precision`).
UPDATE_PRECISIONS = ("float32", "bf16", "auto")


def runs_bf16_natively(device: torch.device | str = "cpu") -> bool:
    """Whether bfloat16 matmuls run in hardware on ``device``: a CUDA device that supports bf16, or a CPU that oneDNN
    runs bf16 on natively (AVX-512 BW/VL/DQ or AMX on x86, BF16 on Arm). Elsewhere bf16 is emulated: on a
    2-core AVX2 AMD EPYC a mixed-bf16 ``lift_state`` update took 5458 ms against 370 ms in float32."""
    device = torch.device(device)
    if device.type == "cuda":
        return torch.cuda.is_available() and torch.cuda.is_bf16_supported()
    if device.type != "cpu":
        return False
    try:
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):  # a torch build without oneDNN
        return False


def warn_if_bf16_emulated(setting: str, device: torch.device | str = "cpu", hint: str = "") -> None:
    """A ``RuntimeWarning`` naming ``setting`` when it asks for bfloat16 on a device that emulates it."""
    if not runs_bf16_natively(device):
        warnings.warn(f"{setting} on {torch.device(device)}, which has no native bfloat16: it runs emulated, many "
                      f"times slower than float32{hint}", RuntimeWarning, stacklevel=3)


def resolve_update_precision(precision: str, device: torch.device | str = "cpu", *, world_model: bool = True,
                             images: bool = False) -> str:
    """The concrete precision of ``precision`` on ``device``: ``auto`` becomes ``bf16`` where bf16 is native, the
    agent has a world model and its observations hold no images, else ``float32``; the others stay, with a warning
    when they ask for bf16 on a device that emulates it.

    Images stay in float32 because bf16 keeps 8 significant bits: on ``push_pixels`` at episode 5 the latents of
    reset states that differ only in the cube's place spread by 0.00037 (mean over dimensions), and encoding them
    under bf16 autocast moved them by 0.0074, twenty times that; a probe read the cube's place from the float32
    latents with R^2 0.97 and from the rounded ones with 0.46 (``diagnostics latent_content --bf16``,
    docs/results/diary/cameras_noise_frames.md); by episode 80 the float32-trained encoder had spread them past the
    rounding. Images keep the reference precision until bf16 is shown to cost their learning nothing.

    Raises:
        ValueError: on a precision not in :data:`UPDATE_PRECISIONS`, or a bf16 one without a world model (the
            model-free updater has no bf16 path).
    """
    if precision not in UPDATE_PRECISIONS:
        raise ValueError(f"unknown update_precision {precision!r}; choose from {UPDATE_PRECISIONS}")
    if precision == "auto":
        return "bf16" if world_model and not images and runs_bf16_natively(device) else "float32"
    if precision != "float32":
        if not world_model:
            raise ValueError(f"update_precision={precision!r} applies to the model-based updater only")
        warn_if_bf16_emulated(f"update_precision={precision!r}", device, " (update_precision='auto' picks for you)")
    return precision


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

    def policy_horizon(self, horizon: int, requested: int | None = None) -> int:
        """Length of the policy's plans for a planning horizon ``horizon``: ``horizon`` with a world model, 1 without
        (the model-free ablations act with a single-step policy, as the paper's baselines).

        Raises:
            ValueError: ``requested`` (``ModelConfig.policy_horizon``) is neither None nor that length.
        """
        length = horizon if self.world_model else 1
        if requested not in (None, length):
            raise ValueError(f"model.policy_horizon={requested} contradicts model.horizon={horizon} with "
                             f"world_model={self.world_model} (the policy plans {length} steps); leave it None")
        return length


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
