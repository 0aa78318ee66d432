"""Random-shift augmentation of camera frames (``modules.augment``, ``loss.image_shift``)."""
import pytest
import torch
from tensordict import TensorDict

from torchrl_mpail2.config import ConfigError, LossConfig, ModelConfig
from torchrl_mpail2.modules import MPAIL2Modules
from torchrl_mpail2.modules.augment import random_shift
from torchrl_mpail2.objectives import DACLoss, MPAIL2Loss


def test_each_frame_moves_by_its_own_offset_with_its_border_repeated():
    gen = torch.Generator().manual_seed(0)
    frames = torch.randint(0, 256, (64, 3, 8, 8), dtype=torch.uint8)
    shifted = random_shift(frames, 2, generator=gen)
    assert shifted.dtype == torch.uint8 and shifted.shape == frames.shape
    # pad by repeating the border, then find the crop each frame is: exactly one offset in [-2, 2]^2 fits
    padded = torch.nn.functional.pad(frames.float(), (2, 2, 2, 2), mode="replicate")
    offsets = set()
    for i in range(len(frames)):
        fits = [(dy, dx) for dy in range(5) for dx in range(5)
                if torch.equal(padded[i, :, dy:dy + 8, dx:dx + 8], shifted[i].float())]
        assert len(fits) == 1, f"frame {i}: {fits}"
        offsets.add(fits[0])
    assert len(offsets) > 10  # the offsets are drawn per frame, not once per batch


def test_no_shift_returns_the_frames_and_bad_input_is_refused():
    frames = torch.zeros(2, 3, 4, 4)
    assert random_shift(frames, 0) is frames
    with pytest.raises(ValueError, match="pad must be >= 0"):
        random_shift(frames, -1)
    with pytest.raises(ValueError, match=r"\[N, C, H, W\]"):
        random_shift(frames[0], 1)
    with pytest.raises(ConfigError, match="image_shift"):
        LossConfig(image_shift=-1)


def _camera_batch(B=4, T=3):
    images = torch.randint(0, 256, (B, T + 1, 3, 64, 64), dtype=torch.uint8)
    proprio = torch.randn(B, T + 1, 5)
    return TensorDict({
        "image": images[:, :-1], "proprio": proprio[:, :-1], "action": torch.rand(B, T, 2) * 2 - 1,
        ("next", "image"): images[:, 1:], ("next", "proprio"): proprio[:, 1:],
        ("next", "terminated"): torch.zeros(B, T, 1, dtype=torch.bool),
        ("expert", "image"): images[:, :-1], ("expert", "proprio"): proprio[:, :-1],
        ("expert", "next", "image"): images[:, 1:], ("expert", "next", "proprio"): proprio[:, 1:],
    }, [B, T])


def test_the_loss_shifts_frames_in_training_only_and_in_every_objective():
    torch.manual_seed(0)
    cfg = ModelConfig(latent_dim=8, hidden_dims=(16,), coder_dim=16, vector_coder_hidden=16, cnn_channels=4,
                      horizon=3, cnn_init="kaiming")
    modules = MPAIL2Modules({"image": [3, 64, 64], "proprio": [5]}, action_dim=2, cfg=cfg)
    td = _camera_batch()
    plain = MPAIL2Loss(modules, LossConfig())
    shifted = MPAIL2Loss(modules, LossConfig(image_shift=4))
    assert {m.image_shift for m in shifted.modules() if hasattr(m, "image_shift")} == {4}
    z_plain, _ = plain.replay_latents(td)
    z1, _ = shifted.replay_latents(td)
    z2, _ = shifted.replay_latents(td)
    assert torch.equal(z_plain, plain.replay_latents(td)[0])
    assert not torch.allclose(z1, z2) and not torch.allclose(z1, z_plain)
    shifted.eval()
    assert torch.equal(shifted.replay_latents(td)[0], z_plain)
    shifted.train()
    out = shifted(td)
    assert all(torch.isfinite(out[k]) for k in ("loss_dynamics", "loss_reward", "loss_value", "loss_actor"))


def test_the_model_free_ablation_shifts_its_frames_too():
    cfg = ModelConfig(latent_dim=8, hidden_dims=(16,), coder_dim=16, vector_coder_hidden=16, cnn_channels=4,
                      horizon=1, policy_horizon=1)
    loss = DACLoss(MPAIL2Modules({"image": [3, 64, 64], "proprio": [5]}, action_dim=2, cfg=cfg), LossConfig(image_shift=2))
    shifts = {type(m).__name__: m.image_shift for m in loss.modules() if hasattr(m, "image_shift")}
    assert set(shifts) == {"DACLoss", "AdversarialRewardLoss", "ModelFreeValueLoss", "ModelFreeActorLoss"}
    assert set(shifts.values()) == {2}
