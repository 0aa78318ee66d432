r"""Acting with the multi-step policy alone (the paper's [-P] ablation) and random warm-up actions."""
from __future__ import annotations

import time

import torch
from tensordict import TensorDictBase
from tensordict.nn import TensorDictModuleBase

from torchrl_mpail2.modules.encoder import validate_observations
from torchrl_mpail2.modules.factory import MPAIL2Modules
from torchrl_mpail2.modules.policy import is_deterministic


class NonFiniteActionError(FloatingPointError):
    """The learner's actor (planner or policy) returned NaN or Inf actions: its networks have diverged."""


class PolicyActor(TensorDictModuleBase):
    r"""Acts with the first step of :math:`\pi_\phi(\cdot \mid e_\omega(o_t))` (no planner).

    Writes ``"action"`` and ``"plan"`` like :class:`LatentMPPIPlanner`, so that either can drive a collector.
    """

    def __init__(self, modules: MPAIL2Modules, action_key="action"):
        super().__init__()
        self.__dict__["components"] = modules
        self.in_keys = list(modules.encoder.in_keys)
        self.out_keys = [action_key, "plan"]
        self.extra_out_shapes = {"plan": (modules.cfg.horizon, modules.action_dim)}

    @torch.no_grad()
    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        m = self.components
        validate_observations(tensordict, m.encoder.observation_shapes)
        plan, _ = m.pi(m.encode(tensordict), deterministic=is_deterministic())
        tensordict.set("plan", plan)
        tensordict.set(self.out_keys[0], plan[..., 0, :])
        return tensordict


class WarmupSwitch(TensorDictModuleBase):
    """Wraps an actor; while ``random_actions`` is set it writes uniform random actions instead.

    Lets one collector run the paper's random warm-up episodes and then the planner. Random steps also
    write zeros for the actor's other outputs (``extra_out_shapes``), since collectors and replay storages
    lay out their buffers from the first step.

    Non-finite actions of the wrapped actor raise :class:`NonFiniteActionError` before they reach the environment.

    The switch is kept in a (non-persistent) boolean buffer behind the ``random_actions`` property, so that
    ``TensorDict.from_module`` of the actor carries it: a copy acting in another process (a Ray worker,
    :mod:`torchrl_mpail2.trainers.ray_collection`) follows the learner's warm-up with the weights it receives.

    It also keeps running sums over the wrapped actor's calls, read and reset by :meth:`pop_stats`: the time
    spent acting and, for a planner, its ``last_stats`` (elite return, plan std), summed as tensors so that
    acting never waits on a host sync.
    """

    #: planner statistics the trainer logs (``policy_influence`` comes per step from the tensordict)
    PLANNER_STATS = ("elite_return", "plan_std", "elite_ess")

    def __init__(self, actor: TensorDictModuleBase, action_spec, random_actions: bool = False):
        super().__init__()
        self.actor = actor
        self.action_spec = action_spec
        self.register_buffer("_random_actions", torch.tensor(bool(random_actions)), persistent=False)
        self.in_keys = list(actor.in_keys)
        self.out_keys = list(actor.out_keys)
        self._sums: dict = {}
        self._calls = self._actions = 0
        self._seconds = 0.0

    @property
    def random_actions(self) -> bool:
        """Whether the next steps take uniform random actions (the paper's warm-up)."""
        return bool(self._random_actions)

    @random_actions.setter
    def random_actions(self, value: bool) -> None:
        self._random_actions.fill_(bool(value))

    def pop_stats(self) -> dict[str, float]:
        """Means of the planner statistics, ``actions_per_s`` and the seconds spent acting (``act_s``) since the
        last call (empty if nothing acted)."""
        out = {}
        if self._calls:
            out = {name: float(total) / self._calls for name, total in self._sums.items()}
            out["actions_per_s"] = self._actions / max(self._seconds, 1e-9)
            out["act_s"] = self._seconds
        self._sums, self._calls, self._actions, self._seconds = {}, 0, 0, 0.0
        return out

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        if self.random_actions:
            shape = tensordict.batch_size
            action = self.action_spec.rand(shape)
            tensordict.set(self.out_keys[0], action)
            for key, key_shape in getattr(self.actor, "extra_out_shapes", {}).items():
                tensordict.set(key, action.new_zeros(*shape, *key_shape))
            return tensordict
        start = time.perf_counter()
        out = self.actor(tensordict)
        action = out.get(self.out_keys[0])
        if not bool(torch.isfinite(action).all()):
            raise NonFiniteActionError(f"{type(self.actor).__name__} returned non-finite actions "
                                       f"({int((~torch.isfinite(action)).sum())} of {action.numel()} entries): "
                                       "its networks or the reward scale hold NaN or Inf.")
        self._seconds += time.perf_counter() - start
        self._calls += 1
        self._actions += max(1, tensordict.batch_size.numel())
        stats = getattr(self.actor, "last_stats", {})
        for name in self.PLANNER_STATS:
            if name in stats:
                self._sums[name] = self._sums.get(name, 0) + stats[name]
        return out
