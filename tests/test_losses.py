import pytest
import torch
from tensordict import TensorDict

from conftest import replay_batch, tiny_modules
from torchrl_mpail2 import (AdversarialRewardLoss, JEPDynamicsLoss, LambdaReturnValueLoss, LossConfig, MPAIL2Loss,
                            MPAIL2Updater, MultiStepActorLoss)
from torchrl_mpail2.config import ConfigError


def _grads(module):
    return [p.grad for p in module.parameters()]


def _has_grad(module):
    return any(g is not None and g.abs().sum() > 0 for g in _grads(module))


def _no_grad(module):
    return all(g is None or g.abs().sum() == 0 for g in _grads(module))


def test_dynamics_loss_trains_encoder_and_dynamics_only():
    m = tiny_modules()
    loss = JEPDynamicsLoss(m.encoder, m.dynamics)
    loss(replay_batch())["loss_dynamics"].backward()
    assert _has_grad(m.encoder) and _has_grad(m.dynamics)
    assert _no_grad(m.reward) and _no_grad(m.value) and _no_grad(m.policy)


def test_dynamics_loss_by_hand_with_linear_dynamics():
    m = tiny_modules()
    loss = JEPDynamicsLoss(m.encoder, m.dynamics, rho=0.5)
    td = replay_batch(batch=2, steps=3)
    z0 = m.encoder.encode(td[:, 0])
    targets = m.encoder.encode(td, ("next",))
    z, expected = z0, 0.0
    for k in range(3):
        z = m.dynamics.module(z, td["action"][:, k])
        expected = expected + 0.5 ** (k + 1) * (z - targets[:, k]).pow(2).sum(-1)
    assert loss(td)["loss_dynamics"].item() == pytest.approx(expected.mean().item(), rel=1e-5)


def test_reward_loss_leaves_encoder_untouched_and_uses_gp():
    m = tiny_modules()
    loss = AdversarialRewardLoss(m.encoder, m.reward, gp_coef=0.1)
    out = loss(replay_batch())
    out["loss_reward"].backward()
    assert _has_grad(m.reward) and _no_grad(m.encoder) and _no_grad(m.dynamics)
    expected = out["reward_agent"] - out["reward_expert"] + 0.1 * out["grad_penalty"]
    assert out["loss_reward"].item() == pytest.approx(expected.item(), rel=1e-5, abs=1e-6)
    assert not out["grad_penalty"].requires_grad and not out["reward_gap"].requires_grad


def test_reward_scale_tracks_the_critic_spread_and_divides_what_consumers_see():
    torch.manual_seed(0)
    m = tiny_modules()
    with torch.no_grad():
        m.reward.module.net[-1].weight.mul_(300.0)  # a critic on the scale a weak gradient penalty lets it reach
    net, td = m.reward.module, replay_batch()
    paper = AdversarialRewardLoss(m.encoder, m.reward, gp_coef=0.1)  # scale_momentum=None: the paper's raw critic
    paper(td)
    assert net.reward_scale.item() == 1.0
    loss = AdversarialRewardLoss(m.encoder, m.reward, gp_coef=0.1, scale_momentum=0.9)
    (z, z_next), (ze, ze_next) = loss.replay_latents(td), loss.expert_latents(td)
    pooled = torch.cat([net.critic(z, z_next).flatten(), net.critic(ze, ze_next).flatten()])
    for _ in range(3):  # same batch, no optimiser step: the bias-corrected running mean equals the batch std
        out = loss(td)
    assert pooled.std().item() > 10.0
    assert net.reward_scale.item() == pytest.approx(pooled.std().item(), rel=1e-4)
    assert out["reward_scale"].item() == pytest.approx(net.reward_scale.item())
    assert torch.allclose(net(z, z_next), net.critic(z, z_next) / net.reward_scale, rtol=1e-5)
    h_now, h_next = net.project(z)
    assert torch.allclose(net.from_projection(h_now, net.project(z_next)[1]), net(z, z_next), rtol=1e-4, atol=1e-5)
    assert net(torch.cat([z, ze]), torch.cat([z_next, ze_next])).std().item() == pytest.approx(1.0, rel=1e-3)
    with pytest.raises(ValueError, match="scale_momentum"):
        AdversarialRewardLoss(m.encoder, m.reward, scale_momentum=1.0)


