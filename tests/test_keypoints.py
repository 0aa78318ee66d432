"""The keypoint head of the image coder: soft-argmax coordinates that move with what the maps find."""
import pytest
import torch

from torchrl_mpail2.config import ConfigError, ModelConfig
from torchrl_mpail2.modules.encoder import ImageCoder
from torchrl_mpail2.modules.keypoints import SpatialSoftmax


def _blob_maps(centres_x, y=0.0, size=9, width=0.15):
    """One map per centre: a Gaussian bump at (x, y) in [-1, 1] coordinates."""
    grid = torch.linspace(-1.0, 1.0, size)
    ys, xs = torch.meshgrid(grid, grid, indexing="ij")
    return torch.stack([torch.exp(-((xs - cx) ** 2 + (ys - y) ** 2) / (2 * width**2)) for cx in centres_x])[:, None]


def test_a_keypoint_follows_a_bump_across_its_map_and_ignores_the_maps_scale():
    softmax = SpatialSoftmax(init_temperature=0.2)
    centres = torch.linspace(-0.8, 0.8, 9)
    coords = softmax(_blob_maps(centres)).detach()
    x, y = coords[:, 0], coords[:, 1]
    assert (x.diff() > 0).all()  # moves the same way as the bump, step by step
    assert torch.allclose(x, centres, atol=0.15)
    assert y.abs().max() < 1e-4
    assert torch.allclose(softmax(10.0 * _blob_maps(centres) + 3.0), softmax(_blob_maps(centres)), atol=1e-5)


def test_a_flat_map_gives_the_centre_and_bad_shapes_or_temperatures_are_refused():
    assert torch.allclose(SpatialSoftmax()(torch.ones(2, 3, 5, 5)), torch.zeros(2, 6))
    with pytest.raises(ValueError, match=r"\[\*B, K, h, w\]"):
        SpatialSoftmax()(torch.ones(5, 5))
    with pytest.raises(ValueError, match="init_temperature"):
        SpatialSoftmax(init_temperature=0.0)


def _dot(px: int) -> torch.Tensor:
    image = torch.zeros(1, 3, 64, 64, dtype=torch.uint8)
    image[0, :, 30:33, px:px + 3] = 255
    return image


def test_the_untrained_keypoint_coder_moves_its_keypoints_with_a_dot_and_trains_its_temperature():
    torch.manual_seed(0)
    coder = ImageCoder((3, 64, 64), channels=16, out_dim=24, init="kaiming", head="keypoints", keypoints=8)
    positions = list(range(2, 60, 4))
    with torch.no_grad():
        centred = [_dot(px).float() / 255 - coder.pixel_mean for px in positions]  # as forward() normalises
        keypoints = torch.cat([coder.convs(image) for image in centred])  # [positions, 2K]
    x = keypoints[:, 0::2]
    moved = torch.stack([torch.tensor(positions, dtype=torch.float32), x.mean(1)])
    assert torch.corrcoef(moved)[0, 1] > 0.8  # the mean keypoint goes left to right with the dot
    out = coder(_dot(10).expand(3, -1, -1, -1))
    assert out.shape == (3, 24)
    out.square().sum().backward()
    assert coder.convs[-1].log_temperature.grad is not None and coder.convs[0].weight.grad.abs().sum() > 0


def test_the_head_is_chosen_by_the_config_and_an_unknown_one_is_named():
    with pytest.raises(ConfigError, match="image_head"):
        ModelConfig(image_head="pooled")
    with pytest.raises(ConfigError, match="keypoints"):
        ModelConfig(keypoints=0)
    with pytest.raises(ValueError, match="'pooled'"):
        ImageCoder((3, 64, 64), channels=8, out_dim=8, head="pooled")
    flat = ImageCoder((3, 64, 64), channels=8, out_dim=8)
    assert not any(isinstance(m, SpatialSoftmax) for m in flat.modules())


def test_an_agent_with_keypoints_keeps_its_temperature_through_a_state_dict():
    from torchrl_mpail2.agents import MPAIL2Agent
    from torchrl_mpail2.envs import make_env

    env = make_env("point_mass", obs="pixels", seed=0)
    cfg = ModelConfig(latent_dim=16, hidden_dims=(32,), coder_dim=32, vector_coder_hidden=32, cnn_channels=8,
                      horizon=3, image_head="keypoints", keypoints=4)
    torch.manual_seed(0)
    agent = MPAIL2Agent(env.observation_spec, env.action_spec, cfg)
    softmax = next(m for m in agent.modules.modules() if isinstance(m, SpatialSoftmax))
    with torch.no_grad():
        softmax.log_temperature.fill_(-1.5)
    torch.manual_seed(1)
    other = MPAIL2Agent(env.observation_spec, env.action_spec, cfg)
    other.load_state_dict(agent.state_dict())
    td = env.reset()
    torch.testing.assert_close(other.modules.encoder(td.clone())["z"], agent.modules.encoder(td.clone())["z"])
    assert next(m for m in other.modules.modules() if isinstance(m, SpatialSoftmax)).log_temperature.item() == -1.5
