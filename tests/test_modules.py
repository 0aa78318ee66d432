import pytest
import torch
from tensordict import TensorDict
from torchrl.data import Bounded, Composite, Unbounded

from conftest import BATCH_SHAPES, TINY, tiny_modules
from torchrl_mpail2.config import ConfigError, ModelConfig
from torchrl_mpail2.modules import (
    LatentDynamics, MPAIL2Modules, MultiStepPolicy, ObservationEncoder, QEnsemble, TransitionReward,
    make_mpail2_modules,
)

Z, A, H = 16, 2, 3


def _count(module):
    return sum(p.numel() for p in module.parameters())


def test_parameter_counts_match_the_paper_printout():
    """Fig. 14: two 64x64 cameras + 8-D proprioception, A = 4, latent 512, hidden [512, 512], H = 7."""
    modules = MPAIL2Modules({"proprio": [8], "external_image": [3, 64, 64], "wrist_image": [3, 64, 64]}, 4, ModelConfig())
    assert _count(modules.encoder) == 2327744
    assert _count(modules.dynamics) == 793088
    assert _count(modules.reward) == 787968
    assert _count(modules.value) == 2649605  # five heads
    assert _count(modules.policy) == 556088


@pytest.mark.parametrize("batch", BATCH_SHAPES)
def test_encoder_shapes_vector_and_image(batch):
    enc = ObservationEncoder({"proprio": [5], "camera": [3, 64, 64]}, Z, [32], coder_dim=32, vector_coder_hidden=32,
                             cnn_channels=8)
    td = TensorDict({"proprio": torch.randn(*batch, 5),
                     "camera": torch.randint(0, 256, (*batch, 3, 64, 64), dtype=torch.uint8)}, batch)
    z = enc(td)["z"]
    assert z.shape == (*batch, Z)
    # uint8 and the equivalent float image in [0, 1] give the same latent
    td_float = td.clone()
    td_float["camera"] = td["camera"].float() / 255
    assert torch.allclose(enc(td_float)["z"], z, atol=1e-5)


@pytest.mark.parametrize("batch", BATCH_SHAPES)
def test_dynamics_reward_value_policy_shapes(batch):
    td = TensorDict({"z": torch.randn(*batch, Z), "action": torch.rand(*batch, A)}, batch)
    LatentDynamics(Z, A, [32])(td)
    assert td["next", "z"].shape == (*batch, Z)
    TransitionReward(Z, [32])(td)
    assert td["learned_reward"].shape == (*batch, 1)
    QEnsemble(Z, A, [32], num_q=5)(td)
    assert td["state_action_value"].shape == (*batch, 5, 1)
    MultiStepPolicy(Z, A, H, [32])(td)
    assert td["plan"].shape == (*batch, H, A)
    assert td["plan_log_prob"].shape == (*batch, 1)
    assert torch.equal(td["action"], td["plan"][..., 0, :])


def test_qensemble_heads_are_independent_and_selectable():
    q = QEnsemble(Z, A, [32], num_q=5).net
    z, a = torch.randn(7, Z), torch.rand(7, A)
    full = q(z, a)
    assert full.shape == (5, 7, 1)
    assert not torch.allclose(full[0], full[1])  # heads are initialised independently
    heads = torch.tensor([3, 1])
    assert torch.allclose(q(z, a, heads=heads), full[heads], atol=1e-6)
    # a head evaluated alone equals an ordinary MLP with that head's weights
    h = 2
    x = torch.cat([z, a], -1)
    for lin, norm in zip(q.linears, q.norms):
        pre = x @ lin.weight[h] + lin.bias[h]
        x = torch.nn.functional.silu(torch.nn.functional.layer_norm(pre, pre.shape[-1:]) * norm.weight[h] + norm.bias[h])
    ref = x @ q.head.weight[h] + q.head.bias[h]
    assert torch.allclose(ref, full[h], atol=1e-5)


