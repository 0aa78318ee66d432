"""Each component learns its own objective in isolation on small synthetic problems."""
import torch
from tensordict import TensorDict
from torch import nn
from torchrl.objectives import SoftUpdate

from conftest import tiny_modules
from torchrl_mpail2 import AdversarialRewardLoss, JEPDynamicsLoss, LambdaReturnValueLoss

OBS, ACT = 4, 2
A_SYS = torch.tensor([[0.9, -0.2, 0.0, 0.0], [0.2, 0.9, 0.0, 0.0], [0.0, 0.0, 0.8, 0.1], [0.0, 0.0, -0.1, 0.8]])
B_SYS = torch.tensor([[0.5, 0.0], [0.0, 0.5], [0.3, 0.3], [0.0, -0.4]])


def linear_trajectories(batch, steps, gen):
    x = torch.randn(batch, OBS, generator=gen)
    a = torch.rand(batch, steps, ACT, generator=gen) * 2 - 1
    xs = [x]
    for k in range(steps):
        xs.append(xs[-1] @ A_SYS.T + a[:, k] @ B_SYS.T)
    xs = torch.stack(xs, 1)
    return TensorDict({"observation": xs[:, :-1], "action": a, ("next", "observation"): xs[:, 1:]}, [batch, steps])


def test_dynamics_fit_a_linear_system_and_predict_held_out_transitions():
    gen = torch.Generator().manual_seed(0)
    m = tiny_modules(obs_dim=OBS, action_dim=ACT, latent_dim=16, hidden_dims=(64, 64))
    loss = JEPDynamicsLoss(m.encoder, m.dynamics)
    opt = torch.optim.Adam(list(m.encoder.parameters()) + list(m.dynamics.parameters()), lr=1e-3)
    held_out = linear_trajectories(512, 3, gen)
    with torch.no_grad():
        initial = loss(held_out)["loss_dynamics"].item()
    for _ in range(400):
        out = loss(linear_trajectories(128, 3, gen))
        opt.zero_grad()
        out["loss_dynamics"].backward()
        opt.step()
    with torch.no_grad():
        z = m.encoder.encode(held_out[:, 0])
        z_next = m.encoder.encode(held_out[:, 0], ("next",))
        pred = m.dynamics.module(z, held_out["action"][:, 0])
        error = (pred - z_next).pow(2).sum(-1).mean()
        spread = z_next.var(0).sum()  # how much the target latents vary across states
        no_model = (z - z_next).pow(2).sum(-1).mean()  # "nothing moves" baseline
        final = loss(held_out)["loss_dynamics"].item()
    assert spread > 0.5, "latents collapsed to a constant"
    assert error < 0.1 * spread and error < 0.5 * no_model
    assert final < 0.2 * initial


def test_reward_scores_expert_transitions_above_non_expert_ones():
    gen = torch.Generator().manual_seed(1)
    m = tiny_modules(obs_dim=OBS, action_dim=ACT, latent_dim=16, hidden_dims=(64, 64))
    loss = AdversarialRewardLoss(m.encoder, m.reward, gp_coef=0.1)
    opt = torch.optim.Adam(m.reward.parameters(), lr=1e-3)
    step = torch.tensor([0.5, 0.5, 0.0, 0.0])  # the expert moves one way, the learner the other

    def batch(n):
        x_e, x_b = torch.randn(n, OBS, generator=gen), torch.randn(n, OBS, generator=gen)
        return TensorDict({"observation": x_b, ("next", "observation"): x_b - step,
                           ("expert", "observation"): x_e, ("expert", "next", "observation"): x_e + step}, [n])

    for _ in range(300):
        out = loss(batch(128))
        opt.zero_grad()
        out["loss_reward"].backward()
        opt.step()
    with torch.no_grad():
        x = torch.randn(1024, OBS, generator=gen)  # held-out states, both transitions from the same state
        td = TensorDict({"observation": x, "expert_next": x + step, "agent_next": x - step}, [1024])
        z = m.encoder.net(td["observation"])
        r_expert = m.reward.module(z, m.encoder.net(td["expert_next"]))
        r_agent = m.reward.module(z, m.encoder.net(td["agent_next"]))
        held = loss(batch(1024))
    assert (r_expert > r_agent).float().mean() > 0.95
    assert held["reward_gap"] > 1.0


class ConstantReward(nn.Module):
    def forward(self, z, z_next):
        return torch.ones(*z.shape[:-1], 1)

    def project(self, z):
        return torch.zeros_like(z), torch.zeros_like(z)

    def from_projection(self, h_now, h_next):
        return torch.ones(*h_now.shape[:-1], 1)


def test_ensemble_regresses_onto_the_known_value_of_a_fixed_chain():
    # with r = 1 everywhere, Eq. 6's fixed point is Q = 1 / (1 - gamma) = 2 for gamma = 0.5
    gen = torch.Generator().manual_seed(2)
    m = tiny_modules(obs_dim=OBS, action_dim=ACT, latent_dim=16)
    m.reward.module = ConstantReward()
    loss = LambdaReturnValueLoss(m.encoder, m.dynamics, m.reward, m.value, m.policy, gamma=0.5, lmbda=0.95)
    updater = SoftUpdate(loss, tau=0.05)
    opt = torch.optim.Adam(m.value.parameters(), lr=3e-3)
    for _ in range(400):
        out = loss(linear_trajectories(64, 1, gen))
        opt.zero_grad()
        out["loss_value"].backward()
        opt.step()
        updater.step()
    with torch.no_grad():
        td = linear_trajectories(256, 1, gen).reshape(-1)
        q = m.value.net(m.encoder.encode(td), td["action"])
    assert (q.mean() - 2.0).abs() < 0.1
    assert q.std() < 0.2  # every head, every state
