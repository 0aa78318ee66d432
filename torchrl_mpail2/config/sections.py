"""Typed configuration of the MPAIL2 networks, losses and planner.

Defaults are the paper's Table 4 ("MPAIL2 Hyperparameters"). Values derived from an
environment (observation keys and shapes, action size) are never stored here: the
factories in :mod:`torchrl_mpail2.modules.factory` compute them from the specs.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

from torchrl_mpail2.config.fields import (AT_LEAST_ONE, FINITE, NON_NEGATIVE, OPEN_UNIT_INTERVAL, POSITIVE,
                                          UNIT_INTERVAL, ConfigError, Range, check_fields)
from torchrl_mpail2.functional import RETURN_FORMS, TERMINAL_VALUES


@dataclass
class ModelConfig:
    """Sizes of the encoder, dynamics, reward, value and policy networks (Table 4, Fig. 14)."""

    latent_dim: int = 512
    """Latent size Z (the paper uses 512 with images and 256 for state observations)."""
    hidden_dims: tuple[int, ...] = (512, 512)
    """Hidden layer widths of every MLP (dynamics, reward, value, policy, latent fusion)."""
    vector_coder_hidden: int = 256
    """Hidden width of the per-key MLP coder of vector observations (Fig. 14: 8 -> 256 -> 512)."""
    coder_dim: int = 512
    """Output width of each per-key coder before fusion (Fig. 14: 512)."""
    cnn_channels: int = 32
    """Channels of the four 3x3 convolutions of the image coder."""
    cnn_init: str = "torch"
    """Initialisation of the image coder (``modules.encoder.CNN_INITS``): ``torch`` (PyTorch's defaults; the paper
    states none) or ``kaiming`` (Kaiming-normal weights, zero biases: the pictures' differences keep their scale)."""
    image_head: str = "flatten"
    """Head of the image coder (``modules.encoder.IMAGE_HEADS``): ``flatten`` the last feature map (Fig. 14) or
    ``keypoints`` (spatial soft-argmax coordinates of ``keypoints`` maps, ``modules.keypoints``; not in the paper)."""
    keypoints: int = 32
    """Keypoints of the ``keypoints`` image head (two coordinates each)."""
    image_norm: str = "centred"
    """How camera pixels enter the CNN (``modules.encoder.IMAGE_NORMS``): ``centred`` (x / 255 - 0.5, as the
    authors' code) or ``demos`` (each pixel and channel standardised by the demonstrations' mean and std, the std
    floored at ``modules.encoder.PIXEL_STD_FLOOR``, clipped at ``obs_clip``, as vector keys are)."""
    fuse_latent: bool = True
    """Fuse the coders' outputs with a latent MLP (True) or keep one latent block per key (compartmentalised)."""
    reward_latent_keys: tuple[str, ...] | None = None
    """Observation keys whose latent blocks the reward reads (compartmentalised mode only; None = all)."""
    horizon: int = 7
    """Planning horizon H: length of the policy's plans and of the replay windows (dynamics loss, value targets)."""
    policy_horizon: int | None = None
    """Length of the policy's plans as the agent builds it: ``horizon``, or 1 for the model-free ablations (their
    replay windows keep ``horizon``). None derives it; a run's saved config records the derived value, and any other
    value is refused when the agent is built."""
    num_q: int = 5
    """Size E of the Q-ensemble."""
    obs_clip: float = 5.0
    """Normalised vector observations are clipped to [-obs_clip, obs_clip]."""
    log_std_min: float = -5.0
    """Lower bound of the policy's log standard deviation."""
    log_std_max: float = 2.0
    """Upper bound of the policy's log standard deviation."""

    RANGES: ClassVar[dict[str, Range]] = {
        "latent_dim": POSITIVE, "hidden_dims": POSITIVE, "vector_coder_hidden": POSITIVE, "coder_dim": POSITIVE,
        "cnn_channels": POSITIVE, "keypoints": POSITIVE, "horizon": POSITIVE, "policy_horizon": POSITIVE, "num_q": Range(2.0), "obs_clip": POSITIVE,
        "log_std_min": FINITE, "log_std_max": FINITE,
    }

    def __post_init__(self) -> None:
        check_fields(self)
        self.hidden_dims = tuple(self.hidden_dims)
        if not self.hidden_dims:
            raise ConfigError(f"ModelConfig.hidden_dims must be non-empty and positive, got {self.hidden_dims}")
        if self.num_q < 2:
            raise ConfigError(f"ModelConfig.num_q must be >= 2 (two heads are drawn per target), got {self.num_q}")
        if self.log_std_min >= self.log_std_max:
            raise ConfigError("ModelConfig.log_std_min must be below log_std_max")
        if self.cnn_init not in ("torch", "kaiming"):
            raise ConfigError(f"unknown ModelConfig.cnn_init {self.cnn_init!r}; choose from ('torch', 'kaiming')")
        if self.image_head not in ("flatten", "keypoints"):
            raise ConfigError(f"unknown ModelConfig.image_head {self.image_head!r}; choose from ('flatten', 'keypoints')")
        if self.image_norm not in ("centred", "demos"):
            raise ConfigError(f"unknown ModelConfig.image_norm {self.image_norm!r}; choose from ('centred', 'demos')")
        if self.reward_latent_keys is not None:
            if self.fuse_latent:
                raise ConfigError("reward_latent_keys needs fuse_latent=False (a fused latent has no per-key blocks)")
            self.reward_latent_keys = tuple(self.reward_latent_keys)


@dataclass
class LossConfig:
    """Coefficients of the four MPAIL2 objectives (Eqs. 2-6, Table 4)."""

    gamma: float = 0.99
    """Discount gamma of every return: the value target, the actor's objective and the planner's plan scores."""
    lmbda: float = 0.95
    """Return parameter lambda of Eq. 6 (weight of the bootstrap q)."""
    return_form: str = "paper"
    """Form of the imagined return of the value target and the actor: ``paper`` (Eq. 6 as printed), ``authors``
    (lambda q_0 + (1 - lambda) TD(lambda), the authors' code) or ``td_lambda`` (the standard TD(lambda) return);
    see :func:`torchrl_mpail2.functional.multi_step_return`."""
    actor_q_reduce: str = "mean"
    """How the actor's objective combines its two random Q heads: ``mean`` (TD-MPC2) or ``min`` (the authors' code)."""
    value_head_reduce: str = "sum"
    """How the value loss combines the ensemble heads' squared errors: ``sum`` (Eq. 4's sum over e) or ``mean``
    (each head's share, so that the gradient clip acts per head as with one Q; hypothesis 7)."""
    rho: float = 0.95
    """Temporal discount rho of the multi-step latent prediction loss (Eq. 2)."""
    gp_coef: float = 0.1
    """Gradient-penalty coefficient beta of the reward loss (Eq. 3)."""
    reward_scale_momentum: float | None = None
    """Running-scale momentum of the learned reward seen by value, actor and planner (None: the raw critic, as
    in the paper). With beta = 0.1 the WGAN critic's outputs reach hundreds, which no Q head can follow: the
    CPU presets ``point_mass`` and ``push_state`` (and those built on them) divide by a running scale of momentum
    ``config.presets.RUNNING_REWARD_SCALE`` (docs/implementation_details.md)."""
    transitions_per_window: int | None = None
    """Random transitions of each replayed ``T``-step window that the reward, value and actor objectives use
    (None: all of them). The dynamics objective always uses whole windows. Their cost scales with it."""
    tau: float = 0.01
    """Polyak coefficient of the target Q-ensemble."""
    init_alpha: float = 1e-3
    """Initial entropy temperature alpha."""
    target_entropy_per_step: float | None = None
    """Target entropy per action step; None means -|A| (Table 4)."""
    mask_terminal: bool = False
    """Zero the bootstrap after terminal transitions (for tasks that terminate, e.g. Hopper)."""
    lr: float = 3e-4
    """Learning rate of dynamics, reward, value and policy (Adam)."""
    encoder_lr: float = 3e-5
    """Learning rate of the encoder."""
    alpha_lr: float = 3e-4
    """Learning rate of log alpha (Table 4: 3e-4). Adam moves log alpha by about ``alpha_lr`` per update whatever
    the entropy gap, so alpha grows e-fold every ``1 / alpha_lr`` updates while the entropy is below its target.
    0 keeps alpha fixed at ``init_alpha`` (a constant entropy coefficient, as TD-MPC2 uses)."""
    value_grad_clip: float = 5.0
    """Gradient-norm clip of the value update."""
    policy_grad_clip: float = 1.0
    """Gradient-norm clip of the policy update."""
    value_trains_encoder: bool = False
    """The value loss's gradient trains the encoder too (at ``encoder_lr``, in the value stage), as TD-MPC2's encoder
    learns from its value loss. False: the encoder learns from Eq. 2 alone, as in the paper and the authors' code."""
    value_branch_fraction: float = 0.0
    """Imagined branches in the value loss, as a share of its replayed transitions: from that many replay latents the
    policy's plan with Gaussian noise (std ``value_branch_noise``) is rolled through the dynamics and one random step
    of each path is regressed onto the same target, so that Q is fitted where the planner reads it and the replay holds
    nothing (``LambdaReturnValueLoss.imagined_branches``). 0: replay only, as in the paper."""
    value_branch_noise: float = 0.3
    """Std of the noise on the policy's plan along the value's imagined branches (actions in [-1, 1])."""
    image_shift: int = 0
    """Random-shift augmentation of camera frames in every update stage: each frame moved by up to this many pixels
    per axis, its border repeated (``modules.augment.random_shift``; DrQ and TD-MPC2 use 4 at 64 x 64). 0: off, as in
    the paper. Acting and evaluation see the frames unshifted."""

    RANGES: ClassVar[dict[str, Range]] = {
        "gamma": UNIT_INTERVAL, "lmbda": UNIT_INTERVAL, "rho": OPEN_UNIT_INTERVAL, "gp_coef": NON_NEGATIVE,
        "reward_scale_momentum": Range(0.0, 1.0, high_open=True), "transitions_per_window": AT_LEAST_ONE,
        "tau": UNIT_INTERVAL, "init_alpha": POSITIVE,
        "target_entropy_per_step": FINITE, "lr": POSITIVE, "encoder_lr": POSITIVE, "alpha_lr": NON_NEGATIVE, "value_grad_clip": POSITIVE, "policy_grad_clip": POSITIVE,
        "image_shift": NON_NEGATIVE, "value_branch_fraction": NON_NEGATIVE, "value_branch_noise": NON_NEGATIVE,
    }

    def __post_init__(self) -> None:
        check_fields(self)

        if self.value_head_reduce not in ("sum", "mean"):
            raise ConfigError(f"LossConfig.value_head_reduce must be 'sum' or 'mean', got {self.value_head_reduce!r}")
        if self.actor_q_reduce not in ("mean", "min"):
            raise ConfigError(f"LossConfig.actor_q_reduce must be 'mean' or 'min', got {self.actor_q_reduce!r}")
        if self.return_form not in RETURN_FORMS:
            raise ConfigError(f"unknown LossConfig.return_form {self.return_form!r}; choose from {RETURN_FORMS}")


#: ``torch.compile`` modes of the plan scoring (:attr:`PlannerConfig.compile_mode`).
COMPILE_MODES = ("default", "reduce-overhead", "max-autotune-no-cudagraphs")


@dataclass
class PlannerConfig:
    """Latent MPPI settings (Algorithm 2, Table 4)."""

    num_candidates: int = 512
    """Number N of sampled plans per iteration."""
    policy_fraction: float = 0.05
    """Fraction M/N of the candidates drawn from the policy."""
    num_elites: int = 64
    """Number K of elite plans that shape the next sampling distribution."""
    iterations: int = 5
    """Number J of MPPI iterations."""
    temperature: float = 2.0
    """Softmax temperature eta of the elite weights."""
    std_min: float = 0.05
    """Lower clip sigma_min of the sampling std."""
    std_max: float = 2.0
    """Upper clip sigma_max of the sampling std (also the std of the first iteration)."""
    bf16: bool = False
    """Run the planner's matmuls under bfloat16 autocast (faster on CPUs with AVX-512 bf16)."""
    compile: bool = False
    """Compile the plan scoring (latent rollout, rewards, terminal value) with ``torch.compile``, once per batch
    shape and precision; training and evaluation calls share the graphs, and so do planners built later in the same
    process on networks of the same sizes. Where compiling fails (inductor needs a working C++ compiler on a CPU), a
    warning is logged and the planner scores eagerly. Off by default: compiling costs 25-55 s on a CPU and changes
    the last bits of the returns (``benchmarks/speed/compile_speed.py``); on Lift, seeds 0 and 1, the compiled runs reached
    0.60 at 300 episodes against 0.925 eager, with no fault found (docs/results/speed/speed_notes.md)."""
    compile_mode: str = "default"
    """``torch.compile`` mode with ``compile``: ``default``, ``reduce-overhead`` (the scoring replayed as CUDA graphs
    on a GPU, against the launch overhead that bounds a planning call there; the returns are copied out of the
    graphs' memory; on one H200 at the paper configuration 149 planning calls per second against 46 eager and 71
    compiled in ``default``, docs/results/speed/device_smoke.md) or ``max-autotune-no-cudagraphs``."""
    terminal_value: str = "policy_action"
    """How a plan's return is closed: ``policy_action`` (H rewards + gamma^H Q(z_H, pi(z_H)), TD-MPC2's form) or
    ``plan_last_action`` (H - 1 rewards + gamma^(H-1) Q(z_{H-1}, a_{H-1}), the authors' code: Q scores the plan's
    own last action)."""

    RANGES: ClassVar[dict[str, Range]] = {
        "num_candidates": POSITIVE, "policy_fraction": UNIT_INTERVAL, "num_elites": POSITIVE, "iterations": POSITIVE,
        "temperature": POSITIVE, "std_min": POSITIVE, "std_max": POSITIVE,
    }

    def __post_init__(self) -> None:
        check_fields(self)
        if self.num_elites > self.num_candidates:
            raise ConfigError(
                f"PlannerConfig.num_elites ({self.num_elites}) cannot exceed num_candidates ({self.num_candidates})"
            )
        if self.terminal_value not in TERMINAL_VALUES:
            raise ConfigError(f"unknown PlannerConfig.terminal_value {self.terminal_value!r}; choose from {TERMINAL_VALUES}")
        if self.compile_mode not in COMPILE_MODES:
            raise ConfigError(f"unknown PlannerConfig.compile_mode {self.compile_mode!r}; choose from {COMPILE_MODES}")
        if self.std_min > self.std_max:
            raise ConfigError(f"PlannerConfig.std_min ({self.std_min}) must not exceed std_max ({self.std_max})")

    @property
    def num_policy_samples(self) -> int:
        """Number M of candidates drawn from the policy (rounded, at least one when the fraction is positive)."""
        if self.policy_fraction == 0:
            return 0
        return min(self.num_candidates, max(1, round(self.policy_fraction * self.num_candidates)))


#: Fields removed with the extensions they switched on (measured, not adopted): ``section.field`` -> (the value the
#: code now always runs, the last commit that had the field). Their results entries name the same commit.
REMOVED_FIELDS: dict[str, tuple[object, str]] = {
    "planner.temperature_scale": ("absolute", "7137cb5"),
    "loss.expert_start_fraction": (0.0, "7137cb5"),
}


def migrate_config_data(data: dict) -> dict:
    """A run config's JSON data (``{"train": ..., "model": ..., "loss": ..., "planner": ...}``) from an older
    version in today's fields: ``planner.gamma``, kept equal to ``loss.gamma`` until the discount got one home in
    :class:`LossConfig`, is dropped, or refused by name where it differed; so is a field of :data:`REMOVED_FIELDS`
    where it holds the value the code now runs (refused with the commit that last had it otherwise)."""
    data = {section: dict(values) if isinstance(values, dict) else values for section, values in data.items()}
    for name, (kept, commit) in REMOVED_FIELDS.items():
        section, field = name.split(".")
        values = data.get(section)
        if not isinstance(values, dict) or field not in values:
            continue
        value = values.pop(field)
        if value != kept:
            raise ConfigError(f"{name}={value!r}: the field was removed after commit {commit} (an extension not "
                              f"adopted; {kept!r} is what runs now); run this config from that commit")
    planner = dict(data.get("planner", {}))
    if "gamma" not in planner:
        return data
    old, current = planner.pop("gamma"), data.get("loss", {}).get("gamma", LossConfig.gamma)
    if old != current:
        raise ConfigError(f"planner.gamma ({old}) differs from loss.gamma ({current}); the discount is loss.gamma now")
    return {**data, "planner": planner}
