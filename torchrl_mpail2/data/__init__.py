"""Demonstrations (observation-only), their sampler and the replay-buffer transform that attaches them."""
from torchrl_mpail2.data.demo_buffer import DemoBuffer
from torchrl_mpail2.data.expert_windows import TRAJ_KEY, AttachExpertWindows
from torchrl_mpail2.data.demo_files import check_observation_spec, load_demos, save_demos
from torchrl_mpail2.data.demos import DemoFormatError, Demonstrations, demos_from_arrays, observation_keys_of
from torchrl_mpail2.data.recording import record_demos
from torchrl_mpail2.data.sources import DEMO_SOURCES, load_demo_source
from torchrl_mpail2.data.ted import demos_from_ted

__all__ = [
    "DEMO_SOURCES",
    "TRAJ_KEY",
    "AttachExpertWindows",
    "DemoBuffer",
    "DemoFormatError",
    "Demonstrations",
    "check_observation_spec",
    "demos_from_arrays",
    "demos_from_ted",
    "load_demo_source",
    "load_demos",
    "observation_keys_of",
    "record_demos",
    "save_demos",
]
