"""MPAIL2 on the point mass in a plain TorchRL loop: a Collector driving the planner, a replay buffer whose
SliceSampler draws H-step slices and whose transform attaches expert windows, and the learner update.
The README's "Use the pieces" section shows this file's code; tests/test_examples.py runs it.

    python examples/minimal_loop.py        # about 2.5 minutes on one CPU thread; prints the evaluation success
"""
import torch
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.data.replay_buffers import SliceSampler
from torchrl.envs.utils import ExplorationType, set_exploration_type

from torchrl_mpail2 import (AttachExpertWindows, LatentMPPIPlanner, LossConfig, ModelConfig, MPAIL2Loss,
                            MPAIL2Updater, PlannerConfig, make_mpail2_modules, record_demos)
from torchrl_mpail2.envs import make_env
from torchrl_mpail2.experts import PointMassExpert


def main(episodes=40, num_demos=20, batch_size=64, updates_per_episode=50, num_candidates=128, eval_episodes=10):
    torch.manual_seed(0)
    env = make_env("point_mass", seed=0)  # 50-step episodes, actions in [-1, 1], reward hidden from the learner
    demos = record_demos(make_env("point_mass", seed=1), PointMassExpert(), num_demos, seed=1, progress=False)
    cfg = ModelConfig(latent_dim=32, hidden_dims=(64, 64), vector_coder_hidden=64, coder_dim=64, horizon=5)
    H = cfg.horizon
    modules = make_mpail2_modules(env.observation_spec, env.action_spec, cfg, demos=demos)  # normalised by the demos
    # one Adam per stage, paper order; the point_mass preset's running reward scale (the paper: the raw critic)
    updater = MPAIL2Updater(MPAIL2Loss(modules, LossConfig(encoder_lr=3e-4, reward_scale_momentum=0.99)))
    planner = LatentMPPIPlanner(modules, env.action_spec,
                                PlannerConfig(num_candidates=num_candidates, num_elites=16, iterations=3),
                                gamma=updater.loss.cfg.gamma)  # plans discounted as the value is
    replay = TensorDictReplayBuffer(
        storage=LazyTensorStorage(episodes * 50), batch_size=batch_size * H,
        sampler=SliceSampler(slice_len=H, traj_key=("collector", "traj_ids"), strict_length=True),
        transform=AttachExpertWindows(demos, H))  # sample(): [B * H] slices + expert windows under "expert"
    collector = Collector(env, planner, frames_per_batch=50, total_frames=episodes * 50)  # one episode a batch
    for data in collector:
        replay.extend(data)
        for _ in range(updates_per_episode):
            metrics = updater.update(replay.sample().reshape(-1, H))  # [B, H], the layout of MPAIL2Loss
    collector.shutdown()

    successes, actions = [], []
    with set_exploration_type(ExplorationType.DETERMINISTIC):  # the planner returns its mean plan
        for seed in range(1000, 1000 + eval_episodes):
            env.set_seed(seed)
            planner.reset()  # forget the warm start of the previous episode
            rollout = env.rollout(50, planner, break_when_any_done=True)
            successes.append(float(rollout["next", "success"][-1]))
            actions.append(rollout["action"])
    return {"success_rate": sum(successes) / len(successes), "actions": torch.cat(actions),
            "metrics": {k: float(v) for k, v in metrics.items()}}


if __name__ == "__main__":
    print(f"evaluation success: {main()['success_rate']:.2f}")
