import torch

from torchrl_mpail2.envs import make_env
from torchrl_mpail2.experts.sac import SACExpert, make_actor


def test_sac_expert_round_trips_weights_and_acts_deterministically(tmp_path):
    env = make_env("gym/Hopper-v5", seed=0)
    actor = make_actor(env.observation_spec["observation"].shape[-1], env.action_spec)
    td = env.reset()
    with torch.no_grad():
        actor(td.clone())
    path = tmp_path / "Hopper-v5.pt"
    torch.save({"env": "Hopper-v5", "obs_dim": 11, "hidden": (256, 256), "actor": actor.state_dict(),
                "summary": {"eval_mean_return": 1.0}}, path)
    expert = SACExpert(path, env.action_spec)
    a1, a2 = expert(td.clone())["action"], expert(td.clone())["action"]
    assert torch.equal(a1, a2) and a1.shape == (3,) and a1.abs().max() <= 1
    # the loaded actor's mean action equals the original's
    loc = actor.module[0](td.clone())["loc"]
    assert torch.allclose(a1, torch.tanh(loc), atol=1e-5)
    traj = env.rollout(20, expert, break_when_any_done=True)
    assert traj["action"].abs().max() <= 1
