r"""Does the learned reward rank progress along an expert's path? The raw critic :math:`r_\theta(z_t, z_{t+1})` of a
checkpoint along demonstration episodes, averaged per window of steps, with its value :math:`Q_\zeta(z_t, a_t)` of the
policy's mean first action there.

    python -m torchrl_mpail2.diagnostics critic_profile CKPT [CKPT ...] --demos DIR [--window 5] [--out FILE.json] \
        [--plot FILE.png] [--agent-episodes N]

Demonstrations the run did not train on (another seed's scripted demos, say) show whether the reward generalises:
a critic that rises step by step along the held-out path rewards the task's progress; one that is flat over a phase
(the approach, the grasp) gives the planner nothing to climb there. On robosuite Lift and Push the rows add the
end-effector-to-cube distance where the episodes hold ``"object"``. ``--agent-episodes N`` profiles the checkpoint's
own agent too, on its first N fixed evaluation episodes (the plan's mean; camera runs get the simulator's
``"object"`` beside the pictures): a critic that scores the agent's steps as high as the expert's at the same step
pays for what the agent does instead of the task.
"""
from __future__ import annotations

import argparse
import json
from pathlib import Path

import torch
from tensordict import TensorDict

from torchrl_mpail2.diagnostics.figures import save_figure


def critic_along_episodes(encoder, reward_net, episodes: list[TensorDict], window: int = 5,
                          eef_to_cube: slice | None = None, q_net=None, policy_net=None) -> list[dict]:
    """Raw critic of consecutive observation pairs of ``episodes`` (each ``[T_i + 1]`` observations) per ``window``
    steps: ``[{step, critic_mean, critic_std, pairs}]`` (``step`` the window's first), plus ``eef_to_cube_m`` (mean
    end-effector-to-cube distance) when ``eef_to_cube`` says where ``"object"`` holds that offset, and ``q_mean``
    (the value of the policy's mean first action, mean over all heads) when ``q_net`` and ``policy_net`` are given.

    Args:
        encoder: has ``encode(observations) -> z`` (``MPAIL2Modules.encoder``).
        reward_net: has ``critic(z, z_next)`` (``MPAIL2Modules.reward.module``).
        q_net, policy_net: ``MPAIL2Modules.value.net`` and ``MPAIL2Modules.policy.net``.
    """
    if window < 1:
        raise ValueError(f"window must be >= 1, got {window}")
    if not episodes:
        raise ValueError("no episodes to profile")
    scores, steps, distances, values = [], [], [], []
    with torch.no_grad():
        for episode in episodes:
            if episode.shape[0] < 2:
                continue
            z = encoder.encode(episode)
            scores.append(reward_net.critic(z[:-1], z[1:]).squeeze(-1).float())
            steps.append(torch.arange(episode.shape[0] - 1))
            if eef_to_cube is not None:
                distances.append(episode["object"][:-1, eef_to_cube].norm(dim=-1).float())
            if q_net is not None and policy_net is not None:
                plan, _ = policy_net(z[:-1], deterministic=True)
                values.append(q_net(z[:-1], plan[..., 0, :].to(z.dtype)).mean(0).squeeze(-1).float())
    if not scores:
        raise ValueError("every episode has fewer than two observations: no pairs to score")
    score, step = torch.cat(scores), torch.cat(steps)
    distance = torch.cat(distances) if len(distances) == len(scores) else None
    value = torch.cat(values) if len(values) == len(scores) else None
    rows = []
    for start in range(0, int(step.max()) + 1, window):
        mask = (step >= start) & (step < start + window)
        row = {"step": start, "critic_mean": score[mask].mean().item(),
               "critic_std": score[mask].std().item() if mask.sum() > 1 else 0.0, "pairs": int(mask.sum())}
        if distance is not None:
            row["eef_to_cube_m"] = distance[mask].mean().item()
        if value is not None:
            row["q_mean"] = value[mask].mean().item()
        rows.append(row)
    return rows


def profile_checkpoint(path: str | Path, demos: str | Path, window: int = 5, agent_episodes: int = 0) -> dict:
    """:func:`critic_along_episodes` for a checkpoint and a demonstration folder (checked against the run's
    observation keys) -> ``{checkpoint, demos, window, profile, reward_scale}``, with ``agent_profile`` along the
    checkpoint's own first ``agent_episodes`` evaluation episodes (:func:`played_episodes`) where that is > 0."""
    from torchrl_mpail2.agents import MPAIL2Agent
    from torchrl_mpail2.data.demo_files import load_demos

    agent = MPAIL2Agent.from_checkpoint(path)
    keys = list(agent.modules.encoder.in_keys)
    demonstrations = load_demos(demos)
    missing = [k for k in keys if k not in demonstrations.observation_keys]
    if missing:
        raise KeyError(f"{demos}: the demonstrations lack the run's observation key(s) {missing} "
                       f"(they have {demonstrations.observation_keys})")
    extra = ["object"] if "object" in demonstrations.observation_keys and "object" not in keys else []
    episodes = [demonstrations.episode(i).select(*keys, *extra) for i in range(demonstrations.num_episodes)]
    net = agent.modules.reward.module

    def profile(episodes):
        eef_to_cube = None
        if agent.run_config["train"]["env"] in ("robosuite/Lift", "robosuite/Push") and "object" in episodes[0].keys():
            from torchrl_mpail2.envs.robosuite_observations import OBJECT_EEF_TO_CUBE as eef_to_cube
        return critic_along_episodes(agent.modules.encoder, net, episodes, window, eef_to_cube,
                                     agent.modules.value.net, agent.modules.policy.net)

    result = {"checkpoint": str(path), "demos": str(demos), "window": window, "reward_scale": float(net.reward_scale),
              "profile": profile(episodes)}
    if agent_episodes:
        result["agent_episodes"] = agent_episodes
        result["agent_profile"] = profile(played_episodes(agent, agent_episodes))
    return result


