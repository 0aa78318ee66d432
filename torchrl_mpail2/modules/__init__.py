"""TensorDict modules of MPAIL2, one per paper symbol."""
from torchrl_mpail2.modules.dynamics import DynamicsNet, LatentDynamics
from torchrl_mpail2.modules.encoder import EncoderNet, ImageCoder, ObservationEncoder, VectorCoder, validate_observations
from torchrl_mpail2.modules.factory import MPAIL2Modules, make_mpail2_modules, observation_shapes_from_spec
from torchrl_mpail2.modules.policy import MultiStepPolicy, PlanPolicyNet
from torchrl_mpail2.modules.reward import RewardNet, TransitionReward
from torchrl_mpail2.modules.value import QEnsemble, QEnsembleNet

__all__ = [
    "DynamicsNet", "LatentDynamics", "EncoderNet", "ImageCoder", "ObservationEncoder", "VectorCoder",
    "validate_observations", "MPAIL2Modules", "make_mpail2_modules", "observation_shapes_from_spec",
    "MultiStepPolicy", "PlanPolicyNet", "RewardNet", "TransitionReward", "QEnsemble", "QEnsembleNet",
]
