"""AttachExpertWindows: expert windows beside replay slices, in the layout MPAIL2Loss reads."""
import pytest
import torch
from tensordict import TensorDict
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.data.replay_buffers import SliceSampler

from conftest import tiny_modules
from torchrl_mpail2.data import TRAJ_KEY, AttachExpertWindows, DemoBuffer, demos_from_arrays
from torchrl_mpail2.objectives import MPAIL2Loss

H = 3


def _labelled_demos(lengths=(10, 12)):
    """Episodes whose observation is 100 * episode + step, so windows show where they come from."""
    return demos_from_arrays([(100.0 * i + torch.arange(n + 1.0)).unsqueeze(-1) for i, n in enumerate(lengths)])


def _episodes(lengths=(20, 15, 25), obs_dim=1):
    steps = sum(lengths)
    traj = torch.repeat_interleave(torch.arange(len(lengths)), torch.tensor(lengths))
    return TensorDict({"observation": torch.randn(steps, obs_dim), "action": torch.rand(steps, 2) * 2 - 1,
                       ("next", "observation"): torch.randn(steps, obs_dim),
                       ("next", "terminated"): torch.zeros(steps, 1, dtype=torch.bool),
                       ("next", "done"): torch.zeros(steps, 1, dtype=torch.bool), TRAJ_KEY: traj}, [steps])


def _replay(transform, batch=4, slice_len=H):
    replay = TensorDictReplayBuffer(storage=LazyTensorStorage(200), batch_size=batch * slice_len,
                                    sampler=SliceSampler(slice_len=slice_len, traj_key=TRAJ_KEY, strict_length=True))
    replay.append_transform(transform)
    replay.extend(_episodes())
    return replay


def _check_windows(expert):
    """Each row of a [n, H] window holds consecutive steps of one demonstration episode."""
    obs, nxt = expert["observation"].squeeze(-1), expert["next", "observation"].squeeze(-1)
    assert torch.equal(nxt, obs + 1)
    assert torch.equal(obs[..., 1:], obs[..., :-1] + 1)


def test_flat_slice_samples_keep_their_shape_and_reshape_into_aligned_windows():
    replay = _replay(AttachExpertWindows(_labelled_demos(), H))
    sample = replay.sample()
    assert sample.shape == (4 * H,) and sample["expert"].shape == (4 * H,)
    assert "index" in sample.keys() and ("next", "truncated") in sample.keys(True)  # the sampler's info still fits
    batch = sample.reshape(-1, H)
    assert batch["expert"].shape == (4, H)
    _check_windows(batch["expert"])


def test_windows_are_the_demo_buffers_own_draws():
    """Same generator state, same windows as DemoBuffer.sample_windows: the trainer's batches are unchanged."""
    demos = _labelled_demos()
    transform = AttachExpertWindows(DemoBuffer(demos, generator=torch.Generator().manual_seed(5)), H)
    out = transform(TensorDict({"observation": torch.zeros(6 * H, 1)}, [6 * H]))
    direct = DemoBuffer(demos, generator=torch.Generator().manual_seed(5)).sample_windows(6, H)
    assert torch.equal(out["expert"].reshape(6, H)["observation"], direct["observation"])


@pytest.mark.parametrize("shape", [(4 * H,), (H,), (4, H), (2, 3, H), (0,), (0, H)])
def test_expert_windows_take_the_samples_shape(shape):
    td = TensorDict({"observation": torch.zeros(*shape, 1)}, list(shape))
    out = AttachExpertWindows(_labelled_demos(), H)(td)
    assert out.batch_size == torch.Size(shape)
    assert out["expert", "observation"].shape == (*shape, 1) and out["expert", "next", "observation"].shape == (*shape, 1)
    _check_windows(out["expert"].reshape(out.numel() // H, H))


@pytest.mark.parametrize("shape", [(), (4,), (2, 4)])
def test_a_sample_that_is_not_made_of_windows_is_refused_naming_its_shape(shape):
    td = TensorDict({"observation": torch.zeros(*shape, 1)}, list(shape))
    with pytest.raises(ValueError, match=rf"horizon=3\): the replay sample has batch shape \[{', '.join(map(str, shape))}\]"):
        AttachExpertWindows(_labelled_demos(), H)(td)


def test_windows_crossing_trajectories_are_refused_naming_the_key():
    td = TensorDict({"observation": torch.zeros(6, 1), TRAJ_KEY: torch.tensor([0, 0, 1, 1, 1, 1])}, [6])
    transform = AttachExpertWindows(_labelled_demos(), H)
    with pytest.raises(ValueError, match=r"1 of 2 windows .* change \('collector', 'traj_ids'\) within 3 steps"):
        transform(td)
    transform.set_keys(traj_ids="episode_id")  # a sample without that key is not checked
    assert transform(td)["expert"].shape == (6,)


def test_a_sampler_with_another_slice_length_is_caught():
    replay = _replay(AttachExpertWindows(_labelled_demos(), 2), batch=8, slice_len=3)
    torch.manual_seed(0)
    with pytest.raises(ValueError, match="SliceSampler\\(slice_len=2"):
        for _ in range(20):  # 24 steps cut into windows of 2: some windows straddle two slices of other trajectories
            replay.sample()


def test_bad_horizons_and_short_demos_are_refused():
    with pytest.raises(ValueError, match="horizon must be an integer >= 1, got 0"):
        AttachExpertWindows(_labelled_demos(), 0)
    with pytest.raises(ValueError, match=r"AttachExpertWindows\(horizon=13\): No episode has 13 steps \(longest: 12\)"):
        AttachExpertWindows(_labelled_demos(), 13)


def test_keys_are_remappable():
    transform = AttachExpertWindows(_labelled_demos(), H, out_key=("demo", "expert"))
    assert transform.out_keys == [("demo", "expert")]
    transform.set_keys(next="following")
    out = transform(TensorDict({"observation": torch.zeros(H, 1)}, [H]))
    assert ("demo", "expert", "following", "observation") in out.keys(True, True)
    assert ("demo", "expert", "next", "observation") not in out.keys(True, True)
    with pytest.raises(ValueError, match="'nxt' is not an accepted key"):
        transform.set_keys(nxt="x")


def test_the_loss_trains_on_what_the_buffer_returns():
    replay = _replay(AttachExpertWindows(_labelled_demos(), H))
    loss = MPAIL2Loss(tiny_modules(obs_dim=1))
    out = loss(replay.sample().reshape(-1, H))
    assert all(torch.isfinite(out[k]) for k in out.keys() if k.startswith("loss_"))


def test_it_is_not_an_environment_transform():
    from torchrl_mpail2.envs import make_env

    env = make_env("point_mass")
    env.append_transform(AttachExpertWindows(_labelled_demos(), H))
    with pytest.raises(RuntimeError, match="replay-buffer transform"):
        env.rand_step(env.reset())
