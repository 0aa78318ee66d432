r"""Latent MPPI planner seeded by the multi-step policy (Algorithm 2)."""
from __future__ import annotations

import contextlib
import logging

import torch
from tensordict import TensorDict, TensorDictBase
from torch import Tensor, nn
from torchrl.data import Unbounded
from torchrl.envs import TensorDictPrimer
from torchrl.modules.planners import MPCPlannerBase

from torchrl_mpail2.config import PlannerConfig
from torchrl_mpail2.functional import mppi_weights, n_step_return, rewarded_steps
from torchrl_mpail2.modules.encoder import validate_observations
from torchrl_mpail2.modules.factory import MPAIL2Modules, check_action_spec
from torchrl_mpail2.modules.policy import is_deterministic
from torchrl_mpail2.modules.world_model import imagine_with_rewards
from torchrl_mpail2.planners.latent_env import LatentWorldModelEnv

#: Where the warm start (the previous call's final plan mean ``[*B, H, A]``) lives in the tensordict when the env
#: carries it (:meth:`LatentMPPIPlanner.make_tensordict_primer`).
WARM_START_KEY = "planner_mean"

log = logging.getLogger(__name__)


def _to_bf16(t: Tensor) -> Tensor:
    return t.to(torch.bfloat16) if t.is_floating_point() else t


class _EagerIfCompileFails:
    """Calls the compiled scorer; where compiling fails (no working C++ compiler for inductor's CPU code, a backend
    error), warns once and scores eagerly from then on. Eager scoring gives the same returns up to their last bits;
    an error that is not the compiler's is raised again by the eager call."""

    def __init__(self, compiled, eager):
        self.compiled, self.eager, self.failed = compiled, eager, False

    def __call__(self, z: Tensor, plans: Tensor, heads: Tensor) -> Tensor:
        if not self.failed:
            try:
                return self.compiled(z, plans, heads)
            except torch._dynamo.exc.BackendCompilerFailed as error:
                self.failed = True
                cause = getattr(error, "inner_exception", None) or error
                text = str(cause).strip()
                log.warning("planner.compile=true: compiling the plan scoring failed, planning eagerly instead "
                            "(%s%s)", type(cause).__name__, f": {text.splitlines()[0]}" if text else "")
        return self.eager(z, plans, heads)


def _outside_graph_memory(scorer):
    """Wraps a scorer compiled with CUDA graphs: each call starts a new graph step and copies the returns out of the
    graph's memory, which the next replay overwrites (the policy samples' returns are kept across iterations)."""

    def scored(z: Tensor, plans: Tensor, heads: Tensor) -> Tensor:
        torch.compiler.cudagraph_mark_step_begin()
        return scorer(z, plans, heads).clone()

    return scored


