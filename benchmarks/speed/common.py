"""Shared pieces of the speed benchmarks: configurations, batches, GEMM ceilings, machine load."""
from __future__ import annotations

import os
import platform
import statistics
import time
from dataclasses import dataclass

import torch
from tensordict import TensorDict

from torchrl_mpail2.config import ModelConfig
from torchrl_mpail2.modules import MPAIL2Modules

IMAGE = (3, 64, 64)


@dataclass(frozen=True)
class Setting:
    """Network sizes and observations of one benchmark configuration."""

    name: str
    latent_dim: int
    hidden: int
    observations: dict
    action_dim: int
    note: str
    coder_dims: tuple[int, int] | None = None
    """``(vector_coder_hidden, coder_dim)``; None keeps :class:`ModelConfig`'s (Table 4)."""

    def modules(self, seed: int = 0) -> MPAIL2Modules:
        torch.manual_seed(seed)
        coders = {} if self.coder_dims is None else dict(zip(("vector_coder_hidden", "coder_dim"), self.coder_dims))
        cfg = ModelConfig(latent_dim=self.latent_dim, hidden_dims=(self.hidden, self.hidden), **coders)
        return MPAIL2Modules(self.observations, self.action_dim, cfg)


SETTINGS = {
    "paper": Setting("paper", 512, 512, {"proprio": [26], "object": [10]}, 4,
                     "Table 4 networks (latent 512, hidden [512, 512]), robosuite Lift state observations, A=4"),
    "state": Setting("state", 256, 256, {"observation": [11]}, 3,
                     "Hopper-size networks (latent 256, hidden [256, 256]), Hopper observations, A=3"),
    "cameras": Setting("cameras", 512, 512, {"proprio": [26], "external_image": list(IMAGE), "wrist_image": list(IMAGE)}, 4,
                       "Table 4 networks, proprio [26] + two 64x64 uint8 cameras, A=4"),
    "cameras_cpu": Setting("cameras_cpu", 128, 256, {"proprio": [27], "external_image": list(IMAGE),
                                                      "wrist_image": list(IMAGE)}, 3,
                           "the CPU presets' networks (latent 128, hidden [256, 256], coders 128 / 256), proprio [27] "
                           "+ two 64x64 uint8 cameras, A=3 (Push)", (128, 256)),
}


def random_observations(shapes: dict, *batch: int) -> dict:
    out = {}
    for key, shape in shapes.items():
        if len(shape) == 3:
            out[key] = torch.randint(0, 256, (*batch, *shape), dtype=torch.uint8)
        else:
            out[key] = torch.randn(*batch, *shape)
    return out


def replay_batch(setting: Setting, batch: int, steps: int, seed: int = 1) -> TensorDict:
    """A ``[B, T]`` batch laid out like the trainer's: contiguous windows, expert windows under ``"expert"``."""
    torch.manual_seed(seed)
    agent = random_observations(setting.observations, batch, steps + 1)
    expert = random_observations(setting.observations, batch, steps + 1)
    data = {"action": torch.rand(batch, steps, setting.action_dim) * 2 - 1,
            ("next", "terminated"): torch.zeros(batch, steps, 1, dtype=torch.bool)}
    for key in setting.observations:
        data[key], data[("next", key)] = agent[key][:, :-1], agent[key][:, 1:]
        data[("expert", key)], data[("expert", "next", key)] = expert[key][:, :-1], expert[key][:, 1:]
    return TensorDict(data, [batch, steps])


def gemm_ceiling(rows: int, inner: int, cols: int, dtype: torch.dtype, seconds: float = 1.0) -> float:
    """Best GFLOP/s of ``[rows, inner] @ [inner, cols]`` in ``dtype`` over about ``seconds``."""
    a = torch.randn(rows, inner).to(dtype)
    b = torch.randn(inner, cols).to(dtype)
    a @ b
    best, start = float("inf"), time.perf_counter()
    while time.perf_counter() - start < seconds:
        t = time.perf_counter()
        a @ b
        best = min(best, time.perf_counter() - t)
    return 2 * rows * inner * cols / best / 1e9


def median_ms(samples: list[float]) -> float:
    return 1000 * statistics.median(samples)


def machine() -> dict:
    return {"cpu": platform.processor() or platform.machine(), "torch": torch.__version__,
            "threads": torch.get_num_threads(), "cores": os.cpu_count(), "loadavg": list(os.getloadavg())}
