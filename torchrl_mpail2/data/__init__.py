"""Demonstrations (observation-only), their sampler and the replay-buffer transform that attaches them."""
from torchrl_mpail2.data.demo_buffer import DemoBuffer
from torchrl_mpail2.data.expert_windows import TRAJ_KEY, AttachExpertWindows
from torchrl_mpail2.data.demos import (
    DemoFormatError,
    Demonstrations,
    check_observation_spec,
    demos_from_arrays,
    load_demos,
    observation_keys_of,
    record_demos,
    save_demos,
)

__all__ = [
    "TRAJ_KEY",
    "AttachExpertWindows",
    "DemoBuffer",
    "DemoFormatError",
    "Demonstrations",
    "check_observation_spec",
    "demos_from_arrays",
    "load_demos",
    "observation_keys_of",
    "record_demos",
    "save_demos",
]