def test_reward_has_no_layernorm_and_no_output_bias():
    net = TransitionReward(Z, [32, 32]).module
    assert not any(isinstance(m, torch.nn.LayerNorm) for m in net.modules())
    assert net.net[-1].bias is None
    z, z2 = torch.randn(5, Z), torch.randn(5, Z)
    h_now, _ = net.project(z)
    _, h_next = net.project(z2)
    assert torch.allclose(net.from_projection(h_now, h_next), net(z, z2), atol=1e-5)


def test_policy_deterministic_mode_returns_the_squashed_mean():
    from tensordict.nn import InteractionType, set_interaction_type
    pi = MultiStepPolicy(Z, A, H, [32])
    td = TensorDict({"z": torch.randn(4, Z)}, [4])
    with set_interaction_type(InteractionType.DETERMINISTIC):
        a1 = pi(td.clone())["plan"]
        a2 = pi(td.clone())["plan"]
    assert torch.equal(a1, a2)
    mean, _ = pi.net.distribution_params(td["z"])
    assert torch.allclose(a1, torch.tanh(mean))
    assert not torch.equal(pi(td.clone())["plan"], pi(td.clone())["plan"])  # random mode samples


def test_state_dict_round_trip():
    a, b = tiny_modules(), tiny_modules()
    z = torch.randn(3, TINY["latent_dim"])
    assert not torch.allclose(a.reward.module(z, z), b.reward.module(z, z))
    b.load_state_dict(a.state_dict())
    act = torch.rand(3, 2)
    assert torch.equal(a.dynamics.module(z, act), b.dynamics.module(z, act))
    assert torch.equal(a.reward.module(z, z), b.reward.module(z, z))
    assert torch.equal(a.value.net(z, act), b.value.net(z, act))
    assert torch.equal(a.policy.net(z, deterministic=True)[0], b.policy.net(z, deterministic=True)[0])
    obs = TensorDict({"observation": torch.randn(3, 3)}, [3])
    assert torch.equal(a.encoder(obs.clone())["z"], b.encoder(obs.clone())["z"])


def test_normalisation_from_statistics_and_clip():
    enc = ObservationEncoder({"observation": [2]}, Z, [32], coder_dim=32, vector_coder_hidden=32)
    enc.net.set_normalization({"observation": (torch.tensor([10.0, -10.0]), torch.tensor([2.0, 0.5]))})
    x = torch.tensor([[12.0, -10.5]])
    # normalised to [1, -1]; a raw input of [1, -1] with identity stats must then give the same latent
    ref = ObservationEncoder({"observation": [2]}, Z, [32], coder_dim=32, vector_coder_hidden=32)
    ref.load_state_dict({k: v for k, v in enc.state_dict().items() if "obs_" not in k}, strict=False)
    assert torch.allclose(enc.net(x), ref.net(torch.tensor([[1.0, -1.0]])), atol=1e-6)
    # clipping at obs_clip = 5: [1e6, 0] normalises to [~5e5, 20], clipped to [5, 5]
    assert torch.allclose(enc.net(torch.tensor([[1e6, 0.0]])), ref.net(torch.tensor([[5.0, 5.0]])), atol=1e-6)
    with pytest.raises(ValueError, match="expected shape \\[2\\]"):
        enc.net.set_normalization({"observation": (torch.zeros(3), torch.ones(3))})


def test_compartmentalised_latent_lets_the_reward_read_a_subset():
    cfg = ModelConfig(**{**TINY, "fuse_latent": False, "reward_latent_keys": ("external_image",)})
    m = MPAIL2Modules({"proprio": [4], "external_image": [3, 64, 64]}, A, cfg)
    slices = m.encoder.net.latent_slices
    assert slices["proprio"] == slice(0, 8) and slices["external_image"] == slice(8, 16)
    td = TensorDict({"proprio": torch.randn(2, 4), "external_image": torch.rand(2, 3, 64, 64)}, [2])
    z = m.encoder(td)["z"]
    # changing the proprioception moves only its own block of the latent
    td2 = td.clone()
    td2["proprio"] = td2["proprio"] + 1
    z2 = m.encoder(td2)["z"]
    assert not torch.allclose(z2[:, :8], z[:, :8]) and torch.allclose(z2[:, 8:], z[:, 8:])
    # ... and the reward, reading only the image block, ignores it
    assert torch.allclose(m.reward.module(z, z), m.reward.module(z2, z2))
    with pytest.raises(ConfigError, match="fuse_latent=False"):
        ModelConfig(reward_latent_keys=("proprio",))


