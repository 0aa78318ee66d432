"""torchrl_mpail2: Model Predictive Adversarial Imitation Learning 2 as a TorchRL plugin.

Inverse reinforcement learning from observation-only demonstrations with a latent world model,
an adversarial transition reward, a Q-ensemble, a multi-step policy and a latent MPPI planner.
"""
from torchrl_mpail2.config import ConfigError, LossConfig, ModelConfig, PlannerConfig
from torchrl_mpail2.data import (
    AttachExpertWindows,
    DemoBuffer,
    Demonstrations,
    demos_from_arrays,
    load_demos,
    record_demos,
    save_demos,
)
from torchrl_mpail2.modules import (
    LatentDynamics,
    MPAIL2Modules,
    MultiStepPolicy,
    ObservationEncoder,
    QEnsemble,
    TransitionReward,
    make_mpail2_modules,
)
from torchrl_mpail2.objectives import (
    AdversarialRewardLoss,
    JEPDynamicsLoss,
    LambdaReturnValueLoss,
    MPAIL2Loss,
    MultiStepActorLoss,
)
from torchrl_mpail2.planners import LatentMPPIPlanner, LatentWorldModelEnv
from torchrl_mpail2.agents import LearnedRewardTransform, MPAIL2Agent, MPAIL2Updater

__version__ = "0.1.0.dev0"


def __getattr__(name):
    # the training loop pulls in the env and data stacks: import it on first use
    if name in ("ExperimentConfig", "MPAIL2Trainer"):
        from torchrl_mpail2 import trainers
        return getattr(trainers, name)
    raise AttributeError(f"module 'torchrl_mpail2' has no attribute {name!r}")

__all__ = [
    "ConfigError", "LossConfig", "ModelConfig", "PlannerConfig", "ExperimentConfig", "MPAIL2Trainer",
    "LatentDynamics", "MPAIL2Modules", "MultiStepPolicy", "ObservationEncoder", "QEnsemble", "TransitionReward",
    "make_mpail2_modules", "AdversarialRewardLoss", "JEPDynamicsLoss", "LambdaReturnValueLoss", "MPAIL2Loss",
    "MultiStepActorLoss", "LatentMPPIPlanner", "LatentWorldModelEnv", "LearnedRewardTransform", "MPAIL2Agent", "MPAIL2Updater",
    "AttachExpertWindows", "DemoBuffer", "Demonstrations", "demos_from_arrays", "load_demos", "record_demos", "save_demos",
]