def test_value_loss_gradients_reach_only_q_and_never_the_target():
    m = tiny_modules()
    loss = LambdaReturnValueLoss(m.encoder, m.dynamics, m.reward, m.value, m.policy)
    loss(replay_batch())["loss_value"].backward()
    assert _has_grad(m.value)
    for other in (m.encoder, m.dynamics, m.reward, m.policy):
        assert _no_grad(other)
    assert all(not p.requires_grad for p in loss.target_qvalue_network_params.values(True, True))


def test_value_trains_encoder_sends_the_value_gradient_into_the_encoder_and_nowhere_else():
    m = tiny_modules()
    loss = LambdaReturnValueLoss(m.encoder, m.dynamics, m.reward, m.value, m.policy, encoder_grad=True)
    td = replay_batch()
    torch.manual_seed(1)  # the target's imagined plan is sampled
    out = loss(td)
    out["loss_value"].backward()
    assert _has_grad(m.value) and _has_grad(m.encoder)
    for other in (m.dynamics, m.reward, m.policy):
        assert _no_grad(other)
    plain = LambdaReturnValueLoss(m.encoder, m.dynamics, m.reward, m.value, m.policy)
    torch.manual_seed(1)
    torch.testing.assert_close(plain(td)["loss_value"], out["loss_value"].detach())  # the same regression
    groups = MPAIL2Loss(m, LossConfig(value_trains_encoder=True)).param_groups()
    encoder = {id(p) for p in m.encoder.parameters()}
    assert [g["lr"] for g in groups["value"]] == [3e-4, 3e-5]
    assert {id(p) for p in groups["value"][1]["params"]} == encoder


def test_value_target_reads_the_slow_target_and_soft_update_moves_it():
    from torchrl.objectives import SoftUpdate
    m = tiny_modules()
    loss = LambdaReturnValueLoss(m.encoder, m.dynamics, m.reward, m.value, m.policy)
    updater = SoftUpdate(loss, tau=0.5)
    z, z2 = torch.randn(6, 16), torch.randn(6, 16)
    torch.manual_seed(3)
    y_before, _ = loss.target(z, z2)
    with torch.no_grad():
        for p in m.value.parameters():
            p.add_(1.0)  # online Q changes, target does not
    torch.manual_seed(3)
    y_same, _ = loss.target(z, z2)
    assert torch.allclose(y_before, y_same)
    updater.step()
    torch.manual_seed(3)
    y_after, _ = loss.target(z, z2)
    assert not torch.allclose(y_before, y_after)
    first = next(iter(loss.target_qvalue_network_params.values(True, True)))
    online = next(iter(loss.qvalue_network_params.values(True, True)))
    assert not torch.equal(first, online)


def test_value_target_masks_terminal_transitions():
    m = tiny_modules()
    loss = LambdaReturnValueLoss(m.encoder, m.dynamics, m.reward, m.value, m.policy, mask_terminal=True, gamma=0.9)
    z, z2 = torch.randn(4, 16), torch.randn(4, 16)
    term = torch.tensor([True, False, True, False]).unsqueeze(-1)
    y, r = loss.target(z, z2, term)
    assert torch.allclose(y[term.squeeze(-1)], r[term.squeeze(-1)])
    assert not torch.allclose(y[~term.squeeze(-1)], r[~term.squeeze(-1)])


def test_masked_value_loss_refuses_a_batch_without_termination_flags():
    m = tiny_modules()
    loss = LambdaReturnValueLoss(m.encoder, m.dynamics, m.reward, m.value, m.policy, mask_terminal=True)
    batch = replay_batch()
    loss(batch)  # with the flags: fine
    del batch["next", "terminated"]
    with pytest.raises(KeyError, match="terminated"):
        loss(batch)  # without them the mask would silently bootstrap through terminations
    LambdaReturnValueLoss(m.encoder, m.dynamics, m.reward, m.value, m.policy)(batch)  # unmasked: not needed


def test_actor_loss_leaves_q_dynamics_reward_and_encoder_without_gradient():
    m = tiny_modules()
    loss = MultiStepActorLoss(m.encoder, m.dynamics, m.reward, m.value, m.policy)
    out = loss(replay_batch())
    out["loss_actor"].backward()
    assert _has_grad(m.policy)
    for other in (m.encoder, m.dynamics, m.reward, m.value):
        assert _no_grad(other)
    assert loss.log_alpha.grad is None  # alpha only learns through loss_alpha
    out["loss_alpha"].backward()
    assert loss.log_alpha.grad is not None and loss.target_entropy == -2.0


