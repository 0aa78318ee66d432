"""The latent-content diagnostic: probe scores and spreads of an encoder's latents."""
import pytest
import torch
from tensordict import TensorDict

from test_plan_pictures import point_mass_agent
from torchrl_mpail2.diagnostics.latent_content import latent_content, visited_states


def test_a_position_the_observation_holds_is_read_and_noise_is_not():
    _, agent = point_mass_agent()
    torch.manual_seed(1)
    observation = torch.rand(400, 4) * 2 - 1
    position = observation[:, :2].clone()
    result = latent_content(agent, TensorDict({"observation": observation}, [400]),
                            {"position": position, "noise": torch.randn(400, 2)})
    assert result["states"] == 400 and result["latent_spread"] > 0.05
    assert result["position"]["held_out_r2"] > 0.8  # the untrained encoder keeps the position
    assert result["noise"]["held_out_r2"] < 0.2  # nothing to read
    assert set(result["coder_relative_spread"]) == {"observation"}


def test_an_env_without_a_simulator_state_is_refused():
    env, agent = point_mass_agent()
    with pytest.raises(ValueError, match="needs a robosuite env"):
        visited_states(agent, env, [0])


def test_a_compartmentalised_latent_is_probed_block_by_block():
    from types import SimpleNamespace

    from torchrl_mpail2.config import ModelConfig
    from torchrl_mpail2.modules import MPAIL2Modules

    torch.manual_seed(0)
    cfg = ModelConfig(latent_dim=32, hidden_dims=(32, 32), vector_coder_hidden=32, coder_dim=32, fuse_latent=False)
    agent = SimpleNamespace(modules=MPAIL2Modules({"arm": (3,), "cube": (3,)}, 2, cfg))
    arm, cube = torch.rand(400, 3) * 2 - 1, torch.rand(400, 3) * 2 - 1
    result = latent_content(agent, TensorDict({"arm": arm, "cube": cube}, [400]), {"cube_pos": cube.clone()})
    blocks = result["blocks"]
    assert set(blocks) == {"arm", "cube"}
    assert blocks["cube"]["cube_pos"] > 0.8 and blocks["arm"]["cube_pos"] < 0.2  # each block holds its own key
    assert result["cube_pos"]["held_out_r2"] > 0.8


def test_bf16_rounding_drowns_a_variation_smaller_than_its_resolution():
    """A position moved by a hundred-thousandth of its range: float32 latents hold it, bf16-rounded ones do not (the
    camera runs' cube moves the latent by about a thousandth early in training); a position over its whole range
    survives the rounding."""
    _, agent = point_mass_agent()
    torch.manual_seed(1)
    small = torch.rand(400, 2) * 2e-5 - 1e-5
    observation = torch.cat([0.3 + small, torch.full((400, 2), 0.2)], dim=1)
    result = latent_content(agent, TensorDict({"observation": observation}, [400]), {"small": small * 1e5}, bf16=True)
    assert result["small"]["held_out_r2"] > 0.8  # float32 keeps it
    assert result["bf16"]["small"]["held_out_r2"] < 0.2 and result["bf16"]["rounding_to_spread"] > 1.0
    large = torch.rand(400, 4) * 2 - 1
    result = latent_content(agent, TensorDict({"observation": large}, [400]), {"position": large[:, :2].clone()},
                            bf16=True)
    assert result["bf16"]["position"]["held_out_r2"] > 0.8 and result["bf16"]["rounding_to_spread"] < 0.1