def test_bad_inputs_name_the_key_and_expected_shape():
    enc = ObservationEncoder({"proprio": [5], "camera": [3, 64, 64]}, Z, [32], coder_dim=32, vector_coder_hidden=32,
                             cnn_channels=8)
    good = {"proprio": torch.randn(2, 5), "camera": torch.zeros(2, 3, 64, 64, dtype=torch.uint8)}
    with pytest.raises(KeyError, match="missing key 'camera'.*\\[\\*B, 3, 64, 64\\]"):
        enc(TensorDict({"proprio": good["proprio"]}, [2]))
    with pytest.raises(ValueError, match="'proprio': expected shape \\[\\*B, 5\\], got \\[2, 6\\]"):
        enc(TensorDict({**good, "proprio": torch.randn(2, 6)}, [2]))
    with pytest.raises(ValueError, match="'camera': expected shape \\[\\*B, 3, 64, 64\\], got \\[2, 64, 64, 3\\]"):
        enc(TensorDict({**good, "camera": torch.zeros(2, 64, 64, 3, dtype=torch.uint8)}, [2]))
    bad = good["proprio"].clone()
    bad[1, 2] = float("nan")
    with pytest.raises(ValueError, match="'proprio' contains NaN or Inf"):
        enc(TensorDict({**good, "proprio": bad}, [2]))
    dyn = LatentDynamics(Z, A, [32])
    with pytest.raises(ValueError, match="'action': expected shape \\[\\*B, 2\\], got \\[4, 3\\]"):
        dyn.module(torch.randn(4, Z), torch.randn(4, 3))
    with pytest.raises(ValueError, match="'z': expected shape \\[\\*B, 16\\], got \\[4, 15\\]"):
        QEnsemble(Z, A, [32]).net(torch.randn(4, 15), torch.randn(4, A))


def test_factory_reads_specs_and_rejects_unnormalised_actions():
    obs_spec = Composite(observation=Unbounded((3,)), success=Unbounded((1,), dtype=torch.bool),
                         step_count=Unbounded((1,), dtype=torch.int64))
    m = make_mpail2_modules(obs_spec, Bounded(-1, 1, (2,)), ModelConfig(**TINY))
    assert m.observation_shapes == {"observation": (3,)} and m.action_dim == 2
    with pytest.raises(ValueError, match="bounded to \\[-1, 1\\]"):
        make_mpail2_modules(obs_spec, Bounded(-0.4, 0.4, (2,)), ModelConfig(**TINY))
    with pytest.raises(KeyError, match="'pixels' not in the observation spec"):
        make_mpail2_modules(obs_spec, Bounded(-1, 1, (2,)), ModelConfig(**TINY), observation_keys=["pixels"])


def test_reward_loads_a_state_dict_from_before_the_running_scale():
    m = tiny_modules()
    old = {k: v for k, v in m.reward.state_dict().items() if "scale" not in k}
    other = tiny_modules()
    other.reward.module.reward_scale.fill_(7.0)
    other.reward.load_state_dict(old)  # strict: the scale buffers default to the raw critic
    assert other.reward.module.reward_scale.item() == 1.0 and other.reward.module.scale_updates.item() == 0
    z = torch.randn(4, 16)
    assert torch.equal(other.reward.module(z, z), m.reward.module(z, z))


