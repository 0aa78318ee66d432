"""The value-inputs diagnostic: permutation importance of each observation key for Q."""
from types import SimpleNamespace

import pytest
import torch
from tensordict import TensorDict

from torchrl_mpail2.config import ModelConfig
from torchrl_mpail2.diagnostics.value_inputs import q_of_policy_action, value_input_importance
from torchrl_mpail2.modules import MPAIL2Modules


def _agent():
    torch.manual_seed(0)
    cfg = ModelConfig(latent_dim=32, hidden_dims=(32, 32), vector_coder_hidden=32, coder_dim=32)
    return SimpleNamespace(modules=MPAIL2Modules({"arm": (3,), "cube": (3,)}, 2, cfg))


def test_a_key_that_does_not_vary_over_the_states_has_no_importance():
    agent = _agent()
    states = TensorDict({"arm": torch.rand(64, 3) * 2 - 1, "cube": torch.full((64, 3), 0.3)}, [64])
    result = value_input_importance(agent, states, permutations=3)
    assert result["states"] == 64 and result["q_spread"] > 0
    assert result["importance"]["cube"] == 0.0  # shuffling identical values changes nothing
    assert result["importance"]["arm"] > 0.1 * result["q_spread"]
    # the reported values are Q of the policy's action at the unshuffled states
    assert result["q_mean"] == pytest.approx(float(q_of_policy_action(agent, states).mean()), rel=1e-6)


def test_one_state_cannot_be_shuffled():
    agent = _agent()
    with pytest.raises(ValueError, match="at least 2 states"):
        value_input_importance(agent, TensorDict({"arm": torch.zeros(1, 3), "cube": torch.zeros(1, 3)}, [1]))


def test_the_reward_importance_shuffles_both_ends_of_each_transition_alike():
    from torchrl_mpail2.diagnostics.value_inputs import reward_input_importance

    agent = _agent()
    arm = torch.rand(65, 3) * 2 - 1
    states = TensorDict({"arm": arm, "cube": torch.full((65, 3), -0.2)}, [65])
    result = reward_input_importance(agent, states[:-1], states[1:], permutations=3)
    assert result["transitions"] == 64 and result["reward_importance"]["cube"] == 0.0
    assert result["reward_importance"]["arm"] > 0
    # a key equal at both ends of every transition but varying across them: shuffled alike, each pair stays equal
    same = TensorDict({"arm": arm[:-1], "cube": torch.rand(64, 3)}, [64])
    moved = TensorDict({"arm": arm[1:], "cube": same["cube"].clone()}, [64])
    assert reward_input_importance(agent, same, moved, permutations=2)["reward_importance"]["cube"] > 0
