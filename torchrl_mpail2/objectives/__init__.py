"""TorchRL loss modules of MPAIL2, one per optimiser."""
from torchrl_mpail2.objectives.base import sample_window_transitions
from torchrl_mpail2.objectives.actor import MultiStepActorLoss
from torchrl_mpail2.objectives.dynamics import JEPDynamicsLoss
from torchrl_mpail2.objectives.model_free import DACLoss, ModelFreeActorLoss, ModelFreeValueLoss
from torchrl_mpail2.objectives.composite import StagedLoss
from torchrl_mpail2.objectives.mpail2 import MPAIL2Loss
from torchrl_mpail2.objectives.reward import AdversarialRewardLoss
from torchrl_mpail2.objectives.value import LambdaReturnValueLoss

__all__ = ["DACLoss", "ModelFreeActorLoss", "ModelFreeValueLoss", "MultiStepActorLoss", "JEPDynamicsLoss", "MPAIL2Loss", "StagedLoss", "AdversarialRewardLoss",
           "LambdaReturnValueLoss", "sample_window_transitions"]
