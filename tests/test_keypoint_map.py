"""The keypoint-map diagnostic: where an image coder's keypoints sit, and whether they follow an object."""
import pytest
import torch
from tensordict import TensorDict

from torchrl_mpail2.agents import MPAIL2Agent
from torchrl_mpail2.config import ModelConfig, PlannerConfig
from torchrl_mpail2.diagnostics.keypoint_map import draw_keypoints, keypoint_motion, keypoint_pixels
from torchrl_mpail2.envs import make_env
from torchrl_mpail2.envs.point_mass import IMAGE_KEY, draw_arena

MODEL = dict(latent_dim=16, hidden_dims=(32, 32), vector_coder_hidden=32, coder_dim=32, cnn_channels=8,
             cnn_init="kaiming", horizon=3)


def _pixel_agent(head: str) -> MPAIL2Agent:
    env = make_env("point_mass", obs="pixels", seed=0)
    torch.manual_seed(0)
    return MPAIL2Agent(env.observation_spec, env.action_spec, ModelConfig(**MODEL, image_head=head, keypoints=8),
                       planner=PlannerConfig(num_candidates=8, num_elites=2, iterations=1))


def test_the_untrained_keypoints_follow_the_point_and_are_drawn(tmp_path):
    agent = _pixel_agent("keypoints")
    torch.manual_seed(1)
    positions = torch.rand(300, 2) * 2.4 - 1.2
    frames = TensorDict({IMAGE_KEY: draw_arena(positions, glow=0)}, [300])
    still = TensorDict({IMAGE_KEY: draw_arena(torch.zeros(300, 2), glow=0)}, [300])
    moving = keypoint_motion(agent, frames, {"position": positions})[IMAGE_KEY]
    assert moving["keypoints"] == 8 and len(moving["spread_px"]) == 8
    assert moving["position"] > 0.5 and moving["mean_spread_px"] > 1.0  # they move with the point
    assert keypoint_motion(agent, still, {"position": positions})[IMAGE_KEY]["mean_spread_px"] < 1e-3
    path = draw_keypoints(agent, [frames[0], frames[1]], ["a", "b"], tmp_path / "keypoints.png")
    assert path.stat().st_size > 1000


def test_a_flattening_coder_is_refused_naming_the_setting():
    with pytest.raises(ValueError, match="model.image_head=keypoints"):
        keypoint_motion(_pixel_agent("flatten"), TensorDict({}, [0]), {})


def test_keypoint_pixels_span_the_receptive_field_centres_of_the_last_map():
    assert keypoint_pixels(torch.tensor([-1.0, 1.0]), map_size=5).tolist() == [15.0, 47.0]


def test_a_target_that_stays_still_gets_no_probe_score():
    agent = _pixel_agent("keypoints")
    positions = torch.rand(50, 2) * 2.4 - 1.2
    frames = TensorDict({IMAGE_KEY: draw_arena(positions, glow=0)}, [50])
    result = keypoint_motion(agent, frames, {"still": torch.full((50, 3), 0.8), "position": positions})[IMAGE_KEY]
    assert result["still"] is None and result["position"] is not None