def test_alpha_moves_toward_the_target_entropy():
    m = tiny_modules()
    loss = MultiStepActorLoss(m.encoder, m.dynamics, m.reward, m.value, m.policy, target_entropy_per_step=100.0)
    loss(replay_batch())["loss_alpha"].backward()
    # entropy far below a target of 100 nats: the gradient step must raise alpha
    assert loss.log_alpha.grad < 0


def test_set_keys_remaps_action_and_expert_prefix():
    m = tiny_modules()
    loss = MPAIL2Loss(m)
    td = replay_batch()
    td.rename_key_("action", "joint_cmd")
    td.rename_key_("expert", "demo")
    with pytest.raises(KeyError):
        loss(td)
    loss.set_keys(action="joint_cmd", expert="demo")
    out = loss(td)
    assert torch.isfinite(out["loss_value"]) and torch.isfinite(out["loss_reward"])
    assert loss.value_loss.tensor_keys.action == "joint_cmd"


def test_composite_returns_every_term_and_state_dict_round_trips():
    m = tiny_modules()
    loss = MPAIL2Loss(m, LossConfig(init_alpha=0.1))
    out = loss(replay_batch())
    for key in ("loss_dynamics", "loss_reward", "loss_value", "loss_actor", "loss_alpha"):
        assert out[key].shape == () and torch.isfinite(out[key])
    for key in ("grad_penalty", "reward_gap", "q_mean", "alpha", "entropy", "target_entropy"):
        assert not out[key].requires_grad
    assert loss.log_alpha.exp().item() == pytest.approx(0.1)
    assert out["target_entropy"].item() == -2.0  # -|A| per step (Table 4), logged beside the entropy
    other = MPAIL2Loss(tiny_modules(), LossConfig())
    other.load_state_dict(loss.state_dict())
    assert other.log_alpha.item() == pytest.approx(loss.log_alpha.item())
    for a, b in zip(loss.value_loss.target_qvalue_network_params.values(True, True),
                    other.value_loss.target_qvalue_network_params.values(True, True)):
        assert torch.equal(a, b)


def test_alpha_lr_zero_keeps_alpha_fixed_while_the_default_raises_it():
    moved = {}
    for alpha_lr in (3e-4, 0.0):
        torch.manual_seed(0)
        loss = MPAIL2Loss(tiny_modules(), LossConfig(alpha_lr=alpha_lr, target_entropy_per_step=100.0))
        before = loss.actor_loss.log_alpha.item()
        MPAIL2Updater(loss, retain_memory=False).update(replay_batch())
        moved[alpha_lr] = loss.actor_loss.log_alpha.item() - before
    # entropy far below a target of 100 nats: Adam's first step raises log alpha by about its learning rate
    assert moved[3e-4] == pytest.approx(3e-4, rel=1e-3) and moved[0.0] == 0.0
    with pytest.raises(ConfigError, match="alpha_lr"):
        LossConfig(alpha_lr=-1e-4)


def test_param_groups_follow_table_4():
    groups = MPAIL2Loss(tiny_modules()).param_groups()
    assert [g["lr"] for g in groups["dynamics"]] == [3e-5, 3e-4]
    assert groups["value"][0]["max_grad_norm"] == 5.0 and groups["actor"][0]["max_grad_norm"] == 1.0
    ids = [id(p) for stage in groups.values() for g in stage for p in g["params"]]
    assert len(ids) == len(set(ids))  # no parameter is stepped by two optimisers (unless value_trains_encoder)


def test_updater_changes_each_component_and_skips_nonfinite_batches():
    m = tiny_modules()
    updater = MPAIL2Updater(MPAIL2Loss(m))
    before = {k: v.clone() for k, v in m.state_dict().items()}
    metrics = updater.update(replay_batch())
    after = m.state_dict()
    for prefix in ("encoder", "dynamics", "reward", "value", "policy"):
        assert any(not torch.equal(before[k], after[k]) for k in before if k.startswith(prefix)), prefix
    assert metrics["nonfinite_skips"].item() == 0
    bad = replay_batch()
    bad["action"][0, 0, 0] = float("nan")
    snapshot = {k: v.clone() for k, v in m.state_dict().items()}
    assert updater.update(bad) is None  # a non-finite batch is skipped whole, before any stage
    assert dict(updater.skipped) == {"batch": 1} and updater.last_nonfinite_keys == ["action"]
    for k, v in m.state_dict().items():
        assert torch.equal(v, snapshot[k]), k


