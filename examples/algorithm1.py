"""Algorithm 1 of the paper (MPAIL2), spelled out top to bottom with the library's pieces.

Everything `MPAIL2Trainer` and `MPAIL2Updater` do for a run is written out here, in the paper's order: the
environment and the observation-only demonstrations, the five networks, the four losses with their optimisers,
TorchRL's collector driving the latent MPPI planner, the replay buffer whose SliceSampler draws H-step windows,
and the evaluation on fixed episodes. What it leaves out (checkpoints, resuming, logging, the ablations, mixed
precision) is the trainer's business; `tests/test_examples.py` checks that one update here moves every weight
exactly as `MPAIL2Updater` does.

    python examples/algorithm1.py                                    # the point mass: about 3 minutes, one thread
    python examples/algorithm1.py --preset push_state --episodes 100 # robosuite Push from state: hours on a CPU
"""
from __future__ import annotations

import argparse

import torch
from torchrl.collectors import Collector
from torchrl.data import LazyTensorStorage, TensorDictReplayBuffer
from torchrl.data.replay_buffers import SliceSampler
from torchrl.objectives import SoftUpdate

from torchrl_mpail2 import AttachExpertWindows, LatentMPPIPlanner, MPAIL2Loss, make_mpail2_modules, record_demos
from torchrl_mpail2.envs import make_env
from torchrl_mpail2.experts import get_expert
from torchrl_mpail2.objectives import sample_window_transitions
from torchrl_mpail2.planners.policy_actor import WarmupSwitch
from torchrl_mpail2.config import apply_overrides, preset
from torchrl_mpail2.data import TRAJ_KEY
from torchrl_mpail2.trainers.evaluation import evaluate_episodes, evaluation_seeds, summarize_outcomes

class Losses:
    """The four objectives of Section 3, as the package builds them from the config (``MPAIL2Loss``), each with its
    own Adam optimiser over the parameter groups the package declares (Table 4's learning rates and clips)."""

    def __init__(self, modules, cfg):
        self.loss = MPAIL2Loss(modules, cfg)
        self.optimizers, self.clips = {}, {}
        for stage, groups in self.loss.param_groups().items():
            # the encoder learns only through the dynamics loss, ten times slower than the rest (Table 4)
            self.optimizers[stage] = torch.optim.Adam([{"params": g["params"], "lr": g["lr"]} for g in groups])
            self.clips[stage] = groups[0]["max_grad_norm"]
        self.polyak = SoftUpdate(self.loss.value_loss, tau=cfg.tau)  # the target Q-ensemble trails the online one
        self.transitions_per_window = cfg.transitions_per_window

    def step(self, stage: str, loss: torch.Tensor) -> None:
        """One gradient step of one stage's optimiser (a non-finite loss is skipped)."""
        if not torch.isfinite(loss):
            return
        optimizer = self.optimizers[stage]
        optimizer.zero_grad(set_to_none=True)
        loss.backward()
        if self.clips[stage] is not None:
            params = [p for group in optimizer.param_groups for p in group["params"]]
            torch.nn.utils.clip_grad_norm_(params, self.clips[stage])
        optimizer.step()

    def update(self, batch) -> dict:
        """Algorithm 1's inner loop on one batch of replayed H-step windows ``[B, H]`` with expert windows."""
        L = self.loss
        # 1. Eq. 2: encoder and dynamics, multi-step latent prediction against stop-gradient encodings of the
        # observed future, on whole windows
        out = L.dynamics_loss(batch)
        self.step("dynamics", out["loss_dynamics"])
        # The reward, value and policy objectives are expectations over single transitions: draw a few per window,
        # and encode them once with the encoder just updated (stop-gradient: no later stage moves the encoder).
        transitions = sample_window_transitions(batch, self.transitions_per_window)
        latents = L.replay_latents(transitions)
        # 2. Eq. 3: the WGAN-GP critic r(z, z'), expert transitions up, replayed ones down, gradient penalty
        out.update(L.reward_loss(transitions, latents=latents))
        self.step("reward", out["loss_reward"])
        # 3. Eq. 4: the Q-ensemble regressed on lambda-returns (Eq. 6) of imagined rollouts under the learned
        # reward, then Polyak averaging of its target
        out.update(L.value_loss(transitions, latents=latents))
        self.step("value", out["loss_value"])
        self.polyak.step()
        # 4. Eq. 5: the multi-step policy maximises the same return plus an entropy bonus; then its temperature
        out.update(L.actor_loss(transitions, latents=latents))
        self.step("actor", out["loss_actor"])
        self.step("alpha", out["loss_alpha"])
        return {k: float(v.detach()) for k, v in out.items()}