def test_modules_built_from_demos_take_their_observation_normalisation():
    from torchrl_mpail2.data import demos_from_arrays
    from torchrl_mpail2.modules import make_mpail2_modules

    spec = Composite(observation=Unbounded((2,)), camera=Unbounded((3, 64, 64), dtype=torch.uint8))
    episode = {"observation": torch.tensor([[0.0, 5.0], [2.0, 5.0], [4.0, 5.0]]),
               "camera": torch.zeros(3, 3, 64, 64, dtype=torch.uint8)}
    demos = demos_from_arrays([episode])
    cfg = ModelConfig(**TINY)
    modules = make_mpail2_modules(spec, Bounded(-1, 1, (A,)), cfg, demos=demos)
    net = modules.encoder.net
    assert net.keys == ["observation", "camera"]  # the demos' keys by default
    assert torch.allclose(net.obs_mean_observation, torch.tensor([2.0, 5.0]))
    assert torch.allclose(net.obs_std_observation, torch.tensor([(8 / 3) ** 0.5, 1e-3]))  # constant dim floored
    plain = make_mpail2_modules(spec, Bounded(-1, 1, (A,)), cfg)
    assert torch.equal(plain.encoder.net.obs_mean_observation, torch.zeros(2))  # no demos: identity
    assert torch.equal(plain.encoder.net.obs_std_observation, torch.ones(2))
    assert plain.normalize_from_demos(demos) is plain
    assert torch.equal(plain.encoder.net.obs_std_observation, net.obs_std_observation)


def test_normalisation_from_demos_names_a_missing_key_or_a_wrong_shape():
    from torchrl_mpail2.data import demos_from_arrays

    modules = MPAIL2Modules({"observation": [3], "proprio": [2]}, A, ModelConfig(**TINY))
    with pytest.raises(KeyError, match=r"reads observation keys \['proprio'\] that the demonstrations"):
        modules.normalize_from_demos(demos_from_arrays([torch.zeros(4, 3)]))
    wrong = demos_from_arrays([{"observation": torch.zeros(4, 4), "proprio": torch.zeros(4, 2)}])
    with pytest.raises(ValueError, match=r"'observation' has shape \[4\] in the demonstrations .* \[3\] in the encoder"):
        modules.normalize_from_demos(wrong)


def test_image_coder_channels_last_computes_the_plain_cnn():
    """The channels-last convolutions against the plain computation written out with F.conv2d on contiguous
    tensors, for outputs and for the gradients of every parameter."""
    import torch.nn.functional as F

    from torchrl_mpail2.modules.encoder import ImageCoder

    torch.manual_seed(0)
    coder = ImageCoder((3, 64, 64), 8, 16)
    images = torch.randint(0, 256, (2, 5, 3, 64, 64), dtype=torch.uint8)

    def plain(x):
        h = x.reshape(-1, 3, 64, 64).float() / 255.0 - 0.5
        for conv in (m for m in coder.convs if isinstance(m, torch.nn.Conv2d)):
            h = F.silu(F.conv2d(h, conv.weight.contiguous(), conv.bias, stride=conv.stride))
        return F.silu(F.linear(h.flatten(1), coder.out[0].weight, coder.out[0].bias)).reshape(2, -1, 16)

    got, want = coder(images), plain(images)
    assert got.shape == (2, 5, 16)
    torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-6)
    grads = torch.autograd.grad(got.square().sum(), list(coder.parameters()))
    want_grads = torch.autograd.grad(want.square().sum(), list(coder.parameters()))
    for g, w in zip(grads, want_grads):
        torch.testing.assert_close(g, w, rtol=1e-4, atol=1e-6)


