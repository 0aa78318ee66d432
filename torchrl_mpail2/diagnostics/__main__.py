"""``python -m torchrl_mpail2.diagnostics COMMAND ...``: the diagnostics' command line (``COMMAND --help`` for each).

Of a checkpoint: ``arena_map``, ``cube_map``, ``critic_profile``, ``latent_content``, ``plan_pictures``,
``held_plans``, ``held_value_probe``, ``actor_vs_planner``, ``value_inputs``, ``keypoint_map``; of a run's
checkpoints: ``lift_phases``, ``grasp_preference``; of a run's replay: ``replay_frames``; of the reward network
alone: ``critic_generalisation``."""
import sys

from torchrl_mpail2.diagnostics import (actor_vs_planner, arena_map, critic_generalisation, critic_profile, cube_map,
                                        grasp_preference, held_plans, held_value_probe, keypoint_map, latent_content,
                                        lift_phases, plan_pictures, replay_frames, value_inputs)

COMMANDS = {module.__name__.rsplit(".", 1)[-1]: module.main
            for module in (actor_vs_planner, arena_map, critic_generalisation, critic_profile, cube_map,
                           grasp_preference, held_plans, held_value_probe, keypoint_map, latent_content, lift_phases,
                           plan_pictures, replay_frames, value_inputs)}

if __name__ == "__main__":
    if len(sys.argv) < 2 or sys.argv[1] not in COMMANDS:
        sys.exit(f"usage: python -m torchrl_mpail2.diagnostics {{{','.join(sorted(COMMANDS))}}} ...")
    COMMANDS[sys.argv[1]](sys.argv[2:])