def played_episodes(agent, episodes: int) -> list[TensorDict]:
    """The observations ``[T + 1]`` of the agent's first ``episodes`` fixed evaluation episodes (the plan's mean), in
    the run's own evaluation env; robosuite camera runs also get the simulator's ``"object"`` (``SimulatorObject``)."""
    from torchrl_mpail2.trainers.evaluation import evaluate_episodes, evaluation_env, evaluation_seeds, run_eval_seed

    train = agent.run_config["train"]
    env = evaluation_env(train)
    keys = list(agent.modules.encoder.in_keys)
    if train["env"].startswith("robosuite/"):
        from torchrl_mpail2.envs.robosuite_env import with_simulator_object

        env = with_simulator_object(env)
    if "object" in env.observation_spec.keys() and "object" not in keys:
        keys.append("object")
    rollouts: list = []
    evaluate_episodes(env, agent.policy, evaluation_seeds(run_eval_seed(train), episodes), agent.planner,
                      rollouts=rollouts)
    env.close()
    return [torch.cat([rollout[:1].select(*keys), rollout["next"].select(*keys)], 0) for rollout in rollouts]


def plot_profiles(results: list[dict], out: str | Path) -> Path:
    """Two panels against the window's first step: the critic's mean (the demonstrations' end-effector-to-cube
    distance dotted on a second axis where it was measured) and Q of the policy's action; one colour per checkpoint,
    its own episodes dashed where they were played."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, ax_q) = plt.subplots(2, 1, figsize=(7, 6), sharex=True)
    for i, result in enumerate(results):
        name = Path(result["checkpoint"]).parent.parent.name + "/" + Path(result["checkpoint"]).name
        for key, style, label in (("profile", dict(marker="o"), name),
                                  ("agent_profile", dict(marker="x", ls="--"), f"{name}: its own episodes")):
            rows = result.get(key)
            if not rows:
                continue
            steps = [r["step"] for r in rows]
            ax.plot(steps, [r["critic_mean"] for r in rows], color=f"C{i}", label=label, **style)
            if "q_mean" in rows[0]:
                ax_q.plot(steps, [r["q_mean"] for r in rows], color=f"C{i}", **style)
    ax_q.set_xlabel(f"episode step (windows of {results[0]['window']}); dashed: the agent's own episodes")
    ax.set_ylabel("raw critic r(z, z')")
    ax_q.set_ylabel("Q(z, policy action)")
    for a in (ax, ax_q):
        a.grid(alpha=0.3)
    ax.legend(fontsize=7, loc="upper left")
    rows = results[0]["profile"]
    if "eef_to_cube_m" in rows[0]:
        twin = ax.twinx()
        twin.plot([r["step"] for r in rows], [100 * r["eef_to_cube_m"] for r in rows], ls=":", color="gray")
        twin.set_ylabel("end-effector to cube (cm, dotted)", color="gray")
    ax.set_title(f"critic and value along {Path(results[0]['demos']).name} (means over episodes)", fontsize=8)
    return save_figure(fig, out, dpi=120)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m torchrl_mpail2.diagnostics critic_profile",
                                     description=__doc__.splitlines()[0])
    parser.add_argument("checkpoints", nargs="+", help="checkpoint folders")
    parser.add_argument("--demos", required=True, help="a demonstration folder (e.g. another seed's scripted demos)")
    parser.add_argument("--window", type=int, default=5, help="steps per row")
    parser.add_argument("--out", help="write the results to this JSON file")
    parser.add_argument("--plot", help="draw the profiles to this PNG file")
    parser.add_argument("--agent-episodes", type=int, default=0, metavar="N",
                        help="also profile the checkpoint's own agent on its first N fixed evaluation episodes")
    parser.add_argument("--threads", type=int, default=1)
    args = parser.parse_args(argv)
    if args.agent_episodes < 0:
        parser.error(f"--agent-episodes must be >= 0, got {args.agent_episodes}")
    torch.set_num_threads(args.threads)
    results = []
    for path in args.checkpoints:
        result = profile_checkpoint(path, args.demos, args.window, args.agent_episodes)
        results.append(result)
        for name in ("profile", "agent_profile"):
            if name not in result:
                continue
            print(f"{path}: {'demonstrations' if name == 'profile' else 'its own evaluation episodes'}")
            for row in result[name]:
                extra = f"  eef-cube {100 * row['eef_to_cube_m']:5.1f} cm" if "eef_to_cube_m" in row else ""
                print(f"  steps {row['step']:3d}+  critic {row['critic_mean']:9.1f} ± {row['critic_std']:7.1f}  "
                      f"Q {row['q_mean']:8.2f}{extra}")
    if args.out:
        Path(args.out).write_text(json.dumps(results, indent=1) + "\n")
        print(f"wrote {args.out}")
    if args.plot:
        print(f"wrote {plot_profiles(results, args.plot)}")