def test_model_free_losses_isolate_their_gradients():
    from torchrl_mpail2.objectives import DACLoss
    m = tiny_modules(horizon=1)
    loss = DACLoss(m)
    td = replay_batch()
    loss.value_loss(td)["loss_value"].backward()
    assert _has_grad(m.value) and _has_grad(m.encoder)  # DAC trains its encoder through the value
    assert _no_grad(m.reward) and _no_grad(m.policy)
    for p in m.parameters():
        p.grad = None
    out = loss.actor_loss(td)
    out["loss_actor"].backward()
    assert _has_grad(m.policy) and _no_grad(m.value) and _no_grad(m.encoder)
    with pytest.raises(ValueError, match="single-step policy"):
        DACLoss(tiny_modules(horizon=3))


def test_window_transitions_are_distinct_steps_of_their_own_window():
    from torchrl_mpail2.objectives.base import sample_window_transitions
    rows = torch.arange(6).unsqueeze(-1).expand(6, 5)
    td = TensorDict({"row": rows, "t": torch.arange(5).expand(6, 5), ("next", "t"): torch.arange(5).expand(6, 5) + 1},
                    [6, 5])
    sub = sample_window_transitions(td, 3)
    assert sub.shape == (6, 3)
    assert torch.equal(sub["row"], rows[:, :3])  # each sample stays in its window
    assert all(len(set(r.tolist())) == 3 for r in sub["t"])  # distinct steps
    assert torch.equal(sub["next", "t"], sub["t"] + 1)  # next observations follow their step
    assert sample_window_transitions(td, None) is td and sample_window_transitions(td, 5) is td
    with pytest.raises(ValueError, match="per_window"):
        sample_window_transitions(td, 0)


def test_updater_feeds_reward_value_actor_the_sampled_transitions_and_dynamics_whole_windows():
    torch.manual_seed(0)
    m = tiny_modules()
    loss = MPAIL2Loss(m, LossConfig(transitions_per_window=1))
    seen = {}
    for name in ("dynamics_loss", "reward_loss", "value_loss", "actor_loss"):
        sub = getattr(loss, name)
        original = sub.forward

        def spy(td, *args, _name=name, _original=original, **kwargs):
            seen[_name] = tuple(td.shape)
            return _original(td, *args, **kwargs)
        sub.forward = spy
    metrics = MPAIL2Updater(loss, retain_memory=False).update(replay_batch(batch=4, steps=3))
    assert seen == {"dynamics_loss": (4, 3), "reward_loss": (4, 1), "value_loss": (4, 1), "actor_loss": (4, 1)}
    assert all(torch.isfinite(v) for k, v in metrics.items() if k.startswith("loss_"))


def test_return_form_reaches_value_and_actor_losses_and_is_validated():
    from torchrl_mpail2.config import ConfigError, LossConfig, ModelConfig
    from torchrl_mpail2.modules import MPAIL2Modules
    from torchrl_mpail2.objectives import MPAIL2Loss

    modules = MPAIL2Modules({"observation": [3]}, 2, ModelConfig(latent_dim=8, hidden_dims=(16,), coder_dim=16,
                                                                 vector_coder_hidden=16, horizon=3))
    loss = MPAIL2Loss(modules, LossConfig(return_form="td_lambda"))
    assert loss.value_loss.return_form == loss.actor_loss.return_form == "td_lambda"
    with pytest.raises(ConfigError, match="return_form"):
        LossConfig(return_form="dreamer")


@pytest.mark.parametrize("composite", ["mpail2", "dac"])
def test_forward_and_updater_follow_the_one_stage_list(composite):
    from torchrl_mpail2.objectives import DACLoss

    torch.manual_seed(0)
    loss = MPAIL2Loss(tiny_modules()) if composite == "mpail2" else DACLoss(tiny_modules(horizon=1))
    expected = ("dynamics", "reward", "value", "actor") if composite == "mpail2" else ("reward", "value", "actor")
    assert loss.stages == expected
    assert {k for k in loss(replay_batch()).keys() if k.startswith("loss_")} == {f"loss_{s}" for s in (*expected, "alpha")}
    updater = MPAIL2Updater(loss, retain_memory=False)
    stepped = []
    for stage, optimizer in updater.optimizers.items():
        original = optimizer.step
        optimizer.step = lambda *a, _stage=stage, _original=original, **k: (stepped.append(_stage), _original(*a, **k))[1]
    # a window batch holding NaN is skipped only where a stage reads it: the model-free composite trains on the
    # latest-episode batch alone when one is given
    bad = replay_batch()
    bad["observation"][0, 0, 0] = float("nan")
    metrics = updater.update(bad, replay_batch())
    assert (metrics is None) == (composite == "mpail2")
    if composite == "dac":
        assert stepped == [*expected, "alpha"]
    stepped.clear()
    updater.update(replay_batch())
    assert stepped == [*expected, "alpha"]