def evaluate(env, planner, cfg, episodes: int) -> dict:
    """Deterministic planner on the fixed evaluation episodes (env seed ``eval_seed + i``, noise seeded alike)."""
    return summarize_outcomes(evaluate_episodes(env, planner, evaluation_seeds(cfg.train.eval_seed, episodes), planner))


def main(preset_name: str = "point_mass", episodes: int | None = None, num_demos: int | None = None,
         eval_every: int | None = None, eval_episodes: int | None = None, updates_per_episode: int | None = None,
         seed: int = 0, overrides=None) -> list[dict]:
    cfg = preset(preset_name)
    if overrides:  # {"section.field": value}, checked as the command line's, e.g. {"planner.num_candidates": 32}
        cfg = apply_overrides(cfg, overrides)
    t = cfg.train
    episodes, num_demos = episodes or t.total_episodes, num_demos or t.num_demos
    eval_every, eval_episodes = eval_every or t.eval_every, eval_episodes or t.eval_episodes
    torch.manual_seed(seed)

    # The task and the expert's observations (no actions, no rewards: imitation from observation).
    env = make_env(t.env, obs=t.obs, seed=seed, **(t.env_kwargs or {}))
    demo_env = make_env(t.env, obs=t.obs, seed=seed + 1_000_000, **(t.env_kwargs or {}))
    demos = record_demos(demo_env, get_expert(t.env, demo_env), num_demos, seed=seed + 1_000_000, progress=False)
    eval_env = make_env(t.env, obs=t.obs, seed=t.eval_seed, **(t.env_kwargs or {}))

    # e_omega, f_psi, r_theta, Q_zeta (an ensemble) and pi_phi; observations normalised by the demos' statistics.
    modules = make_mpail2_modules(env.observation_spec, env.action_spec, cfg.model, demos=demos)
    losses = Losses(modules, cfg.loss)
    # Algorithm 2: latent MPPI seeded by the policy's plans, scored by the learned reward and Q.
    planner = LatentMPPIPlanner(modules, env.action_spec, cfg.planner, gamma=cfg.loss.gamma)
    # uniform random actions during the warm-up episodes
    actor = WarmupSwitch(planner, env.action_spec, random_actions=t.warmup_episodes > 0)

    H = cfg.model.horizon
    steps_per_episode = int(getattr(env, "horizon", 0) or getattr(env.base_env, "horizon", 0) or 1000)
    replay = TensorDictReplayBuffer(
        storage=LazyTensorStorage(episodes * steps_per_episode), batch_size=t.batch_size * H,
        sampler=SliceSampler(slice_len=H, traj_key=TRAJ_KEY, strict_length=True),
        transform=AttachExpertWindows(demos, H))  # each sample: [B * H] steps + H-step expert windows
    collector = Collector(env, actor, frames_per_batch=steps_per_episode, total_frames=episodes * steps_per_episode)

    history = []
    for episode, data in enumerate(collector, start=1):
        replay.extend(data)  # off-policy: every transition is kept (Table 4: unbounded replay)
        actor.random_actions = episode < t.warmup_episodes  # applies from the next batch on
        metrics = {}
        if episode >= t.warmup_episodes:
            for _ in range(updates_per_episode or max(1, round(t.utd * data.numel()))):
                metrics = losses.update(replay.sample().reshape(-1, H))
        if eval_every and (episode % eval_every == 0 or episode == episodes):
            result = evaluate(eval_env, planner, cfg, eval_episodes)
            history.append({"episode": episode, **result, **{k: v for k, v in metrics.items() if k.startswith("loss_")}})
            print(f"episode {episode}: success {result['success_rate_any_step']:.2f} (any step), "
                  f"{result['success_rate']:.2f} (last step)", flush=True)
    collector.shutdown()
    return history


if __name__ == "__main__":
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--preset", default="point_mass", help="a preset of torchrl_mpail2.config.PRESETS")
    p.add_argument("--episodes", type=int, help="default: the preset's train.total_episodes")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--threads", type=int, default=1)
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    main(args.preset, args.episodes, seed=args.seed)
