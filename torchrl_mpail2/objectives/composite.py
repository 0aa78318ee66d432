r"""Base of the composite losses: objectives optimised one after another, in one order (Algorithm 1)."""
from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import AbstractContextManager, nullcontext

from tensordict import TensorDict, TensorDictBase

from torchrl_mpail2.objectives.base import MPAIL2LossBase, sample_window_transitions

#: Stages that read whole ``[B, T]`` windows (the world model's multi-step prediction, Eq. 2); every other stage
#: reads ``cfg.transitions_per_window`` random transitions of each window.
WINDOW_STAGES = ("dynamics",)


class StagedLoss(MPAIL2LossBase):
    r"""A composite loss whose objectives are optimised one after another, each with its own optimiser.

    ``stages`` is the update order: the one list that :meth:`forward` and
    :class:`~torchrl_mpail2.agents.MPAIL2Updater` both follow. Stage ``s`` is computed by the sub-loss
    ``<s>_loss``, returns ``loss_<s>`` and has an entry in :meth:`param_groups` (which also holds ``alpha``,
    stepped after ``actor``). The transition stages share one set of stop-gradient latents, encoded when the
    first of them runs, i.e. after the ``dynamics`` stage (in MPAIL2 the only one that changes the encoder).

    Subclasses set ``stages``, ``cfg`` (a :class:`~torchrl_mpail2.config.LossConfig`) and the sub-losses.
    """

    stages: tuple[str, ...] = ()

    def set_image_shift(self, pad: int) -> None:
        """Random-shift augmentation of camera frames (``LossConfig.image_shift``) in this loss and its objectives."""
        for module in self.modules():
            if isinstance(module, MPAIL2LossBase):
                module.image_shift = int(pad)

    def set_keys(self, **kwargs) -> None:
        super().set_keys(**kwargs)
        for stage in self.stages:
            getattr(self, f"{stage}_loss").set_keys(**kwargs)

    def stage_batches(self, tensordict: TensorDictBase, policy_tensordict: TensorDictBase | None = None
                      ) -> tuple[TensorDictBase | None, TensorDictBase]:
        """``(windows, transitions)``: the batch of the window stages (None when there is none) and the one the
        transition stages draw from (``policy_tensordict`` where given: the paper's [-O] ablation trains the
        reward, value and policy on the latest episode only)."""
        windows = tensordict if any(stage in WINDOW_STAGES for stage in self.stages) else None
        return windows, policy_tensordict if policy_tensordict is not None else tensordict

    def stage_outputs(self, tensordict: TensorDictBase, policy_tensordict: TensorDictBase | None = None,
                      precision: Callable[[], AbstractContextManager] = nullcontext,
                      ) -> Iterator[tuple[str, TensorDictBase]]:
        """Yields ``(stage, output)`` in ``stages`` order, computing each stage only when the previous one has
        been consumed, so that an optimiser step taken between two items reaches the next stage.

        Args:
            tensordict: ``[B, T]`` replay windows with expert pairs under ``"expert"``.
            policy_tensordict (optional): the batch of the transition stages (see :meth:`stage_batches`).
            precision: a context factory entered around each stage's forward pass and left before it is
                yielded (the updater's bf16 autocast).
        """
        windows, transitions = self.stage_batches(tensordict, policy_tensordict)
        latents = None
        for stage in self.stages:
            sub = getattr(self, f"{stage}_loss")
            if stage in WINDOW_STAGES:
                with precision():
                    out = sub(windows)
            else:
                if latents is None:
                    transitions = sample_window_transitions(transitions, self.cfg.transitions_per_window)
                    with precision():
                        latents = self.replay_latents(transitions)
                with precision():
                    out = sub(transitions, latents=latents)
            yield stage, out

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        """Every stage's terms and diagnostics, all from the same parameters (no step in between)."""
        out = TensorDict({}, [])
        for _, stage_out in self.stage_outputs(tensordict):
            out.update(stage_out)
        return out
