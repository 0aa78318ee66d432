"""Regenerates ``robomimic_lift_low_dim.hdf5`` and ``robomimic_lift_image.hdf5`` with robomimic's own writer.

Not run by the tests (robomimic is not installable beside robosuite 1.5 from the package registry: its release 0.3.0
imports mujoco_py). Recipe, from a checkout of robomimic (github.com/ARISE-Initiative/robomimic, commit d309eae)::

    python tests/data/make_robomimic_lift.py OUT            # robosuite demo.hdf5 of 2 scripted Lift episodes
    python ROBOMIMIC/robomimic/scripts/conversion/convert_robosuite.py --dataset OUT/demo.hdf5
    python ROBOMIMIC/robomimic/scripts/dataset_states_to_obs.py --dataset OUT/demo.hdf5 \
        --output_name low_dim.hdf5 --done_mode 2
    python ROBOMIMIC/robomimic/scripts/dataset_states_to_obs.py --dataset OUT/demo.hdf5 --output_name image.hdf5 \
        --done_mode 2 --camera_names agentview robot0_eye_in_hand --camera_height 84 --camera_width 84 --compress

with ``PYTHONPATH=ROBOMIMIC`` and its script dependencies (h5py, huggingface_hub, psutil, termcolor, tensorboardX,
egl_probe; torchvision, diffusers and transformers are imported by its model code only and can be placeholders).
``convert_robosuite.py`` stops after writing ``env_args`` (its action-dictionary step expects 7-d OSC_POSE actions,
this library's Lift takes 4-d OSC_POSITION ones); the env settings written below make robomimic's env step them.
"""
import json
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # tests/

from test_robosuite_hdf5 import _record_with_robosuites_writer  # noqa: E402
from torchrl_mpail2.envs.robosuite_control import CONTROL_FREQ_HZ, OSC_POSITION_ARM  # noqa: E402

ENV_INFO = {"env_name": "Lift", "robots": "Panda", "control_freq": CONTROL_FREQ_HZ, "reward_shaping": True,
            "controller_configs": {"type": "BASIC", "body_parts": {"right": dict(OSC_POSITION_ARM)}}}

if __name__ == "__main__":
    out = Path(sys.argv[1])
    out.mkdir(parents=True, exist_ok=True)
    path, _ = _record_with_robosuites_writer(out, episodes=2, env_info=json.dumps(ENV_INFO))
    path.replace(out / "demo.hdf5")
    print(out / "demo.hdf5")
