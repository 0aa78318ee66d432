"""The agent: networks, losses, per-stage updaters, actor and the switches that pick the paper's ablations."""
from torchrl_mpail2.agents.switches import ABLATIONS, AgentSwitches, switches_for
from torchrl_mpail2.agents.update import MPAIL2Updater
from torchrl_mpail2.agents.model_free_update import ModelFreeUpdater
from torchrl_mpail2.agents.mpail2 import MPAIL2Agent

__all__ = ["ABLATIONS", "AgentSwitches", "MPAIL2Agent", "MPAIL2Updater", "ModelFreeUpdater", "switches_for"]
