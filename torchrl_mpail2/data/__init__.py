"""Demonstrations (observation-only) and their sampler."""
from torchrl_mpail2.data.demo_buffer import DemoBuffer
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