def test_value_head_reduce_mean_is_the_sum_over_the_ensemble_size():
    torch.manual_seed(0)
    m = tiny_modules()
    td = replay_batch()
    summed = MPAIL2Loss(m, LossConfig()).value_loss
    averaged = MPAIL2Loss(m, LossConfig(value_head_reduce="mean")).value_loss
    torch.manual_seed(1)
    a = summed(td)["loss_value"]
    torch.manual_seed(1)
    b = averaged(td)["loss_value"]
    torch.testing.assert_close(b * m.value.net.num_q, a)
    with pytest.raises(Exception, match="value_head_reduce"):
        LossConfig(value_head_reduce="max")


@pytest.mark.parametrize("which", ["value", "actor"])
def test_the_value_and_actor_losses_never_read_the_expert_observations(which):
    m = tiny_modules()
    cls = LambdaReturnValueLoss if which == "value" else MultiStepActorLoss
    poisoned = replay_batch()
    poisoned["expert"] = poisoned["expert"].apply(lambda x: torch.full_like(x, float("nan")))
    assert torch.isfinite(cls(m.encoder, m.dynamics, m.reward, m.value, m.policy)(poisoned)[f"loss_{which}"])


def test_imagined_branches_are_steps_of_noisy_policy_plans_through_the_dynamics():
    m = tiny_modules()
    loss = LambdaReturnValueLoss(m.encoder, m.dynamics, m.reward, m.value, m.policy, branch_fraction=0.5,
                                 branch_noise=5.0)
    z = torch.randn(8, 16)
    torch.manual_seed(0)
    z_b, a_b, z_b_next = loss.imagined_branches(z)
    assert z_b.shape == (4, 16) and a_b.shape == (4, 2) and z_b_next.shape == (4, 16)
    assert a_b.abs().max() <= 1.0 and (a_b.abs() == 1.0).any()  # large noise, clipped to the action box
    torch.testing.assert_close(z_b_next, m.dynamics.module(z_b, a_b))  # one step of the model from z_b
    assert LambdaReturnValueLoss(m.encoder, m.dynamics, m.reward, m.value, m.policy).imagined_branches(z) is None
    with pytest.raises(ValueError, match="branch_fraction"):
        LambdaReturnValueLoss(m.encoder, m.dynamics, m.reward, m.value, m.policy, branch_fraction=-0.5)


@pytest.mark.parametrize("mask_terminal", [False, True])
def test_value_branches_join_the_regression_and_train_q_alone(mask_terminal):
    m = tiny_modules()
    cfg = LossConfig(value_branch_fraction=0.5, value_branch_noise=0.2, mask_terminal=mask_terminal)
    loss = MPAIL2Loss(m, cfg).value_loss
    assert (loss.branch_fraction, loss.branch_noise) == (0.5, 0.2)
    batch = replay_batch(batch=4, steps=3)
    batch["next", "terminated"][:, -1] = True
    seen = []
    target = loss.target

    def recording_target(z, z_next, terminated=None):
        seen.append((z.shape[0], None if terminated is None else terminated.reshape(-1).clone()))
        return target(z, z_next, terminated)

    loss.target = recording_target
    loss(batch)["loss_value"].backward()
    rows, terminated = seen[0]
    assert rows == 12 + 6  # the 12 replayed transitions and round(0.5 * 12) imagined ones
    if mask_terminal:
        assert terminated[:12].sum() == 4 and not terminated[12:].any()  # imagined steps never terminate
    assert _has_grad(m.value)
    for other in (m.encoder, m.dynamics, m.reward, m.policy):
        assert _no_grad(other)
    with pytest.raises(ConfigError, match="value_branch_fraction"):
        LossConfig(value_branch_fraction=-1.0)
