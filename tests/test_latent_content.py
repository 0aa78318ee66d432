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