def test_image_coder_standardises_in_one_pass_as_the_written_out_formula():
    """clip((x / 255 - mu) / sigma) per pixel, for uint8 and float [0, 1] frames, with demonstration statistics that
    make the clip bite: the fused pass x * a + b gives the same frames up to float rounding, channels-last."""
    from torchrl_mpail2.modules.encoder import ImageCoder

    torch.manual_seed(0)
    coder = ImageCoder((3, 32, 32), 4, 6, clip=2.0)
    coder.pixel_mean.copy_(torch.rand(3, 32, 32))
    coder.pixel_std.copy_(torch.rand(3, 32, 32) * 0.2 + 0.05)
    images = torch.randint(0, 256, (2, 3, 3, 32, 32), dtype=torch.uint8)
    want = ((images.reshape(-1, 3, 32, 32).float() / 255.0 - coder.pixel_mean) / coder.pixel_std).clamp(-2.0, 2.0)
    for frames in (images, images.float() / 255.0):
        got = coder._normalised(frames)
        assert got.dtype == torch.float32 and got.is_contiguous(memory_format=torch.channels_last)
        assert (got.abs() == 2.0).any() and (got.abs() < 2.0).any()  # the clip bites on some pixels, not all
        torch.testing.assert_close(got, want, rtol=1e-5, atol=1e-5)


def test_image_coder_loads_a_state_dict_from_before_the_pixel_statistics_as_centred():
    from torchrl_mpail2.modules.encoder import ImageCoder

    coder = ImageCoder((3, 64, 64), 8, 16)
    coder.pixel_mean.fill_(0.2)  # as if normalised from demonstrations
    old = {k: v for k, v in coder.state_dict().items() if not k.startswith("pixel_")}
    coder.load_state_dict(old)  # strict: the missing buffers are filled in, as the old code centred pixels
    assert torch.equal(coder.pixel_mean, torch.full((3, 64, 64), 0.5)) and torch.equal(coder.pixel_std, torch.ones(3, 64, 64))


def test_the_world_model_verbs_are_the_networks_walked_forward():
    """``imagine`` steps f_psi through the plan, ``rewards`` scores each consecutive pair as r_theta does, ``q`` and
    ``pi`` are the ensemble's heads and the policy's plan, ``draw_heads`` two distinct heads."""
    m = tiny_modules()
    z0, plan = torch.randn(5, 16), torch.rand(5, 3, 2) * 2 - 1
    latents = m.imagine(z0, plan)
    assert latents.shape == (4, 5, 16) and torch.equal(latents[0], z0)
    z = z0
    for k in range(3):
        z = m.dynamics.module(z, plan[:, k])
        torch.testing.assert_close(latents[k + 1], z)
    expected = torch.stack([m.reward.module(latents[k], latents[k + 1]).squeeze(-1) for k in range(3)])
    torch.testing.assert_close(m.rewards(latents), expected, rtol=1e-5, atol=1e-6)
    heads = m.draw_heads("cpu", torch.Generator().manual_seed(0))
    assert heads.unique().numel() == 2 and m.q(z0, plan[:, 0], heads).shape == (2, 5)
    assert m.q(z0, plan[:, 0]).shape == (m.value.net.num_q, 5)
    mean_plan, log_prob = m.pi(z0, deterministic=True)
    assert mean_plan.shape == (5, 3, 2) and log_prob.shape == (5,)
    td = TensorDict({"observation": torch.randn(5, 3)}, [5])
    torch.testing.assert_close(m.encode(td), m.encoder.encode(td))


def test_the_step_by_step_walk_gives_the_batched_path_and_rewards():
    from torchrl_mpail2.modules.world_model import chain_rewards, imagine_with_rewards, rollout_latents

    torch.manual_seed(0)
    m = tiny_modules(obs_dim=3, action_dim=2, horizon=4)
    z0, plan = torch.randn(6, m.cfg.latent_dim), torch.rand(6, 4, 2) * 2 - 1
    latents, rewards = imagine_with_rewards(m.dynamics.module, m.reward.module, z0, plan)
    batched = rollout_latents(m.dynamics.module, z0, plan)
    assert latents.shape == (5, 6, m.cfg.latent_dim) and rewards.shape == (4, 6)
    torch.testing.assert_close(latents, batched)
    torch.testing.assert_close(rewards, chain_rewards(m.reward.module, batched), rtol=1e-6, atol=1e-6)
    empty = imagine_with_rewards(m.dynamics.module, m.reward.module, z0, plan[:, :0])
    assert empty[0].shape == (1, 6, m.cfg.latent_dim) and empty[1].shape == (0, 6)
