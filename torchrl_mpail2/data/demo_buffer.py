r"""Sampling expert transitions :math:`(o, o')` and windows from observation-only demonstrations."""
from __future__ import annotations

from collections.abc import Sequence

import torch
from tensordict import TensorDict

from torchrl_mpail2.data.demos import Demonstrations

__all__ = ["DemoBuffer"]


class DemoBuffer:
    r"""Uniform sampler of expert observation pairs and windows that never crosses episode boundaries.

    Samples are laid out like TorchRL transitions but hold observations only:
    ``{key: [B, ...], ("next", key): [B, ...]}`` for pairs and ``[B, L, ...]`` for windows, with
    ``td["next", key][:, t] == td[key][:, t + 1]`` inside a window.

    Args:
        demos (Demonstrations): the demonstrations (their observations are copied to ``device``; kept as ``demos``).
        device (torch.device or str): where samples live. Defaults to ``"cpu"``.
        generator (torch.Generator, optional): source of the sampled indices. If ``None``, a CPU
            generator seeded from the global torch RNG (so :func:`torch.manual_seed` controls it).

    Examples:
        >>> import torch
        >>> from torchrl_mpail2.data.demos import demos_from_arrays
        >>> steps = torch.arange(6.0).unsqueeze(-1)  # one episode whose observation is the time step
        >>> buffer = DemoBuffer(demos_from_arrays([steps]), generator=torch.Generator().manual_seed(0))
        >>> pairs = buffer.sample_pairs(8)
        >>> bool((pairs["next", "observation"] == pairs["observation"] + 1).all())
        True
        >>> buffer.sample_windows(2, 3).shape
        torch.Size([2, 3])
    """

    def __init__(
        self,
        demos: Demonstrations,
        device: torch.device | str = "cpu",
        generator: torch.Generator | None = None,
    ) -> None:
        self.device = torch.device(device)
        self.demos = demos
        self.keys = list(demos.observation_keys)
        self.observations = demos.observations.select(*self.keys).to(self.device)
        if generator is None:
            generator = torch.Generator().manual_seed(int(torch.randint(0, 2**62, ()).item()))
        self.generator = generator
        self._lengths = torch.tensor(demos.episode_lengths, dtype=torch.long)
        self._first = torch.tensor([int(meta["first_observation"]) for meta in demos.header["episodes"]])
        self._window_starts: dict[int, torch.Tensor] = {}

    def __len__(self) -> int:
        """Number of distinct ``(o, o')`` pairs."""
        return int(self._lengths.sum())

    def _starts(self, length: int) -> torch.Tensor:
        """Flat indices ``i`` such that observations ``i .. i + length`` lie in one episode."""
        if length not in self._window_starts:
            per_episode = [
                first + torch.arange(int(steps) - length + 1)
                for first, steps in zip(self._first.tolist(), self._lengths.tolist())
                if steps >= length
            ]
            if not per_episode:
                raise ValueError(f"No episode has {length} steps (longest: {int(self._lengths.max())}).")
            self._window_starts[length] = torch.cat(per_episode)
        return self._window_starts[length]

    def num_windows(self, length: int) -> int:
        """Number of distinct windows of ``length`` transitions; ValueError when no episode has ``length`` steps."""
        if length < 1:
            raise ValueError(f"length must be >= 1, got {length}.")
        return len(self._starts(length))

    def _draw(self, starts: torch.Tensor, batch_size: int) -> torch.Tensor:
        choice = torch.randint(len(starts), (batch_size,), generator=self.generator, device=self.generator.device)
        return starts[choice.cpu()].to(self.device)

    def _gather(self, index: torch.Tensor) -> TensorDict:
        # index: [*batch] flat positions of o; o' is the next stored observation of the same episode.
        current = self.observations[index]
        following = self.observations[index + 1]
        sample = current.clone(recurse=False)
        sample.set("next", following)
        return sample

    def sample_pairs(self, batch_size: int) -> TensorDict:
        """I.i.d. uniform transitions ``(o, o')`` from within episodes, as a ``[B]`` TensorDict."""
        return self._gather(self._draw(self._starts(1), batch_size))

    def sample_windows(self, batch_size: int, length: int) -> TensorDict:
        """Contiguous windows of ``length`` transitions from within one episode, as a ``[B, L]`` TensorDict."""
        if length < 1:
            raise ValueError(f"length must be >= 1, got {length}.")
        starts = self._draw(self._starts(length), batch_size)
        offsets = torch.arange(length, device=self.device)
        return self._gather(starts.unsqueeze(-1) + offsets)

    def observation_stats(self, keys: Sequence | None = None) -> dict:
        """:meth:`Demonstrations.observation_stats` of the buffer's demonstrations, on the buffer's device.

        Floors ``std`` at ``MIN_STD``.
        """
        return {key: (mean.to(self.device), std.to(self.device))
                for key, (mean, std) in self.demos.observation_stats(keys).items()}
