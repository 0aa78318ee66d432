"""``model.cnn_init``: the image coder's initialisation, and what it does to the latents of different pictures."""
import math

import pytest
import torch
from torch import nn

from conftest import TINY
from torchrl_mpail2.config import ConfigError, ModelConfig
from torchrl_mpail2.envs.point_mass import draw_arena
from torchrl_mpail2.modules import MPAIL2Modules
from torchrl_mpail2.modules.encoder import EncoderNet, ImageCoder

IMAGE = (3, 64, 64)


def _layers(coder: ImageCoder) -> list[nn.Module]:
    return [m for m in (*coder.convs, *coder.out) if isinstance(m, (nn.Conv2d, nn.Linear))]


def test_kaiming_init_draws_he_weights_and_zero_biases():
    torch.manual_seed(0)
    kaiming, default = ImageCoder(IMAGE, 32, 512, init="kaiming"), ImageCoder(IMAGE, 32, 512)
    for layer, plain in zip(_layers(kaiming), _layers(default)):
        fan_in = layer.weight[0].numel()
        assert torch.equal(layer.bias, torch.zeros_like(layer.bias))
        assert layer.weight.std().item() == pytest.approx(math.sqrt(2 / fan_in), rel=0.1)
        assert plain.weight.std().item() < 0.7 * math.sqrt(2 / fan_in)  # PyTorch's default: std 1 / sqrt(3 fan_in)
        assert plain.bias.abs().max() > 0


def _spread(cnn_init: str) -> float:
    """Mean over latent features of their std across 256 point-mass positions, pixels standardised per pixel by
    the pictures' own statistics (``image_norm="demos"``), the point-mass pixel preset's sizes."""
    torch.manual_seed(0)
    net = EncoderNet({"external_image": IMAGE}, 512, (64, 64), coder_dim=64, cnn_channels=8, cnn_init=cnn_init)
    frames = draw_arena(torch.rand(256, 2, generator=torch.Generator().manual_seed(1)) * 2 - 1)
    x = frames.float() / 255.0
    net.set_normalization({"external_image": (x.mean(0), x.std(0))})
    with torch.no_grad():
        return net(frames).std(0).mean().item()


def test_kaiming_init_tells_point_mass_positions_apart():
    """With PyTorch's defaults the coder's outputs sit below the fusion layer's biases and every picture gets
    nearly the same latent; with Kaiming weights and zero biases the pictures' differences reach the latent."""
    assert _spread("torch") < 0.02
    assert _spread("kaiming") > 0.2


def test_the_config_field_reaches_the_image_coders_and_is_checked():
    modules = MPAIL2Modules({"observation": [4], "camera": list(IMAGE)}, 2, ModelConfig(**TINY, cnn_init="kaiming"))
    coder = modules.encoder.net.coders["camera"]
    assert all(torch.equal(layer.bias, torch.zeros_like(layer.bias)) for layer in _layers(coder))
    vector = modules.encoder.net.coders["observation"][0]
    assert vector.bias.abs().max() > 0  # vector coders keep PyTorch's defaults
    default = MPAIL2Modules({"camera": list(IMAGE)}, 2, ModelConfig(**TINY)).encoder.net.coders["camera"]
    assert default.convs[0].bias.abs().max() > 0
    with pytest.raises(ConfigError, match=r"unknown ModelConfig.cnn_init 'orthogonal'; choose from \('torch', 'kaiming'\)"):
        ModelConfig(cnn_init="orthogonal")
    with pytest.raises(ValueError, match="unknown image coder init 'xavier'"):
        ImageCoder(IMAGE, 8, 16, init="xavier")
