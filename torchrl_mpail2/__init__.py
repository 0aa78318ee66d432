"""torchrl_mpail2: Model Predictive Adversarial Imitation Learning 2 as a TorchRL plugin.

Inverse reinforcement learning from observation-only demonstrations with a latent world model,
an adversarial transition reward, a Q-ensemble, a multi-step policy and a latent MPPI planner.
"""
from torchrl_mpail2.config import ConfigError, LossConfig, ModelConfig, MPAIL2Config, PlannerConfig
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
from torchrl_mpail2.trainers import MPAIL2Updater

__version__ = "0.1.0.dev0"

__all__ = [
    "ConfigError", "LossConfig", "ModelConfig", "MPAIL2Config", "PlannerConfig",
    "LatentDynamics", "MPAIL2Modules", "MultiStepPolicy", "ObservationEncoder", "QEnsemble", "TransitionReward",
    "make_mpail2_modules", "AdversarialRewardLoss", "JEPDynamicsLoss", "LambdaReturnValueLoss", "MPAIL2Loss",
    "MultiStepActorLoss", "LatentMPPIPlanner", "LatentWorldModelEnv", "MPAIL2Updater",
]