class LatentMPPIPlanner(MPCPlannerBase):
    r"""MPPI in the learned latent space, warm-started by the previous plan and seeded by :math:`\pi_\phi`.

    Each call encodes :math:`z_t = e_\omega(o_t)` once, shifts the previous plan mean one step (last step
    0) for each environment (reset where ``"is_init"`` is set), draws ``M = policy_fraction * N`` plans from
    :math:`\pi_\phi(\cdot|z_t)` and ``N - M`` from :math:`\mathcal N(\mu, \sigma)` (first iteration at
    :math:`\sigma_{max}`), and scores each plan by

    .. math:: \mathcal R = \sum_{k=0}^{H-1}\gamma^k r_\theta(\hat z_k, \hat z_{k+1}) + \gamma^H Q_\zeta(\hat z_H, a_H),

    with :math:`a_H` the first step of the policy mean at :math:`\hat z_H` and Q the mean of two random heads
    (``cfg.terminal_value="plan_last_action"``: ``H - 1`` rewards and :math:`\gamma^{H-1} Q(\hat z_{H-1}, a_{H-1})`,
    as in the authors' code).
    The ``K`` best plans set the next mean and std (softmax weights at temperature :math:`\eta`,
    max-subtracted; std clipped to :math:`[\sigma_{min}, \sigma_{max}]`), for ``J`` iterations.

    Departures from Algorithm 2, each for speed or stability and stated here: the policy's ``M`` plans are
    drawn and scored once per call and kept for every iteration (the policy's distribution does not change
    between iterations); non-elite plans get zero weight (the pseudocode's "set to 0" would give them weight);
    the warm start stores the final mean rather than the sample (as TD-MPC2 does).

    With ``cfg.bf16`` the dynamics, reward, value and policy networks run on bfloat16 copies of their
    parameters (the encoder, the sampling statistics and the returns' sums stay in float32).

    The warm start lives in the tensordict under ``"planner_mean"`` when the env carries that key (append
    :meth:`make_tensordict_primer` to it, as for TorchRL's recurrent modules): each environment's state then travels
    with its own data, so batched and asynchronous collectors work. Without the key the planner keeps the previous
    mean itself, which suits one caller stepping one batch of environments in order.

    In the ``RANDOM`` interaction type (training) the returned plan is a sample of the final Gaussian; in
    ``DETERMINISTIC`` (``set_exploration_type(ExplorationType.DETERMINISTIC)``) it is the mean.

    Writes ``action`` ``[*B, A]`` (projected on the action spec), ``"plan"`` ``[*B, H, A]`` and
    ``"policy_influence"`` ``[*B, 1]``: the share of the final elite weight held by policy samples. With
    ``record_elites = True`` also ``"elite_plans"`` ``[*B, K, H, A]`` and ``"elite_weights"`` ``[*B, K]`` of the last
    iteration (for pictures of planning; off by default).

    Args:
        modules (MPAIL2Modules): the learned components.
        action_spec (TensorSpec): the environment's action spec, ``[A]`` bounded to ``[-1, 1]`` (checked).
        cfg (PlannerConfig, optional): Table 4 defaults.

    Keyword Args:
        gamma (float): discount of the plan scores: the learner's ``LossConfig.gamma`` (required, so that plans and
            the value they end on are discounted alike).
        action_key (NestedKey): where the action is written. Defaults to ``"action"``.
        generator (torch.Generator, optional): source of all sampling noise (for reproducible plans).

    Examples:
        >>> from tensordict import TensorDict
        >>> from torchrl.data import Bounded
        >>> from torchrl_mpail2.config import ModelConfig, PlannerConfig
        >>> from torchrl_mpail2.modules import MPAIL2Modules
        >>> modules = MPAIL2Modules({"observation": [3]}, 2, ModelConfig(latent_dim=8, hidden_dims=(16,), coder_dim=16,
        ...                         vector_coder_hidden=16, horizon=4))
        >>> planner = LatentMPPIPlanner(modules, Bounded(-1, 1, (2,)), PlannerConfig(num_candidates=64, num_elites=8),
        ...                             gamma=0.99)
        >>> td = planner(TensorDict({"observation": torch.zeros(3, 3)}, [3]))
        >>> td["action"].shape, td["plan"].shape, td["policy_influence"].shape
        (torch.Size([3, 2]), torch.Size([3, 4, 2]), torch.Size([3, 1]))
    """

    def __init__(self, modules: MPAIL2Modules, action_spec, cfg: PlannerConfig | None = None, *,
                 gamma: float, action_key="action", generator: torch.Generator | None = None):
        check_action_spec(action_spec, modules.action_dim)
        env = LatentWorldModelEnv(modules, action_spec)
        super().__init__(env, action_key=action_key)
        self.cfg = cfg or PlannerConfig()
        if not 0.0 <= gamma <= 1.0:
            raise ValueError(f"gamma must be in [0, 1], got {gamma}")
        self.gamma = gamma
        if self.cfg.num_elites > self.cfg.num_candidates:
            raise ValueError(f"num_elites ({self.cfg.num_elites}) > num_candidates ({self.cfg.num_candidates})")
        self.__dict__["components"] = modules  # the planner acts with the learner's networks; it does not own them
        self.generator = generator
        self.in_keys = list(modules.encoder.in_keys)
        # MPCPlannerBase writes only the action through out_keys; "plan" and "policy_influence" are set directly.
        self.horizon, self.action_dim = modules.cfg.horizon, modules.action_dim
        self.extra_out_shapes = {"plan": (self.horizon, self.action_dim), "policy_influence": (1,)}
        self._prev_mean: Tensor | None = None
        self.last_stats: dict[str, Tensor] = {}
        self.record_elites = False
        self._last_elites: tuple[Tensor, Tensor] | None = None

    # ---- warm-start state -------------------------------------------------------------------------
    def make_tensordict_primer(self) -> TensorDictPrimer:
        """A transform that gives an env the ``"planner_mean"`` entry ``[H, A]`` (zeros at reset) in which the
        planner keeps each environment's warm start (``env.append_transform(planner.make_tensordict_primer())``)."""
        return TensorDictPrimer({WARM_START_KEY: Unbounded((self.horizon, self.action_dim))}, default_value=0.0,
                                expand_specs=True)  # batched envs: the spec takes their batch dimensions

    def reset(self) -> None:
        """Forgets the previous plans (all environments start from a zero mean)."""
        self._prev_mean = None

    def get_extra_state(self):
        return {"prev_mean": self._prev_mean}

    def set_extra_state(self, state) -> None:
        self._prev_mean = state.get("prev_mean")

    def _initial_mean(self, td: TensorDictBase, num_envs: int, like: Tensor) -> Tensor:
        mean = torch.zeros(num_envs, self.horizon, self.action_dim, dtype=like.dtype, device=like.device)
        carried = td.get(WARM_START_KEY, None)
        prev = self._prev_mean if carried is None else carried.reshape(num_envs, self.horizon, self.action_dim)
        if prev is None or prev.shape[0] != num_envs:
            return mean
        mean[:, :-1] = prev[:, 1:]
        is_init = td.get("is_init", None)
        if is_init is not None:
            mean = mean.masked_fill(is_init.reshape(num_envs, 1, 1), 0.0)
        return mean

    # ---- scoring ----------------------------------------------------------------------------------
    def _noise(self, shape, like: Tensor) -> Tensor:
        return torch.randn(shape, dtype=like.dtype, device=like.device, generator=self.generator)

    def score(self, z: Tensor, plans: Tensor, heads: Tensor) -> Tensor:
        """Returns of ``plans [B, C, H, A]`` from latents ``z [B, Z]`` -> ``[B, C]`` (float32).

        The networks run in ``z``'s dtype (bfloat16 in the ``bf16`` mode); the return is summed in float32.
        """
        rewards, terminal = self.score_parts(z, plans, heads)
        return rewards + terminal

    def score_parts(self, z: Tensor, plans: Tensor, heads: Tensor) -> tuple[Tensor, Tensor]:
        """:meth:`score`'s two terms apart -> ``(discounted reward sum, discounted terminal value)``, each
        ``[B, C]`` float32."""
        batch, num = plans.shape[:2]
        zk = z.unsqueeze(1).expand(batch, num, -1).reshape(batch * num, -1)
        actions = plans.to(z.dtype).reshape(batch * num, self.horizon, self.action_dim)
        rewarded = rewarded_steps(self.horizon, self.cfg.terminal_value)
        m = self.components
        latents, r = imagine_with_rewards(m.dynamics.module, m.reward.module, zk, actions[:, :rewarded])
        rewards, terminal = self._return_parts(latents, actions, heads, r)
        return rewards.view(batch, num), terminal.view(batch, num)

    def path_return_parts(self, latents: Tensor, actions: Tensor, heads: Tensor) -> tuple[Tensor, Tensor]:
        """:meth:`score_parts` of a given latent path instead of an imagined one: ``latents [B, H + 1, Z]`` (e.g. the
        encoded observations of a trajectory the simulator played with ``actions [B, H, A]``) -> ``([B], [B])``.
        What the learned reward and value make of a real outcome, next to what they make of the imagined one."""
        rewarded = rewarded_steps(self.horizon, self.cfg.terminal_value)
        return self._return_parts(latents.transpose(0, 1)[:rewarded + 1], actions.to(latents.dtype), heads)

    def _return_parts(self, latents: Tensor, actions: Tensor, heads: Tensor, r: Tensor | None = None
                      ) -> tuple[Tensor, Tensor]:
        r"""Algorithm 2's return (:func:`~torchrl_mpail2.functional.n_step_return`) of the latent path ``[K + 1, N, Z]``
        reached by ``actions [N, H, A]`` (``r [K, N]``: its rewards, when already walked): ``K`` rewards, then Q (the
        mean of ``heads``) at :math:`\hat z_K` with the plan's action ``K`` or, where ``K = H``, the policy mean's
        first action there. The losses' return of the same path at lambda 1 (tests/test_planner.py)."""
        m = self.components
        rewarded, z_end = latents.shape[0] - 1, latents[-1]
        last_action = actions[:, rewarded] if rewarded < self.horizon else m.pi(z_end, deterministic=True)[0][:, 0]
        q_end = m.q(z_end, last_action, heads).float().mean(0)
        r = m.rewards(latents) if r is None else r
        return n_step_return(r.float().transpose(0, 1), q_end, self.gamma)

    def _scorer(self):
        """:meth:`score`, compiled on first use with ``cfg.compile`` (kept out of the module's attributes, so the
        planner still copies and pickles)."""
        if not self.cfg.compile:
            return self.score
        compiled = self.__dict__.get("_compiled_score")
        if compiled is None:
            compiled = torch.compile(self.score, dynamic=False, mode=self.cfg.compile_mode)
            if self.cfg.compile_mode == "reduce-overhead":
                compiled = _outside_graph_memory(compiled)
            compiled = _EagerIfCompileFails(compiled, self.score)
            self.__dict__["_compiled_score"] = compiled
        return compiled

    def __getstate__(self):
        state = dict(super().__getstate__())
        state.pop("_compiled_score", None)  # recompiled on first use after a copy
        return state

    # ---- Algorithm 2 ------------------------------------------------------------------------------
    def _planning_networks(self) -> tuple[nn.Module, ...]:
        m = self.components
        return m.dynamics, m.reward, m.value, m.policy

    @contextlib.contextmanager
    def _low_precision(self):
        """With ``cfg.bf16``: the planning networks run on bfloat16 copies of their parameters.

        The copies are made once per call (a few ms at the paper's sizes), so every GEMM runs in bf16 with
        no per-op casts (autocast would re-cast the weights at each call and run LayerNorm in fp32).
        The encoder stays in fp32; returns are summed and the sampling statistics kept in fp32.
        """
        if not self.cfg.bf16:
            yield None
            return
        swaps = [TensorDict.from_module(net).apply(_to_bf16).to_module(net) for net in self._planning_networks()]
        try:
            for swap in swaps:
                swap.__enter__()
            yield torch.bfloat16
        finally:
            for swap in reversed(swaps):
                swap.__exit__(None, None, None)

    def planning(self, td: TensorDictBase) -> Tensor:
        validate_observations(td, self.components.encoder.observation_shapes)
        batch_shape = td.batch_size
        flat = td.reshape(-1) if len(batch_shape) != 1 else td
        with torch.inference_mode():
            mean, plan, influence = self._optimise(flat)
        # inference tensors cannot be saved for backward later (e.g. replayed actions): hand out normal copies
        self._prev_mean, plan, influence = mean.clone(), plan.clone(), influence.clone()
        self.last_stats = {k: v.clone() for k, v in self.last_stats.items()}
        if WARM_START_KEY in td.keys():
            td.set(WARM_START_KEY, self._prev_mean.reshape(*batch_shape, self.horizon, self.action_dim))
        td.set("plan", plan.reshape(*batch_shape, self.horizon, self.action_dim))
        td.set("policy_influence", influence.reshape(*batch_shape, 1))
        if self.record_elites:
            elites, weights = (x.clone() for x in self._last_elites)
            td.set("elite_plans", elites.reshape(*batch_shape, *elites.shape[1:]))
            td.set("elite_weights", weights.reshape(*batch_shape, weights.shape[-1]))
        return plan[:, 0].reshape(*batch_shape, self.action_dim)

    def _optimise(self, flat: TensorDictBase) -> tuple[Tensor, Tensor, Tensor]:
        """Algorithm 2 on ``[B]`` observations -> final ``(mean, plan, policy influence)``."""
        cfg, m = self.cfg, self.components
        num_envs = flat.shape[0]
        z = m.encode(flat)
        num_pi = cfg.num_policy_samples
        num_gauss = cfg.num_candidates - num_pi
        heads = m.draw_heads(z.device, self.generator)  # one pair of Q heads for the whole call
        mean = self._initial_mean(flat, num_envs, z)
        std = torch.full_like(mean, cfg.std_max)
        score = self._scorer()
        with self._low_precision() as dtype:
            z = z.to(dtype or z.dtype)
            pi_plans = mean.new_empty(num_envs, 0, self.horizon, self.action_dim)
            if num_pi:
                pi_plans = m.pi(z.unsqueeze(1).expand(num_envs, num_pi, z.shape[-1]), generator=self.generator)[0].float()
            for iteration in range(cfg.iterations):
                noise = self._noise((num_envs, num_gauss, self.horizon, self.action_dim), mean)
                plans = (mean.unsqueeze(1) + std.unsqueeze(1) * noise).clamp(-1.0, 1.0)
                plans = torch.cat([plans, pi_plans], 1)  # policy samples sit at indices >= N - M, as in Algorithm 2
                if iteration == 0:  # the policy samples are scored once, together with the first Gaussian ones
                    returns = score(z, plans, heads)
                    pi_returns = returns[:, num_gauss:]
                else:
                    returns = torch.cat([score(z, plans[:, :num_gauss], heads), pi_returns], 1)
                weights, elite_index = mppi_weights(returns, cfg.num_elites, cfg.temperature)
                elites = plans.gather(1, elite_index[..., None, None].expand(-1, -1, self.horizon, self.action_dim))
                w = weights[..., None, None]
                mean = (w * elites).sum(1)
                std = (w * (elites - mean.unsqueeze(1)).pow(2)).sum(1).sqrt().clamp(cfg.std_min, cfg.std_max)
        influence = (weights * (elite_index >= num_gauss)).sum(-1, keepdim=True)
        self._last_elites = (elites, weights) if self.record_elites else None
        plan = mean if is_deterministic() else (mean + std * self._noise(mean.shape, mean)).clamp(-1.0, 1.0)
        self.last_stats = {"policy_influence": influence.mean(), "elite_return": returns.gather(1, elite_index).mean(),
                           "plan_std": std.mean(),
                           # effective number of elites 1 / sum w^2: K when the weights are flat, 1 when one plan wins
                           "elite_ess": weights.pow(2).sum(-1).reciprocal().mean()}
        return mean, plan, influence
