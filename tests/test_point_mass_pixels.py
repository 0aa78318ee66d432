"""The point mass observed as a 64 x 64 picture: frames, the expert and demos from pictures, the mode checks, and
MPAIL2 learning it from pixels alone."""
import pytest
import torch
from tensordict import TensorDict
from torchrl.envs.utils import check_env_specs

from conftest import QUIET_RUN
from torchrl_mpail2.agents import MPAIL2Agent
from torchrl_mpail2.config import ConfigError
from torchrl_mpail2.data import record_demos
from torchrl_mpail2.envs import PointMassEnv, make_env
from torchrl_mpail2.envs.keys import observation_keys_of
from torchrl_mpail2.envs.point_mass import POSITION_LIMIT, draw_arena
from torchrl_mpail2.experts import PointMassExpert, get_expert
from torchrl_mpail2.trainers import MPAIL2Trainer, apply_overrides, preset

SIZE = 64


def _blue_centroid(frames: torch.Tensor) -> torch.Tensor:
    """``[*B, 2]`` positions of the pixels more than half covered by the blue point, read with the picture's
    geometry written out here (column 0 at x = -1.5, row 0 at y = +1.5), independently of the drawing code."""
    r, g, b = frames.float().unbind(-3)
    # more than half blue (40, 60, 220): over white (255, 255, 255, green dimmed by the glow) red falls below 147.5,
    # over the goal's green (120, 200, 120) blue rises above 170; the glow touches neither channel
    weight = ((r < 147.5) & (b > 170)).float()
    centres = (torch.arange(SIZE) + 0.5) / SIZE * 2 * POSITION_LIMIT - POSITION_LIMIT
    total = weight.sum((-2, -1))
    assert (total > 0).all(), "no blue point in a frame"
    x = (weight * centres).sum((-2, -1)) / total
    y = (weight * -centres.unsqueeze(-1)).sum((-2, -1)) / total
    return torch.stack([x, y], dim=-1)


@pytest.mark.parametrize("batch_size", [[], [4]])
def test_pixel_observation_is_a_uint8_picture_and_nothing_else(batch_size):
    env = PointMassEnv(batch_size=batch_size, seed=0, obs="pixels")
    check_env_specs(env)
    assert env.reset()["external_image"].shape == (*batch_size, 3, SIZE, SIZE)
    td = env.rollout(3)
    frames = td["next", "external_image"]
    assert frames.shape == (*batch_size, 3, 3, SIZE, SIZE) and frames.dtype == torch.uint8
    assert "observation" not in td.keys()  # the state stays hidden
    num_envs = batch_size[0] if batch_size else None
    assert observation_keys_of(make_env("point_mass", obs="pixels", num_envs=num_envs)) == ["external_image"]


def test_pixels_state_observes_the_picture_and_the_state_of_the_same_point():
    env = PointMassEnv(batch_size=[4], seed=5, obs="pixels_state")
    check_env_specs(env)
    assert observation_keys_of(env) == ["observation", "external_image"]
    td = env.rollout(5, policy=PointMassExpert())
    position = td["next", "observation"][..., :2].reshape(-1, 2)
    frames = td["next", "external_image"].reshape(-1, 3, SIZE, SIZE)
    assert torch.allclose(_blue_centroid(frames), position, atol=0.05)
    assert env.pictures == PointMassEnv(obs="pixels").pictures and PointMassEnv().pictures is None


