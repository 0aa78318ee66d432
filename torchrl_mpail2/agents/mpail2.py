"""The MPAIL2 agent: networks, losses, optimisers and actor as one object with one state dict.

A training loop receives it (:class:`~torchrl_mpail2.trainers.MPAIL2Trainer`); evaluation, planning pictures and
the learned-reward transform load it from a checkpoint on their own (:meth:`MPAIL2Agent.from_checkpoint`), without
a run folder, a replay buffer or demonstrations.
"""
from __future__ import annotations

import dataclasses
import warnings
from pathlib import Path

import torch
from tensordict import TensorDictBase

from torchrl_mpail2.agents.update import MPAIL2Updater
from torchrl_mpail2.config import (AgentSwitches, LossConfig, ModelConfig, PlannerConfig, build_section,
                                   migrate_config_data, resolve_update_precision, switches_for, warn_if_bf16_emulated)
from torchrl_mpail2.data import Demonstrations
from torchrl_mpail2.data import checkpoint as ckpt
from torchrl_mpail2.modules.encoder import is_image_shape
from torchrl_mpail2.modules.factory import make_mpail2_modules
from torchrl_mpail2.objectives.model_free import DACLoss
from torchrl_mpail2.objectives.mpail2 import MPAIL2Loss
from torchrl_mpail2.planners.mppi import LatentMPPIPlanner
from torchrl_mpail2.planners.policy_actor import PolicyActor, WarmupSwitch

__all__ = ["MPAIL2Agent"]
#: The parts of :meth:`MPAIL2Agent.state_dict` (a training checkpoint's ``state.pt`` holds them at its top level).
AGENT_STATE_KEYS = ("modules", "loss", "updater", "planner", "observation_keys")
#: What :meth:`MPAIL2Agent.transfer_from` copies from another run: everything, or only the world model.
TRANSFER_PARTS = {"all": ("encoder", "dynamics", "reward", "value", "policy"), "world-model": ("encoder", "dynamics")}


