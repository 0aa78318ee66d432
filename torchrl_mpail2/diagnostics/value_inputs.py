r"""Which observation keys do the value :math:`Q_\zeta(z, \pi_\phi(z))` and the reward :math:`r_\theta(z, z')` read?
Permutation importance over states.

    python -m torchrl_mpail2.diagnostics value_inputs CKPT [--resets 100] [--episodes 2] [--permutations 5] [--out FILE]

For a set of states, each observation key in turn is shuffled across the states (the others kept), the observations
are encoded again and Q of the policy's mean first action is recomputed: ``importance[key]`` is the mean absolute
change of Q over states and shuffles, beside ``q_spread``, the standard deviation of Q over the unshuffled states.
At a robosuite task's initial states (``--resets``, held-out evaluation seeds) the arm starts at nearly the same pose
and the cube is placed anew: a value that sees the cube changes when the cameras are shuffled, one that reads the arm
alone changes with the proprioception only. ``--episodes`` adds the states of episodes the checkpoint's agent plays
(the plan's mean), and over their transitions the same for the reward (``reward_importance``: a key shuffled across
the transitions, the same shuffle for both ends of each, beside ``reward_spread``). The planner ranks plans by their
rewards and terminal Q, so a value or a reward blind to the cube ranks plans by the arm's pose alone.
"""
from __future__ import annotations

import argparse

import torch
from tensordict import TensorDictBase

#: Shuffles per key: enough for a stable mean over 100 states.
PERMUTATIONS = 5


def q_of_policy_action(agent, observations: TensorDictBase) -> torch.Tensor:
    """``Q(z, a_0)`` (mean over heads) of the policy's mean first action ``a_0`` at each state ``[N]``."""
    m = agent.modules
    with torch.no_grad():
        z = m.encoder.encode(observations)
        plan, _ = m.policy.net(z, deterministic=True)
        return m.value.net(z, plan[:, 0]).float().mean(0).squeeze(-1)


def reward_of_transitions(agent, observations: TensorDictBase, next_observations: TensorDictBase) -> torch.Tensor:
    """``r(z, z')`` of each transition ``[N]``."""
    m = agent.modules
    with torch.no_grad():
        return m.reward.module(m.encoder.encode(observations), m.encoder.encode(next_observations)).float().squeeze(-1)


def reward_input_importance(agent, observations: TensorDictBase, next_observations: TensorDictBase,
                            permutations: int = PERMUTATIONS, seed: int = 0) -> dict:
    """Permutation importance of each observation key for the reward over the transitions
    ``(observations[i], next_observations[i])``: a key shuffled across transitions, both ends alike."""
    if observations.batch_size[0] < 2:
        raise ValueError("value_inputs needs at least 2 transitions to shuffle a key across")
    generator = torch.Generator().manual_seed(seed)
    r = reward_of_transitions(agent, observations, next_observations)
    importance = {}
    for key in agent.modules.encoder.in_keys:
        changes = []
        for _ in range(permutations):
            order = torch.randperm(len(r), generator=generator)
            now, then = observations.clone(), next_observations.clone()
            now.set(key, observations[key][order])
            then.set(key, next_observations[key][order])
            changes.append((reward_of_transitions(agent, now, then) - r).abs().mean())
        importance[key] = float(torch.stack(changes).mean())
    return {"transitions": int(len(r)), "reward_mean": float(r.mean()), "reward_spread": float(r.std()),
            "reward_importance": importance}


def value_input_importance(agent, observations: TensorDictBase, permutations: int = PERMUTATIONS,
                           seed: int = 0) -> dict:
    """Permutation importance of each of the encoder's observation keys for Q over ``observations [N]`` (see the
    module docstring)."""
    keys = list(agent.modules.encoder.in_keys)
    if observations.batch_size[0] < 2:
        raise ValueError("value_inputs needs at least 2 states to shuffle a key across")
    generator = torch.Generator().manual_seed(seed)
    q = q_of_policy_action(agent, observations)
    importance = {}
    for key in keys:
        changes = []
        for _ in range(permutations):
            shuffled = observations.clone()
            shuffled.set(key, observations[key][torch.randperm(len(q), generator=generator)])
            changes.append((q_of_policy_action(agent, shuffled) - q).abs().mean())
        importance[key] = float(torch.stack(changes).mean())
    return {"states": int(len(q)), "q_mean": float(q.mean()), "q_spread": float(q.std()),
            "q_range": [float(q.min()), float(q.max())], "importance": importance}


def main(argv: list[str] | None = None) -> dict:
    from torchrl_mpail2.agents import MPAIL2Agent
    from torchrl_mpail2.diagnostics.latent_content import add_state_set_arguments, state_sets, write_result

    p = argparse.ArgumentParser(prog="python -m torchrl_mpail2.diagnostics value_inputs", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    add_state_set_arguments(p, resets=100, episodes=2)
    p.add_argument("--permutations", type=int, default=PERMUTATIONS, help="shuffles per key")
    p.add_argument("--threads", type=int, default=None)
    args = p.parse_args(argv)
    if args.permutations < 1:
        raise SystemExit("--permutations must be >= 1")
    if args.threads:
        torch.set_num_threads(args.threads)
    agent = MPAIL2Agent.from_checkpoint(args.checkpoint)
    at_reset, played = state_sets(agent, args.resets, args.episodes)
    result = {"checkpoint": str(args.checkpoint), "resets": args.resets, "episodes": args.episodes,
              "permutations": args.permutations}
    if at_reset is not None:
        result["at_reset"] = value_input_importance(agent, at_reset[0], args.permutations)
    if played:
        episodes = [observations for observations, _ in played]
        result["played"] = value_input_importance(agent, torch.cat(episodes), args.permutations)
        result["played"].update(reward_input_importance(agent, torch.cat([e[:-1] for e in episodes]),
                                                        torch.cat([e[1:] for e in episodes]), args.permutations))
    return write_result(result, args.out)
