"""One learner update in the composite loss's stage order, each stage with its own optimiser (Algorithm 1)."""
from __future__ import annotations

import ctypes
import logging
from collections import Counter
from contextlib import nullcontext

import torch
from tensordict import TensorDict, TensorDictBase
from torchrl.objectives import SoftUpdate

from torchrl_mpail2.objectives import StagedLoss
from torchrl_mpail2.objectives.base import MPAIL2LossBase

log = logging.getLogger(__name__)

# glibc mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3
_MMAP_THRESHOLD_BYTES = 1 << 30
_TRIM_THRESHOLD_BYTES = (1 << 31) - 1


def nonfinite_keys(tensordict: TensorDictBase) -> list[str]:
    """Floating-point entries of ``tensordict`` holding NaN or Inf, as dotted names (``"next.observation"``).

    One host synchronisation for a finite batch (the per-entry flags are reduced on the device first); the entries
    are looked at one by one only when something is not finite."""
    floats = [(key, value) for key, value in tensordict.items(include_nested=True, leaves_only=True)
              if isinstance(value, torch.Tensor) and value.is_floating_point()]
    if not floats:
        return []
    finite = torch.stack([torch.isfinite(value).all() for _, value in floats])
    if bool(finite.all()):
        return []
    return [key if isinstance(key, str) else ".".join(key)
            for (key, _), ok in zip(floats, finite.tolist()) if not ok]


def retain_freed_memory() -> bool:
    """Lets glibc's malloc keep freed memory for reuse instead of handing it back to the OS.

    By default blocks over 32 MiB get fresh ``mmap`` pages and freed memory at the top of the heap is
    returned to the OS, so each update's large activations (e.g. ``[2, B*T*(H+1), 512]`` in the imagined
    rollouts, the first convolution's output with cameras) page-fault in new memory every time: that
    costs as much as the arithmetic on them here. Raising both thresholds keeps the peak heap mapped.
    Process-wide and idempotent; returns False where glibc's ``mallopt`` is not available (then nothing changes).
    """
    try:
        mallopt = ctypes.CDLL(None).mallopt  # the process's own symbols, glibc's among them
    except (OSError, AttributeError, TypeError):
        return False
    return bool(mallopt(_M_MMAP_THRESHOLD, _MMAP_THRESHOLD_BYTES)) and bool(mallopt(_M_TRIM_THRESHOLD, _TRIM_THRESHOLD_BYTES))


