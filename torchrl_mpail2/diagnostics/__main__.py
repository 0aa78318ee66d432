"""``python -m torchrl_mpail2.diagnostics {arena_map,cube_map,plan_pictures,lift_phases,held_plans,critic_profile,latent_content} CKPT
[...]``: the diagnostics' command line."""
import sys

from torchrl_mpail2.diagnostics import (arena_map, critic_profile, cube_map, held_plans, latent_content, lift_phases,
                                        plan_pictures)

COMMANDS = {"arena_map": arena_map.main, "critic_profile": critic_profile.main, "cube_map": cube_map.main,
            "held_plans": held_plans.main,
            "latent_content": latent_content.main, "lift_phases": lift_phases.main, "plan_pictures": plan_pictures.main}

if __name__ == "__main__":
    if len(sys.argv) < 2 or sys.argv[1] not in COMMANDS:
        sys.exit(f"usage: python -m torchrl_mpail2.diagnostics {{{','.join(COMMANDS)}}} ... (commands: {sorted(COMMANDS)})")
    COMMANDS[sys.argv[1]](sys.argv[2:])