class MPAIL2Agent:
    """Encoder, dynamics, reward, Q-ensemble and policy with their losses, optimisers and actor.

    Args:
        observation_spec (Composite): the environment's observation spec.
        action_spec (TensorSpec): its action spec (flat ``[A]``, bounded to ``[-1, 1]``).
        model (ModelConfig, optional): network sizes (Table 4).
        loss (LossConfig, optional): loss coefficients and learning rates (Table 4).
        planner (PlannerConfig, optional): latent MPPI settings (Table 4).

    Keyword Args:
        ablation (str): a Table 2 name resolved by :func:`~torchrl_mpail2.config.switches_for`
            (``"none"``: MPAIL2). Ignored when ``switches`` is given.
        switches (AgentSwitches, optional): the parts to use, directly.
        update_precision (str): ``float32`` | ``bf16`` (see :class:`MPAIL2Updater`) |
            ``auto`` (``bf16`` where the device runs it natively and no observation is an image, else ``float32``:
            :func:`resolve_update_precision`).
        demos (Demonstrations, optional): set the observation normalisation from the demonstrations and encode
            their keys.
        observation_keys (list[str], optional): the observation keys to encode (default: the demos' keys, else
            every observation of the spec).
        device (torch.device or str): where the networks live; the losses, optimisers and planner follow them, and
            inputs are expected there (default ``"cpu"``).

    Attributes:
        modules, loss, updater: the networks, the composite loss and the per-stage updater.
        planner (LatentMPPIPlanner or None): None for the model-free switches.
        actor (WarmupSwitch): what a collector drives: random warm-up actions, then the planner or the policy.
        policy: the deterministic acting module inside ``actor`` (what evaluation plays).

    Examples:
        >>> from torchrl_mpail2.envs import make_env
        >>> env = make_env("point_mass")
        >>> model = ModelConfig(latent_dim=8, hidden_dims=(16,), coder_dim=16, vector_coder_hidden=16, horizon=3)
        >>> agent = MPAIL2Agent(env.observation_spec, env.action_spec, model,
        ...                     planner=PlannerConfig(num_candidates=16, num_elites=4, iterations=2))
        >>> td = agent.actor(env.reset())
        >>> td["action"].shape
        torch.Size([2])
    """

    def __init__(self, observation_spec, action_spec, model: ModelConfig | None = None,
                 loss: LossConfig | None = None, planner: PlannerConfig | None = None, *, ablation: str = "none",
                 switches: AgentSwitches | None = None, update_precision: str = "float32",
                 demos: Demonstrations | None = None, observation_keys: list[str] | None = None,
                 device: torch.device | str = "cpu"):
        self.switches = switches or switches_for(ablation)
        model, loss, planner = model or ModelConfig(), loss or LossConfig(), planner or PlannerConfig()
        if planner.bf16 and self.switches.world_model:
            warn_if_bf16_emulated("planner.bf16=True", device)
        policy_horizon = self.switches.policy_horizon(model.horizon, model.policy_horizon)
        # the model-free ablations act with a single-step policy, as in the paper's baselines
        model = dataclasses.replace(model, horizon=policy_horizon, policy_horizon=policy_horizon)
        self.modules = make_mpail2_modules(observation_spec, action_spec, model, observation_keys,
                                           demos=demos).to(device)
        images = any(is_image_shape(shape) for shape in self.modules.encoder.net.shapes.values())
        if images and planner.bf16 and self.switches.world_model:
            warnings.warn("planner.bf16=True with image observations: bf16 rounding moves a camera latent more than a "
                          "small object in the picture does (see resolve_update_precision); plan in float32",
                          RuntimeWarning, stacklevel=2)
        update_precision = resolve_update_precision(update_precision, device, world_model=self.switches.world_model,
                                                    images=images)
        if self.switches.world_model:
            self.loss = MPAIL2Loss(self.modules, loss)
            self.updater = MPAIL2Updater(self.loss, bf16=update_precision == "bf16")
            self.planner = LatentMPPIPlanner(self.modules, action_spec, planner, gamma=loss.gamma)
        else:
            self.loss, self.planner = DACLoss(self.modules, loss), None
            self.updater = MPAIL2Updater(self.loss)
        policy = self.planner if self.switches.act_with == "planner" else PolicyActor(self.modules)
        self.actor = WarmupSwitch(policy, action_spec)

    @property
    def policy(self):
        """The deterministic acting module (planner or policy actor), without the warm-up switch."""
        return self.actor.actor

    @property
    def random_actions(self) -> bool:
        """Whether :attr:`actor` acts at random (Algorithm 1's warm-up episodes) rather than with :attr:`policy`."""
        return self.actor.random_actions

    @random_actions.setter
    def random_actions(self, value: bool) -> None:
        self.actor.random_actions = value

    def update(self, tensordict: TensorDictBase, policy_tensordict: TensorDictBase | None = None):
        """One learner update, every stage of Algorithm 1's inner loop (see :meth:`MPAIL2Updater.update`): the
        ``loss_*`` terms and diagnostics, or None when the batch held NaN or Inf and was skipped whole (its
        non-finite keys are then in :attr:`last_nonfinite_keys`)."""
        return self.updater.update(tensordict, policy_tensordict)

    @property
    def skipped(self) -> dict[str, int]:
        """Updates skipped so far: whole batches under ``"batch"``, single stages under their names."""
        return dict(self.updater.skipped)

    @property
    def last_nonfinite_keys(self) -> list[str]:
        """The non-finite keys of the last batch :meth:`update` skipped."""
        return list(self.updater.last_nonfinite_keys)

    def stats(self) -> dict[str, float]:
        """The acting statistics since the last call (planner figures averaged over its calls, ``act_s`` the
        acting seconds), then reset."""
        return self.actor.pop_stats()

    def state_dict(self) -> dict:
        return {"modules": self.modules.state_dict(), "loss": self.loss.state_dict(),
                "updater": self.updater.state_dict(),
                "planner": self.planner.get_extra_state() if self.planner is not None else None,
                "observation_keys": list(self.modules.encoder.in_keys)}

    def load_state_dict(self, state: dict, *, with_optimizers: bool = True) -> None:
        """Restores networks, loss state (``log_alpha``, targets, reward scale), planner warm start and, with
        ``with_optimizers``, the optimisers."""
        load_weights(self.modules, state["modules"], "the checkpoint")
        self.loss.load_state_dict(state["loss"])
        if with_optimizers:
            self.updater.load_state_dict(state["updater"])
        if self.planner is not None and state.get("planner") is not None:
            self.planner.set_extra_state(state["planner"])

    def transfer_from(self, path: str | Path, transfer: str = "all", config: dict | None = None) -> None:
        """Copies the networks of another run's checkpoint: ``all`` of them (the value targets too) or only the
        ``world-model`` (encoder and dynamics); optimisers and loss state stay as they are.

        Args:
            path: the checkpoint folder (verified against its manifest).
            transfer (str): ``"all"`` or ``"world-model"``.
            config (dict, optional): this run's config (sections of dicts): the checkpoint's must agree on the
                fields that shape the networks (:data:`~torchrl_mpail2.data.checkpoint.NETWORK_FIELDS` but
                ``train.env``: transfer goes to another task).

        Raises:
            CheckpointError: the checkpoint is damaged, or its networks differ from this agent's (the message
                names the config fields, or the parameters and their shapes).
        """
        if transfer not in TRANSFER_PARTS:
            raise ValueError(f"transfer must be one of {sorted(TRANSFER_PARTS)}, got {transfer!r}")
        state = ckpt.read_checkpoint(path)
        if config is not None and isinstance(state.get("config"), dict):
            # network fields only: a removed loss or planner field does not stop the weights' transfer
            ckpt.check_compatible(state["config"], config, Path(path), ignore=("train.env",))
        weights = state["modules"]
        for part in TRANSFER_PARTS[transfer]:
            prefix = part + "."
            load_weights(getattr(self.modules, part), {k[len(prefix):]: v for k, v in weights.items()
                                                       if k.startswith(prefix)}, f"{path} ({part})")
        if transfer == "all":
            value_loss = self.loss.value_loss
            value_loss.target_qvalue_network_params.data.update_(value_loss.qvalue_network_params.data)

    @classmethod
    def from_checkpoint(cls, path: str | Path, env=None, *, with_optimizers: bool = False,
                        device: torch.device | str = "cpu") -> "MPAIL2Agent":
        """The agent of a training checkpoint (``RUN/checkpoints/best``, ``.../last`` or ``.../episode_N``).

        Args:
            path: the checkpoint folder (verified against its manifest).
            env (EnvBase, optional): an environment with the run's specs; default: the run's own, built from the
                checkpoint's config (``train.env``, ``train.obs``, ``train.env_kwargs``) and closed again.

        Keyword Args:
            with_optimizers (bool): restore the optimisers too (to go on training). Defaults to False.
            device (torch.device or str): where to load the networks (default ``"cpu"``, wherever they were saved).

        Returns:
            MPAIL2Agent: with ``run_config``, the run's config as saved (a dict of sections).

        Raises:
            CheckpointError: the checkpoint is missing or damaged (the message names the file).
        """
        path = Path(path)
        return cls.from_state(ckpt.read_checkpoint(path), env, source=path, with_optimizers=with_optimizers,
                              device=device)

    @classmethod
    def from_state(cls, state: dict, env=None, *, source: str | Path = "the checkpoint", with_optimizers: bool = False,
                   device: torch.device | str = "cpu") -> "MPAIL2Agent":
        """:meth:`from_checkpoint` on a checkpoint's state already read (``source`` names it in errors)."""
        config = run_config_of(state, source)
        train = config["train"]
        own_env = env is None
        if own_env:
            from torchrl_mpail2.envs import make_env

            env = make_env(train["env"], obs=train["obs"], **(train.get("env_kwargs") or {}))
        try:
            agent = cls(env.observation_spec, env.action_spec, build_section(ModelConfig, config["model"]),
                        build_section(LossConfig, config["loss"]), build_section(PlannerConfig, config["planner"]),
                        ablation=train.get("ablation", "none"),
                        update_precision=train.get("update_precision", "float32"),
                        observation_keys=state.get("observation_keys"), device=device)
            agent.load_state_dict(state, with_optimizers=with_optimizers)
        except (ckpt.CheckpointError, KeyError, ValueError) as error:
            if own_env:
                raise
            raise ckpt.CheckpointError(f"{source} was written for train.env={train['env']!r} (train.obs="
                                       f"{train['obs']!r}); the env given ({_describe_specs(env)}) does not fit it: "
                                       f"{error}") from error
        finally:
            if own_env:
                env.close()
        agent.run_config = config
        return agent


