"""Settings of the training loop (Algorithm 1): the env, the demonstrations, the budget, the schedule of
evaluations and checkpoints, collection and logging."""
from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import torch

from torchrl_mpail2.config.ablations import ABLATIONS, UPDATE_PRECISIONS
from torchrl_mpail2.config.fields import AT_LEAST_ONE, NON_NEGATIVE, POSITIVE, ConfigError, Range, check_fields
from torchrl_mpail2.envs.names import OBS_MODES, obs_modes_of

#: How an evaluation may act (``TrainConfig.eval_acting``; :data:`torchrl_mpail2.trainers.evaluation.ACTING` maps
#: each to TorchRL's exploration type).
EVAL_ACTINGS = ("deterministic", "random")
#: ``train.eval_seed`` unless set: clear of the training (``seed + episode``) and demo (``seed + 1e6 + i``) seeds.
DEFAULT_EVAL_SEED = 2_000_000

#: Fields that an override may change when a run is resumed (the rest is what the run was started with).
RESUME_FIELDS = ("train.total_episodes", "train.total_env_steps", "train.max_wall_s", "train.progress", "train.threads",
                 "train.checkpoint_every", "train.ray_address")
#: Who collects the training episodes (``TrainConfig.collector``): this process, or Ray workers.
COLLECTORS = ("local", "ray")


