r"""A replay-buffer transform that puts expert observation windows beside each sampled sub-trajectory."""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import torch
from tensordict import TensorDictBase
from tensordict.utils import NestedKey
from torchrl.envs.transforms import Transform

from torchrl_mpail2.data.demo_buffer import DemoBuffer
from torchrl_mpail2.data.demos import Demonstrations

__all__ = ["TRAJ_KEY", "AttachExpertWindows"]

#: Where TorchRL's collectors write trajectory ids, the key ``SliceSampler(traj_key=...)`` cuts slices by.
TRAJ_KEY = ("collector", "traj_ids")


class AttachExpertWindows(Transform):
    r"""Writes ``H``-step expert observation windows under ``"expert"`` beside every ``H``-step replay slice.

    The adversarial reward (Eq. 3) contrasts replayed transitions with expert pairs :math:`(o^E, o'^E)`;
    :class:`~torchrl_mpail2.objectives.MPAIL2Loss` reads them under ``("expert", key)`` and
    ``("expert", "next", key)``, laid out like the replayed batch. Appended to a ``TensorDictReplayBuffer``
    whose ``SliceSampler(slice_len=H)`` returns ``B`` slices as one flat ``[B * H]`` sample, this transform
    adds ``B`` windows of ``H`` consecutive transitions of one demonstration episode each, in the same flat
    order, so that ``sample.reshape(-1, H)`` is the ``[B, H]`` batch the loss takes, slice ``b`` beside
    expert window ``b``. A sample shaped ``[*B, H]`` already (a transform called on a reshaped sample, a
    2-D storage) gets ``[*B, H]`` windows.

    The transform leaves the sample's shape as it is: ``TensorDictReplayBuffer.sample`` writes the sampler's
    info (``"index"``, the ``SliceSampler``'s ``("next", "truncated")`` flags) into the sample after the
    transforms have run, and fails on a sample whose batch shape a transform changed. Indexing the buffer
    (``replay[i]``) runs its transforms too: read stored steps with ``replay.storage[i]``.

    When the sample holds trajectory ids (``traj_ids``, by default ``("collector", "traj_ids")``), each
    window of ``H`` steps must lie in one trajectory, which catches a sampler whose ``slice_len`` differs
    from ``horizon`` (use ``strict_length=True`` so that no slice comes back short).

    Args:
        demos (DemoBuffer or Demonstrations): where expert windows are drawn from (a :class:`DemoBuffer`
            is built around plain demonstrations; its generator is then seeded from the global torch RNG).
        horizon (int): ``H``, the length of each replay slice and expert window.

    Keyword Args:
        out_key (NestedKey): where the windows go. Defaults to ``"expert"`` (the loss's ``expert`` key).

    Raises:
        ValueError: ``horizon`` is below 1, or no demonstration episode has ``horizon`` steps.

    Examples:
        >>> import torch
        >>> from tensordict import TensorDict
        >>> from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
        >>> from torchrl.data.replay_buffers import SliceSampler
        >>> from torchrl_mpail2.data import demos_from_arrays
        >>> demos = demos_from_arrays([torch.arange(11.0).unsqueeze(-1)])  # one expert episode of 10 steps
        >>> replay = TensorDictReplayBuffer(storage=LazyTensorStorage(100), batch_size=4 * 3,
        ...     sampler=SliceSampler(slice_len=3, traj_key=TRAJ_KEY, strict_length=True))
        >>> _ = replay.append_transform(AttachExpertWindows(demos, horizon=3))
        >>> _ = replay.extend(TensorDict({"observation": torch.randn(20, 1), ("next", "observation"): torch.randn(20, 1),
        ...                               TRAJ_KEY: torch.arange(20) // 10}, [20]))
        >>> batch = replay.sample().reshape(-1, 3)
        >>> batch.shape, batch["expert", "observation"].shape
        (torch.Size([4, 3]), torch.Size([4, 3, 1]))
        >>> bool((batch["expert", "next", "observation"] == batch["expert", "observation"] + 1).all())
        True
    """

    @dataclass
    class _AcceptedKeys:
        """Configurable tensordict keys (``transform.set_keys(expert=("demo", "expert"))``).

        Attributes:
            expert (NestedKey): prefix the windows are written under. Defaults to ``"expert"``.
            next (NestedKey): prefix of the next observations inside a window. Defaults to ``"next"``.
            traj_ids (NestedKey): trajectory ids of the replayed steps, checked when present.
                Defaults to ``("collector", "traj_ids")``.
        """

        expert: NestedKey = "expert"
        next: NestedKey = "next"
        traj_ids: NestedKey = TRAJ_KEY

    def __init__(self, demos: DemoBuffer | Demonstrations, horizon: int, *, out_key: NestedKey = "expert"):
        if isinstance(horizon, bool) or not isinstance(horizon, int) or horizon < 1:
            raise ValueError(f"AttachExpertWindows: horizon must be an integer >= 1, got {horizon!r}")
        self.tensor_keys = self._AcceptedKeys(expert=out_key)
        super().__init__(in_keys=[], out_keys=[out_key])
        self.demo_buffer = demos if isinstance(demos, DemoBuffer) else DemoBuffer(demos)
        self.horizon = horizon
        try:
            self.demo_buffer.num_windows(horizon)
        except ValueError as error:
            raise ValueError(f"AttachExpertWindows(horizon={horizon}): {error}") from error

    def set_keys(self, **kwargs: NestedKey) -> None:
        """Remaps the keys of :class:`_AcceptedKeys` (``expert``, ``next``, ``traj_ids``)."""
        accepted = [field.name for field in dataclasses.fields(self._AcceptedKeys)]
        for name, key in kwargs.items():
            if name not in accepted:
                raise ValueError(f"AttachExpertWindows: {name!r} is not an accepted key; accepted: {accepted}")
            setattr(self.tensor_keys, name, key)
        self.out_keys = [self.tensor_keys.expert]

    def _windows_shape(self, tensordict: TensorDictBase) -> torch.Size:
        """``[*B]``, the leading shape of the sample's windows, or a ValueError naming the sample's shape."""
        shape, H = tensordict.batch_size, self.horizon
        if len(shape) == 1 and shape[0] % H == 0:
            return torch.Size([shape[0] // H])
        if len(shape) >= 2 and shape[-1] == H:
            return shape[:-1]
        raise ValueError(f"AttachExpertWindows(horizon={H}): the replay sample has batch shape {list(shape)}; "
                         f"expected [B * {H}] (B flat slices of SliceSampler(slice_len={H})) or [*B, {H}]")

    def _check_slices(self, tensordict: TensorDictBase, num_windows: int) -> None:
        key = self.tensor_keys.traj_ids
        ids = tensordict.get(key, None)
        if ids is None or num_windows == 0:
            return
        ids = ids.reshape(num_windows, self.horizon, -1)
        crossing = (ids != ids[:, :1]).flatten(1).any(-1)
        if bool(crossing.any()):
            raise ValueError(
                f"AttachExpertWindows(horizon={self.horizon}): {int(crossing.sum())} of {num_windows} windows of the "
                f"replay sample change {key!r} within {self.horizon} steps: sample with SliceSampler(slice_len="
                f"{self.horizon}, traj_key={key!r}, strict_length=True)")

    def forward(self, tensordict: TensorDictBase) -> TensorDictBase:
        lead = self._windows_shape(tensordict)
        self._check_slices(tensordict, lead.numel())
        windows = self.demo_buffer.sample_windows(lead.numel(), self.horizon)  # [n, H], rows in sample order
        if self.tensor_keys.next != "next":
            windows.set(self.tensor_keys.next, windows.pop("next"))
        if tensordict.device is not None and windows.device != tensordict.device:
            windows = windows.to(tensordict.device)
        tensordict.set(self.tensor_keys.expert, windows.reshape(tensordict.batch_size))
        return tensordict

    _NOT_FOR_ENVS = "AttachExpertWindows is a replay-buffer transform: append it to a replay buffer, not to an environment"

    def _call(self, next_tensordict: TensorDictBase) -> TensorDictBase:
        raise RuntimeError(self._NOT_FOR_ENVS)

    def transform_output_spec(self, output_spec):
        raise RuntimeError(self._NOT_FOR_ENVS)

    def __repr__(self) -> str:
        return f"{type(self).__name__}(horizon={self.horizon}, out_key={self.tensor_keys.expert!r})"
