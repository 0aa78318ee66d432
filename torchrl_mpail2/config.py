"""Typed configuration of the MPAIL2 networks, losses and planner.

Defaults are the paper's Table 4 ("MPAIL2 Hyperparameters"). Values derived from an
environment (observation keys and shapes, action size) are never stored here: the
factories in :mod:`torchrl_mpail2.modules.factory` compute them from the specs.
"""
from __future__ import annotations

from dataclasses import dataclass


class ConfigError(ValueError):
    """A configuration value is unknown or impossible."""


def _check_positive(obj, *names: str) -> None:
    for name in names:
        value = getattr(obj, name)
        if value <= 0:
            raise ConfigError(f"{type(obj).__name__}.{name} must be > 0, got {value!r}")


def _check_unit_interval(obj, *names: str, closed: bool = True) -> None:
    for name in names:
        value = getattr(obj, name)
        ok = 0.0 <= value <= 1.0 if closed else 0.0 < value < 1.0
        if not ok:
            raise ConfigError(f"{type(obj).__name__}.{name} must lie in {'[0, 1]' if closed else '(0, 1)'}, got {value!r}")


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
    fuse_latent: bool = True
    """Fuse the coders' outputs with a latent MLP (True) or keep one latent block per key (compartmentalised)."""
    reward_latent_keys: tuple[str, ...] | None = None
    """Observation keys whose latent blocks the reward reads (compartmentalised mode only; None = all)."""
    horizon: int = 7
    """Planning horizon H: length of the policy's plans and of the dynamics loss windows."""
    num_q: int = 5
    """Size E of the Q-ensemble."""
    obs_clip: float = 5.0
    """Normalised vector observations are clipped to [-obs_clip, obs_clip]."""
    log_std_min: float = -5.0
    """Lower bound of the policy's log standard deviation."""
    log_std_max: float = 2.0
    """Upper bound of the policy's log standard deviation."""

    def __post_init__(self) -> None:
        self.hidden_dims = tuple(int(h) for h in self.hidden_dims)
        _check_positive(self, "latent_dim", "vector_coder_hidden", "coder_dim", "cnn_channels", "horizon", "num_q")
        if not self.hidden_dims or min(self.hidden_dims) <= 0:
            raise ConfigError(f"ModelConfig.hidden_dims must be non-empty and positive, got {self.hidden_dims}")
        if self.num_q < 2:
            raise ConfigError(f"ModelConfig.num_q must be >= 2 (two heads are drawn per target), got {self.num_q}")
        if self.log_std_min >= self.log_std_max:
            raise ConfigError("ModelConfig.log_std_min must be below log_std_max")
        if self.reward_latent_keys is not None:
            if self.fuse_latent:
                raise ConfigError("reward_latent_keys needs fuse_latent=False (a fused latent has no per-key blocks)")
            self.reward_latent_keys = tuple(self.reward_latent_keys)


@dataclass
class LossConfig:
    """Coefficients of the four MPAIL2 objectives (Eqs. 2-6, Table 4)."""

    gamma: float = 0.99
    """Discount gamma of returns."""
    lmbda: float = 0.95
    """Return parameter lambda of Eq. 6 (weight of the bootstrap q)."""
    return_form: str = "paper"
    """Form of the imagined return of the value target and the actor: ``paper`` (Eq. 6 as printed), ``authors``
    (lambda q_0 + (1 - lambda) TD(lambda), the authors' code) or ``td_lambda`` (the standard TD(lambda) return);
    see :func:`torchrl_mpail2.functional.multi_step_return`."""
    actor_q_reduce: str = "mean"
    """How the actor's objective combines its two random Q heads: ``mean`` (TD-MPC2) or ``min`` (the authors' code)."""
    rho: float = 0.95
    """Temporal discount rho of the multi-step latent prediction loss (Eq. 2)."""
    gp_coef: float = 0.1
    """Gradient-penalty coefficient beta of the reward loss (Eq. 3)."""
    reward_scale_momentum: float | None = 0.99
    """Running-scale momentum of the learned reward seen by value, actor and planner (None: raw critic, as
    in the paper). With beta = 0.1 the WGAN critic's outputs reach hundreds, which no Q head can follow."""
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
    """Learning rate of log alpha."""
    value_grad_clip: float = 5.0
    """Gradient-norm clip of the value update."""
    policy_grad_clip: float = 1.0
    """Gradient-norm clip of the policy update."""

    def __post_init__(self) -> None:
        _check_unit_interval(self, "gamma", "lmbda", "tau")
        _check_unit_interval(self, "rho", closed=False)
        from torchrl_mpail2.functional import RETURN_FORMS

        if self.actor_q_reduce not in ("mean", "min"):
            raise ConfigError(f"LossConfig.actor_q_reduce must be 'mean' or 'min', got {self.actor_q_reduce!r}")
        if self.return_form not in RETURN_FORMS:
            raise ConfigError(f"unknown LossConfig.return_form {self.return_form!r}; choose from {RETURN_FORMS}")
        _check_positive(self, "init_alpha", "lr", "encoder_lr", "alpha_lr", "value_grad_clip", "policy_grad_clip")
        if self.gp_coef < 0:
            raise ConfigError(f"LossConfig.gp_coef must be >= 0, got {self.gp_coef}")
        if self.transitions_per_window is not None and self.transitions_per_window < 1:
            raise ConfigError(f"LossConfig.transitions_per_window must be >= 1 or None, got {self.transitions_per_window}")
        if self.reward_scale_momentum is not None and not 0.0 <= self.reward_scale_momentum < 1.0:
            raise ConfigError(f"LossConfig.reward_scale_momentum must be in [0, 1) or None, got {self.reward_scale_momentum}")


#: Forms of the planner's terminal value (:attr:`PlannerConfig.terminal_value`).
TERMINAL_VALUES = ("policy_action", "plan_last_action")


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
    gamma: float = 0.99
    """Discount of the planned return."""
    bf16: bool = False
    """Run the planner's matmuls under bfloat16 autocast (faster on CPUs with AVX-512 bf16)."""
    terminal_value: str = "policy_action"
    """How a plan's return is closed: ``policy_action`` (H rewards + gamma^H Q(z_H, pi(z_H)), TD-MPC2's form) or
    ``plan_last_action`` (H - 1 rewards + gamma^(H-1) Q(z_{H-1}, a_{H-1}), the authors' code: Q scores the plan's
    own last action)."""

    def __post_init__(self) -> None:
        _check_positive(self, "num_candidates", "num_elites", "iterations", "temperature", "std_min", "std_max")
        _check_unit_interval(self, "policy_fraction", "gamma")
        if self.num_elites > self.num_candidates:
            raise ConfigError(
                f"PlannerConfig.num_elites ({self.num_elites}) cannot exceed num_candidates ({self.num_candidates})"
            )
        if self.terminal_value not in TERMINAL_VALUES:
            raise ConfigError(f"unknown PlannerConfig.terminal_value {self.terminal_value!r}; choose from {TERMINAL_VALUES}")
        if self.std_min > self.std_max:
            raise ConfigError(f"PlannerConfig.std_min ({self.std_min}) must not exceed std_max ({self.std_max})")

    @property
    def num_policy_samples(self) -> int:
        """Number M of candidates drawn from the policy (rounded, at least one when the fraction is positive)."""
        if self.policy_fraction == 0:
            return 0
        return min(self.num_candidates, max(1, round(self.policy_fraction * self.num_candidates)))