@dataclass
class TrainConfig:
    """Settings of the training loop (Algorithm 1)."""

    env: str = "robosuite/Lift"
    """Environment name understood by ``torchrl_mpail2.envs.make_env``."""
    obs: str = "state"
    """Observation mode, one of the env family's in ``envs.names.FAMILY_OBS_MODES`` (state, pixels, ...)."""
    env_kwargs: dict | None = None
    """Extra keyword arguments of ``make_env`` (JSON on the command line), e.g. robosuite's
    ``{"observe_gripper_command": true}`` or ``{"gripper": "binary"}``; demos are recorded with the same."""
    seed: int = 0
    """Seed of torch, the environments and the demonstrations."""
    demos: str | None = None
    """A demonstration directory, or ``<format>:<path>`` for an importer (``data.DEMO_SOURCES``, e.g.
    ``robosuite_hdf5:demo.hdf5``); None records scripted-expert demos into demos/ on first use."""
    num_demos: int = 10
    """Number of expert episodes recorded when ``demos`` is None."""
    expert_kwargs: dict | None = None
    """Options of the scripted expert that records the demos (JSON on the command line), e.g.
    ``{"human_like": true}`` (per-episode speed, approach path, drift and pauses) or ``{"max_lift_speed": 0.005}``."""
    demo_steps_after_success: int | None = None
    """End each recorded demonstration this many steps after its first success (None: whole episodes)."""
    demo_keys: tuple[str, ...] | None = None
    """Observation keys the demonstrations keep, the others dropped after loading or recording (None: all). The
    paper's video-only demonstrations keep the table camera's frames alone (``["external_image"]``): the learner
    still observes every key, and the reward must read only kept keys' latent blocks (``model.fuse_latent=false``,
    ``model.reward_latent_keys``)."""
    total_episodes: int = 200
    """Training episodes (warm-up included)."""
    total_env_steps: int | None = None
    """A budget in environment steps as well (the Gymnasium tasks': the paper runs 200 iterations of 1000 steps):
    the run ends after the episode that reaches it, or at ``total_episodes``, whichever comes first. None: episodes
    alone."""
    warmup_episodes: int = 2
    """Episodes of uniformly random actions before learning starts."""
    num_envs: int = 1
    """Environments collected from at once (the planner acts on all in one batched call); each batch of ``num_envs``
    episodes is followed by ``utd`` updates per collected step, so the updates per frame stay as configured.
    Evaluations and checkpoints fall due when a batch steps over their multiple; a run may end up to
    ``num_envs - 1`` episodes past ``total_episodes``."""
    parallel_envs: bool = False
    """With ``num_envs > 1``: one worker process per environment (TorchRL ``ParallelEnv``) instead of all in the
    training process (``SerialEnv``)."""
    collector: str = "local"
    """Who collects the training episodes: ``local`` (this process, ``num_envs`` environments at a time) or ``ray``
    (``ray_workers`` Ray workers, each with ``num_envs`` environments and a copy of the actor that receives the
    learner's weights after each update; ``pip install 'torchrl-mpail2[ray]'``, cluster recipe in docs/ray.md).
    Evaluation and checkpoints stay in the training process."""
    ray_workers: int = 2
    """With ``collector=ray``: Ray workers, one CPU each. A batch holds ``ray_workers * num_envs`` episodes, one set
    from every worker, followed by ``utd`` updates per collected step (as ``num_envs`` environments in one process)."""
    ray_address: str | None = None
    """With ``collector=ray``: the Ray cluster to join, ``auto`` (the one ``ray start`` runs on this machine) or
    ``HOST:6379``; None starts a local Ray of ``ray_workers`` CPUs for the run."""
    max_wall_s: float | None = None
    """Stop after this many seconds of training (checked after each episode); None: no time limit."""
    utd: float = 1.0
    """Updates per collected environment step (Table 4: 1)."""
    batch_size: int = 256
    """Sub-trajectories per update (each H steps long)."""
    eval_every: int = 10
    """Evaluate every this many episodes, and where the run ends (0: never). A run shorter than this (a smoke run of a
    few episodes) reaches no evaluation and ends without one."""
    eval_at_start: bool = False
    """Also evaluate before the first episode (logged at episode 0): the starting weights, e.g. a transferred
    checkpoint's (``--init-from``), as the paper's transfer curves start."""
    eval_until: int | None = None
    """The periodic evaluations (every ``eval_every``) stop after this episode; the run still evaluates where it ends.
    None: every ``eval_every`` to the end (the paper's transfer runs: every 10 up to 60)."""
    eval_episodes: int = 20
    """Episodes per evaluation (50 for final numbers, as in the paper's real-world tables)."""
    eval_envs: int = 1
    """Evaluation episodes played at once, in lockstep, the planner acting on all of them in one batched call
    (``trainers.evaluation.evaluate_episodes_lockstep``): with 8, an evaluation took 2.7 times less time on one H200
    at the paper configuration and 1.4 times less on 2 CPU cores with ``lift_state`` (``benchmarks/speed/eval_speed.py``).
    The initial states are the same; the planner's noise is drawn per batch, so scores compare between runs with
    the same ``eval_envs`` (1, the default, is the sequential evaluation every recorded result used)."""
    eval_acting: str = "deterministic"
    """How the evaluation acts (:data:`EVAL_ACTINGS`): ``deterministic`` (the plan's mean; every recorded
    result) or ``random`` (the action sampled around it as in training, the noise drawn from the evaluation's
    per-episode seeded generator, so the episodes stay fixed)."""
    video: bool = False
    """Record the first ``video_episodes`` episodes of each evaluation to ``videos/*.mp4`` in the run folder, and send
    them to the logger under ``eval/video`` (``trainers.logs.RunLogger.log_videos``: tensorboard needs moviepy 1);
    needs the ``video`` extra (imageio-ffmpeg) and an env with ``render()``."""
    video_episodes: int = 1
    """Evaluation episodes recorded per evaluation when ``video`` is on."""
    eval_seed: int = DEFAULT_EVAL_SEED
    """Seed of the first evaluation episode: episode ``i`` starts from env seed ``eval_seed + i`` and draws its
    planner noise from a generator seeded the same way, so every evaluation of every run (any training seed)
    plays the same initial states. Kept clear of the training (``seed + episode``) and demo (``seed + 1e6 + i``) seeds.
    The evaluation env is also built with this seed (Lift's cube size is drawn then); tools that re-evaluate a
    checkpoint rebuild it alike (``trainers.evaluation.evaluation_env``)."""
    checkpoint_every: int = 10
    """Write a numbered checkpoint every this many episodes (``last`` is written at every evaluation too).
    The checkpoint kept as ``best`` is the evaluation with the highest any-step success (ties: last-step success)."""
    last_every: int = 5
    """Write ``checkpoints/last`` (with the replay buffer) every this many episodes, evaluations aside, so that a
    crash loses at most this many episodes (0: only at evaluations)."""
    success_window: int = 25
    """Moving window (episodes) of the logged training success rate."""
    run_dir: str | None = None
    """Run folder; None makes runs/<env>-<seed>-<time>."""
    replay_size: int | None = None
    """Replay capacity in steps (memory-mapped in the run folder); None holds the whole run, like the paper's unbounded
    buffer (sized from the episode budget when the run is built, so a resumed run with a larger budget gets more).
    The memory-mapped files are sparse: disk use follows the steps stored, not the capacity, and checkpoints hold
    the stored steps alone (``data.checkpoint.dump_replay``)."""
    logger: str = "csv"
    """csv | wandb | tensorboard | none. wandb goes online where it is logged in (``wandb login``) and reads its own
    environment variables: ``WANDB_MODE=offline`` (or ``disabled``), ``WANDB_PROJECT`` (default:
    ``trainers.logs.WANDB_PROJECT``), ``WANDB_ENTITY``, ``WANDB_RUN_GROUP``, ``WANDB_NAME`` (default: the run folder's
    name) and ``WANDB_DIR`` (default: the run folder); see ``trainers.logs.make_torchrl_logger``."""
    ablation: str = "none"
    """A Table 2 name (``agents.switches.ABLATIONS``): none | P | O | PM | PMO."""
    threads: int | None = None
    """torch intra-op threads (None: torch's default)."""
    device: str = "cpu"
    """Where the agent lives and learns (``cpu``, ``cuda``, ``cuda:1``): networks, planning and updates; the
    environments write their tensors there too. Replay and demonstrations stay in host memory."""
    progress: bool = True
    """Show a tqdm progress bar."""
    figures: bool = True
    """Redraw ``curves.png`` and ``learner.png`` in the run folder at each evaluation and at the end (about a second
    of one CPU core each time); false leaves them out (``python -m torchrl_mpail2.trainers.plots RUN_DIR`` draws
    them from the logs at any time)."""
    update_precision: str = "float32"
    """Precision of the learner's update (``MPAIL2Updater``): float32 | bf16 (mixed precision: every stage's forward
    in bf16, float32 weights and optimiser) | auto (bf16 where the device runs bfloat16 natively, float32 elsewhere;
    the saved config records the choice). See docs/results/speed/speed_notes.md for speed and closeness."""

    RANGES: ClassVar[dict[str, Range]] = {
        "seed": NON_NEGATIVE, "num_demos": AT_LEAST_ONE, "num_envs": AT_LEAST_ONE, "total_episodes": AT_LEAST_ONE, "warmup_episodes": NON_NEGATIVE,
        "total_env_steps": AT_LEAST_ONE, "ray_workers": AT_LEAST_ONE,
        "max_wall_s": POSITIVE, "utd": POSITIVE, "batch_size": AT_LEAST_ONE, "eval_every": NON_NEGATIVE,
        "eval_until": AT_LEAST_ONE,
        "eval_episodes": AT_LEAST_ONE, "eval_envs": AT_LEAST_ONE, "checkpoint_every": NON_NEGATIVE, "last_every": NON_NEGATIVE,
        "success_window": AT_LEAST_ONE, "replay_size": AT_LEAST_ONE, "threads": AT_LEAST_ONE,
        "eval_seed": NON_NEGATIVE, "video_episodes": AT_LEAST_ONE, "demo_steps_after_success": NON_NEGATIVE,
    }

    def __post_init__(self) -> None:
        check_fields(self)
        if self.demo_keys is not None:
            if isinstance(self.demo_keys, str) or not self.demo_keys or not all(isinstance(k, str) for k in self.demo_keys):
                raise ConfigError(f"TrainConfig.demo_keys must be a non-empty list of observation keys or None, "
                                  f"got {self.demo_keys!r}")
            self.demo_keys = tuple(self.demo_keys)
        if self.obs not in OBS_MODES:
            raise ConfigError(f"unknown TrainConfig.obs {self.obs!r}; choose from {OBS_MODES}")
        if obs_modes_of(self.env) and self.obs not in obs_modes_of(self.env):  # () for an env of a custom env_fn
            raise ConfigError(f"TrainConfig.obs={self.obs!r} is not a mode of {self.env!r}; "
                              f"choose from {obs_modes_of(self.env)}")
        if self.ablation not in ABLATIONS:
            raise ConfigError(f"unknown ablation {self.ablation!r}; choose from {sorted(ABLATIONS)}")
        if self.warmup_episodes >= self.total_episodes:
            raise ConfigError(f"TrainConfig.warmup_episodes must lie in [0, total_episodes), got {self.warmup_episodes}")
        if self.collector not in COLLECTORS:
            raise ConfigError(f"unknown TrainConfig.collector {self.collector!r}; choose from {COLLECTORS}")
        if self.collector == "ray" and self.parallel_envs:
            raise ConfigError("TrainConfig.parallel_envs applies to collector='local': with collector='ray' each Ray "
                              "worker is a process of its own (more of them: ray_workers)")
        if self.ray_address is not None and self.collector != "ray":
            raise ConfigError(f"TrainConfig.ray_address={self.ray_address!r} applies to collector='ray' only "
                              f"(collector is {self.collector!r})")
        if self.episodes_per_batch > self.total_episodes:
            which = (f"num_envs={self.num_envs}" if self.collector == "local"
                     else f"ray_workers * num_envs={self.ray_workers} * {self.num_envs}")
            raise ConfigError(f"TrainConfig.{which} is more than total_episodes={self.total_episodes}: "
                              "the run could not use the extra environments (each collects whole episodes)")
        if self.eval_acting not in EVAL_ACTINGS:
            raise ConfigError(f"unknown TrainConfig.eval_acting {self.eval_acting!r}; choose from {EVAL_ACTINGS}")
        if self.update_precision == "bf16_stop_gradient":
            raise ConfigError("update_precision='bf16_stop_gradient' was removed after commit 7137cb5 (an option not "
                              "adopted; 'bf16' runs the whole update in mixed precision); run this config from that "
                              f"commit, or choose from {UPDATE_PRECISIONS}")
        if self.update_precision not in UPDATE_PRECISIONS:
            raise ConfigError(f"unknown update_precision {self.update_precision!r}; choose from {UPDATE_PRECISIONS}")
        if self.update_precision not in ("float32", "auto") and not ABLATIONS[self.ablation].world_model:
            raise ConfigError(f"update_precision={self.update_precision!r} applies to the model-based updater only, "
                              f"not to the model-free ablation {self.ablation!r}")
        for name in ("env_kwargs", "expert_kwargs"):
            value = getattr(self, name)
            if value is not None and not isinstance(value, dict):
                raise ConfigError(f"TrainConfig.{name} must be a JSON object (keyword -> value), got {value!r}")
        try:
            device = torch.device(self.device)
        except (RuntimeError, TypeError) as error:
            raise ConfigError(f"TrainConfig.device: {self.device!r} is not a torch device ({error})") from error
        # whether the device exists here is checked where the agent is placed (MPAIL2Trainer): a GPU run's saved
        # config stays readable on a CPU machine (diagnostics, benchmarks, from_checkpoint onto the CPU)
        if self.collector == "ray" and device.type != "cpu":
            raise ConfigError(f"TrainConfig.device={self.device!r} with collector='ray': Ray collection runs on the "
                              "CPU for now (the workers would receive the learner's device tensors and build their "
                              "envs on that device)")
        if self.logger not in ("csv", "wandb", "tensorboard", "none"):
            raise ConfigError(f"unknown logger {self.logger!r}; choose csv, wandb, tensorboard or none")

    @property
    def episodes_per_batch(self) -> int:
        """Episodes of one collected batch: ``num_envs``, from each of the ``ray_workers`` with ``collector=ray``."""
        return self.num_envs * (self.ray_workers if self.collector == "ray" else 1)