def test_the_point_moves_in_the_picture_where_the_state_moves():
    state_env, pixel_env = PointMassEnv(batch_size=[8], seed=3), PointMassEnv(batch_size=[8], seed=3, obs="pixels")
    actions = torch.rand(30, 8, 2, generator=torch.Generator().manual_seed(0)) * 2 - 1
    state_td, pixel_td = state_env.reset(), pixel_env.reset()
    for a in actions:  # the same start states and actions in both envs
        state_td = state_env.step(state_td.set("action", a))["next"]
        pixel_td = pixel_env.step(pixel_td.set("action", a))["next"]
        position = state_td["observation"][:, :2]
        assert torch.allclose(_blue_centroid(pixel_td["external_image"]), position, atol=0.05)  # about a pixel
    # across the whole box too, x to the right and y up
    grid = torch.tensor([[-1.2, -1.2], [-1.2, 1.2], [1.2, -1.2], [0.5, 0.0], [0.0, 0.5], [0.03, -0.02]])
    assert torch.allclose(_blue_centroid(draw_arena(grid)), grid, atol=0.05)
    # the goal disc is green and stays where it is; the glow dims the green channel alone, more near the point
    frame = draw_arena(torch.tensor([1.0, 1.0]), glow=0.0)
    assert frame[:, SIZE // 2, SIZE // 2].tolist() == [120, 200, 120] and frame[:, 0, 0].tolist() == [255, 255, 255]
    glowing = draw_arena(torch.tensor([1.0, 1.0])).int()
    assert torch.equal(glowing[[0, 2]], frame.int()[[0, 2]])
    dimmed = frame.int()[1] - glowing[1]
    beside, farther, far = dimmed[10, 57], dimmed[10, 36], dimmed[53, 10]  # 0.2, 0.8 and 2.8 away from (1, 1)
    assert (dimmed >= 0).all() and beside > 60 and beside > farther > far and far == 0


def test_a_sub_pixel_step_changes_the_picture():
    """Velocity is read from two frames: even the smallest moves of a settling point must show."""
    step = 0.1 * 2 * POSITION_LIMIT / SIZE  # a tenth of a pixel
    a, b = draw_arena(torch.tensor([0.31, -0.2])), draw_arena(torch.tensor([0.31 + step, -0.2]))
    assert not torch.equal(a, b)


def test_expert_and_demos_from_pictures():
    env = make_env("point_mass", obs="pixels", seed=0)
    demos = record_demos(env, get_expert("point_mass", env), episodes=3, seed=0, progress=False)
    assert demos.success_rate == 1.0 and demos.observation_keys == ["external_image"]
    episode = demos.episode(0)["external_image"]
    assert episode.shape == (51, 3, SIZE, SIZE) and episode.dtype == torch.uint8
    # reading the position off the picture, the expert acts as it does on the state
    state = PointMassEnv(batch_size=[16], seed=5).rollout(50, policy=PointMassExpert())
    pixels = PointMassEnv(batch_size=[16], seed=5, obs="pixels").rollout(50, policy=PointMassExpert())
    assert torch.allclose(pixels["action"], state["action"], atol=0.03)
    with pytest.raises(ValueError, match="velocity_gain must be 0"):
        PointMassEnv(obs="pixels").rollout(1, policy=PointMassExpert(velocity_gain=1.0))


def test_bad_observation_modes_name_the_valid_ones():
    with pytest.raises(ValueError, match="'point_mass' has no observation mode 'external_pixels'; its modes: state, "
                                         "pixels"):
        make_env("point_mass", obs="external_pixels")
    with pytest.raises(ValueError, match="valid modes: state, pixels"):
        PointMassEnv(obs="thermal")
    with pytest.raises(ConfigError, match="TrainConfig.obs='external_pixels' is not a mode of 'point_mass'"):
        apply_overrides(preset("point_mass"), ["train.obs=external_pixels"])


def _latent_spread(obs: str) -> float:
    """Mean over latent features of their std across 256 positions: the untrained encoder of ``point_mass_pixels``
    as a run starts it (its pixels standardised by 3 demonstrations' statistics)."""
    cfg = preset("point_mass_pixels")
    env = make_env("point_mass", obs=obs)
    agent = MPAIL2Agent(env.observation_spec, env.action_spec, cfg.model, cfg.loss, cfg.planner)
    if obs == "pixels":
        agent.modules.normalize_from_demos(record_demos(env, get_expert("point_mass", env), episodes=3, seed=0,
                                                        progress=False))
    position = torch.rand(256, 2, generator=torch.Generator().manual_seed(1)) * 2 - 1
    if obs == "pixels":
        observation = {"external_image": draw_arena(position)}
    else:
        observation = {"observation": torch.cat([position, torch.zeros_like(position)], dim=-1)}
    with torch.no_grad():
        z = agent.modules.encoder(TensorDict(observation, [256]))["z"]
    return z.std(0).mean().item()


def test_the_untrained_image_encoder_tells_point_mass_positions_apart():
    """The fast stand-in for the learning test below: the pictures' latents spread across positions about as the
    state's do (the preset's pixel standardisation and Kaiming weights; PyTorch's defaults gave 0.001)."""
    state, pixels = _latent_spread("state"), _latent_spread("pixels")
    assert state > 0.1, "the control changed: the untrained state encoder no longer spreads positions"
    assert pixels > 0.25 * state, (pixels, state)


@pytest.mark.slow
def test_mpail2_learns_the_point_mass_from_pixels(tmp_path):
    """The ``point_mass`` learning test from pixels (``tests/test_training.py``: >= 80% after 35 episodes from state).
    Measured with the preset, any-step success on the 10 fixed episodes at 30: 1.0 on seeds 0, 1 and 2 (0.0 without
    the pictures' glow); seed 0 runs here: 441 s beside three other jobs on a 2-core CPU."""
    trainer = MPAIL2Trainer(apply_overrides(preset("point_mass_pixels"), [*QUIET_RUN, "train.total_episodes=30"]),
                            run_dir=tmp_path / "run")
    summary = trainer.train()
    assert summary["last_eval"]["episode"] == 30 and summary["last_eval"]["success_rate_any_step"] >= 0.8, summary


def test_demos_of_pictures_drawn_otherwise_are_refused_by_name(tmp_path):
    from torchrl_mpail2.data import load_demos, save_demos

    env = make_env("point_mass", obs="pixels", seed=0)
    demos = record_demos(env, get_expert("point_mass", env), episodes=1, seed=0, progress=False)
    assert demos.header["pictures"] == env.pictures == "point_mass arena, glow 0.6"
    save_demos(demos, tmp_path / "glow")
    assert load_demos(tmp_path / "glow", env).num_episodes == 1
    plain = PointMassEnv(seed=0, obs="pixels", glow=0.0)
    with pytest.raises(ValueError, match=r"drawn as 'point_mass arena, glow 0.6', the env draws them as "
                                         r"'point_mass arena, glow 0.0': record the demonstrations again"):
        load_demos(tmp_path / "glow", plain)
    del demos.header["pictures"]  # demonstrations saved before headers recorded the pictures
    save_demos(demos, tmp_path / "old")
    with pytest.raises(ValueError, match="drawn before the header recorded how"):
        load_demos(tmp_path / "old", env)
    assert make_env("point_mass", seed=0).pictures is None  # from state nothing is drawn
    with pytest.raises(ValueError, match="glow must be >= 0"):
        PointMassEnv(obs="pixels", glow=-1.0)
