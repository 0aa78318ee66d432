"""The agent: networks, losses, per-stage updaters, actor, the switches that pick the paper's ablations, and its
learned reward as a TorchRL transform."""
from torchrl_mpail2.config import ABLATIONS, AgentSwitches, switches_for
from torchrl_mpail2.agents.update import MPAIL2Updater
from torchrl_mpail2.agents.mpail2 import MPAIL2Agent
from torchrl_mpail2.agents.learned_reward import LearnedRewardTransform

__all__ = ["ABLATIONS", "AgentSwitches", "LearnedRewardTransform", "MPAIL2Agent", "MPAIL2Updater", "switches_for"]