class MPAIL2Updater:
    """Runs the stages of a composite loss in its ``stages`` order on one batch, a step after each: for
    :class:`~torchrl_mpail2.objectives.MPAIL2Loss` dynamics -> reward -> value (+ Polyak) -> policy (+ alpha), for
    the model-free :class:`~torchrl_mpail2.objectives.DACLoss` the same without dynamics.

    Adam optimisers and gradient clips come from the loss's ``param_groups()`` (Table 4). A batch holding
    NaN or Inf anywhere is skipped as a whole before it touches any state (weights, optimisers, running
    reward scale), counted in ``skipped["batch"]`` and logged with its non-finite keys (also kept in
    ``last_nonfinite_keys``); :meth:`update` then returns None. A stage whose loss is not finite is skipped
    (no gradient step) and counted in ``skipped`` under its name, so that one bad batch cannot corrupt the weights.
    On a GPU that stage check costs no host synchronisation (``sync_free_skips``): fused Adam is handed the
    not-finite flag and leaves weights, moments and step count as they were, and the counts wait on the device
    until ``skipped`` is read; one synchronisation per update remains, for the batch check.

    Args:
        loss (StagedLoss): the composite loss.

    Keyword Args:
        retain_memory (bool): call :func:`retain_freed_memory` (process-wide; Linux/glibc only). Defaults to True.
        bf16 (bool): mixed precision for the whole update: each stage's forward pass (gradient penalty and
            stop-gradient parts included) runs under bfloat16 autocast, exited before the backward pass and the
            optimiser step; parameters, gradients, Adam's moments and the Polyak targets stay float32; the losses'
            stop-gradient latents and value targets come back in float32 (``MPAIL2LossBase.bf16_stop_gradient``).
            2-3x faster on CPUs with AVX-512 bf16 (docs/results/speed/speed_notes.md); losses move by up to about 2%
            (relative) on the test batches. Defaults to False (float32 throughout).
        sync_free_skips (bool, optional): skip not-finite stages without a host synchronisation (fused Adam, which
            takes the flag on the device). Defaults to None: on where the parameters are on a CUDA device; on a CPU a
            synchronisation costs nothing and the default Adam is kept.

    Examples:
        >>> from torchrl_mpail2.config import ModelConfig
        >>> from torchrl_mpail2.modules import MPAIL2Modules
        >>> from torchrl_mpail2.objectives import MPAIL2Loss
        >>> modules = MPAIL2Modules({"observation": [3]}, 2, ModelConfig(latent_dim=8, hidden_dims=(16,), coder_dim=16,
        ...                         vector_coder_hidden=16, horizon=3))
        >>> updater = MPAIL2Updater(MPAIL2Loss(modules))
        >>> o = lambda: torch.randn(4, 3, 3)
        >>> td = TensorDict({"observation": o(), "action": torch.rand(4, 3, 2) * 2 - 1, ("next", "observation"): o(),
        ...                  ("expert", "observation"): o(), ("expert", "next", "observation"): o()}, [4, 3])
        >>> metrics = updater.update(td)
        >>> sorted(k for k in metrics.keys() if k.startswith("loss_"))
        ['loss_actor', 'loss_alpha', 'loss_dynamics', 'loss_reward', 'loss_value']
    """

    def __init__(self, loss: StagedLoss, *, retain_memory: bool = True, bf16: bool = False,
                 sync_free_skips: bool | None = None):
        if retain_memory:
            retain_freed_memory()
        self.loss = loss
        self.bf16 = bf16
        self.device_type = next(loss.parameters()).device.type
        self.sync_free_skips = self.device_type == "cuda" if sync_free_skips is None else sync_free_skips
        for module in loss.modules():
            if isinstance(module, MPAIL2LossBase):
                module.bf16_stop_gradient = bf16
        self.optimizers: dict[str, torch.optim.Optimizer] = {}
        self.max_grad_norm: dict[str, float | None] = {}
        for stage, groups in loss.param_groups().items():
            self.max_grad_norm[stage] = groups[0]["max_grad_norm"]
            self.optimizers[stage] = torch.optim.Adam([{"params": g["params"], "lr": g["lr"]} for g in groups],
                                                      **({"fused": True} if self.sync_free_skips else {}))
        self.target_updater = SoftUpdate(loss.value_loss, tau=loss.cfg.tau)
        self._skipped: Counter[str] = Counter()
        self._pending_skips: dict[str, torch.Tensor] = {}  # per stage, on the device (sync_free_skips)
        self.last_nonfinite_keys: list[str] = []

    def _forward_precision(self):
        """bf16 autocast for one stage's forward pass (``bf16=True``), else nothing. Entered and left per stage:
        autocast caches its bf16 copies of the weights until the outermost context exits, so a context held
        across an optimiser step would hand the next stage stale weights."""
        if not self.bf16:
            return nullcontext()
        return torch.autocast(self.device_type, dtype=torch.bfloat16)

    def skip_nonfinite(self, *tensordicts: TensorDictBase | None) -> bool:
        """True (and counted, and logged with the keys) when any of the batches holds NaN or Inf."""
        bad = sorted({key for td in tensordicts if td is not None for key in nonfinite_keys(td)})
        if not bad:
            return False
        self._skipped["batch"] += 1
        self.last_nonfinite_keys = bad
        log.warning("skipping a batch with NaN or Inf under %s (%d batch(es) skipped so far)", bad,
                    self._skipped["batch"])
        return True

    @property
    def skipped(self) -> Counter[str]:
        """Skipped batches (``"batch"``) and stages (by name) so far; reading it synchronises with the device
        where counts are pending there."""
        for stage, count in self._pending_skips.items():
            self._skipped[stage] += int(count.item())
        self._pending_skips.clear()
        return +self._skipped  # without zero counts

    @skipped.setter
    def skipped(self, counts: Counter[str]) -> None:
        self._skipped, self._pending_skips = Counter(counts), {}

    def _step(self, stage: str, value: torch.Tensor) -> None:
        optimizer = self.optimizers[stage]
        if self.sync_free_skips:
            not_finite = (~torch.isfinite(value.detach())).float().reshape(())
            pending = self._pending_skips.get(stage)
            self._pending_skips[stage] = not_finite if pending is None else pending + not_finite
            optimizer.found_inf = not_finite  # fused Adam leaves every state as it was where this is 1
        elif not bool(torch.isfinite(value)):
            self._skipped[stage] += 1
            return
        optimizer.zero_grad(set_to_none=True)
        value.backward()
        clip = self.max_grad_norm[stage]
        if clip is not None:
            params = [p for g in optimizer.param_groups for p in g["params"]]
            torch.nn.utils.clip_grad_norm_(params, clip)
        optimizer.step()

    def update(self, tensordict: TensorDictBase, policy_tensordict: TensorDictBase | None = None) -> TensorDictBase | None:
        """One update on a replay batch ``[B, T]`` that carries expert pairs under ``"expert"``.

        Args:
            tensordict: the batch of every stage.
            policy_tensordict (optional): a separate batch for the reward, value and actor stages (the
                paper's [-O] ablation trains those on the latest episode only, the world model off-policy).

        Returns:
            TensorDict: every ``loss_*`` term and diagnostic, detached; None when the batch was skipped.
        """
        loss = self.loss
        windows, transitions = loss.stage_batches(tensordict, policy_tensordict)
        if self.skip_nonfinite(windows, transitions):
            return None
        metrics = TensorDict({}, [])
        for stage, out in loss.stage_outputs(tensordict, policy_tensordict, precision=self._forward_precision):
            self._step(stage, out[f"loss_{stage}"])
            if stage == "value":
                self.target_updater.step()
            elif stage == "actor":
                self._step("alpha", out["loss_alpha"])
            metrics.update(out)
        counted, pending = float(sum(self._skipped.values())), list(self._pending_skips.values())
        # pending counts stay on the device: filled there, not copied from the host (a blocking copy would wait)
        skips = torch.full((), counted, device=pending[0].device) + sum(pending) if pending else torch.tensor(counted)
        metrics.set("nonfinite_skips", skips)
        return metrics.apply(lambda x: x.detach().float())

    def state_dict(self) -> dict:
        return {"optimizers": {k: o.state_dict() for k, o in self.optimizers.items()}, "skipped": dict(self.skipped)}

    def load_state_dict(self, state: dict) -> None:
        for k, o in self.optimizers.items():
            o.load_state_dict(state["optimizers"][k])
            # the saving updater's Adam kernel is not necessarily this one's (a CPU checkpoint resumed on a GPU):
            # keep this updater's, with the step counts where its kernel keeps them (fused: beside the parameters;
            # plain: on the host, as a fresh plain Adam has them)
            for group in o.param_groups:
                group["fused"], group["foreach"] = (True if self.sync_free_skips else None), None
                for param in group["params"]:
                    step = o.state.get(param, {}).get("step")
                    if step is not None:
                        o.state[param]["step"] = step.to("cpu") if not self.sync_free_skips else step.to(
                            device=param.device, dtype=torch.float32)
        self.skipped = Counter(state.get("skipped", {}))  # the setter also drops pending counts