def run_config_of(state: dict, source: str | Path) -> dict:
    """The run config a checkpoint's ``state`` holds, in today's fields (:func:`migrate_config_data`).

    Raises:
        CheckpointError: it holds none (sections train, model, loss, planner), naming ``source``.
    """
    config = state.get("config")
    if not isinstance(config, dict) or not {"train", "model", "loss", "planner"} <= set(config):
        raise ckpt.CheckpointError(f"{source} holds no run config (sections train, model, loss, planner)")
    return migrate_config_data(config)


def load_weights(module: torch.nn.Module, weights: dict, source: str) -> None:
    """``module.load_state_dict(weights)`` (its hooks fill what older checkpoints lack), refused with every differing
    parameter named (its shape in ``source`` and here) instead of PyTorch's size-mismatch error.

    Raises:
        CheckpointError: a parameter is missing, extra or of another shape.
    """
    try:
        module.load_state_dict(weights)
    except RuntimeError as error:
        own = module.state_dict()
        differ = [f"{name}: {tuple(weights[name].shape)} in {source}, {tuple(own[name].shape)} here"
                  for name in own if name in weights and weights[name].shape != own[name].shape]
        differ += [f"{name}: absent from {source}" for name in own if name not in weights]
        differ += [f"{name}: in {source}, absent here" for name in weights if name not in own]
        shown = differ[:8] + ([f"... and {len(differ) - 8} more"] if len(differ) > 8 else []) or [str(error)]
        raise ckpt.CheckpointError(f"the networks of {source} differ from this agent's:\n  "
                                   + "\n  ".join(shown)) from error


def _describe_specs(env) -> str:
    """``observations {key: shape}, actions shape`` of an env, for error messages."""
    shapes = {key: tuple(spec.shape) for key, spec in env.observation_spec.items(True, True)}
    return f"observations {shapes}, actions {tuple(env.action_spec.shape)}"
