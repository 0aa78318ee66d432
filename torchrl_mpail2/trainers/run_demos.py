"""The demonstrations of a run: the configured source, else scripted-expert demos cached under ``demos/``."""
from __future__ import annotations

import logging
from collections.abc import Callable
from pathlib import Path

from torchrl.envs import EnvBase

from torchrl_mpail2.data import Demonstrations, load_demo_source, load_demos, record_demos, save_demos
from torchrl_mpail2.experts import get_expert
from torchrl_mpail2.experts.gym import expert_fingerprint
from torchrl_mpail2.config import ExperimentConfig

log = logging.getLogger(__name__)
#: Offset of the demo episodes' seeds from the run's seed (demo, training and evaluation episodes never share one).
DEMO_SEED_OFFSET = 1_000_000


def default_demo_dir(cfg: ExperimentConfig) -> Path:
    """Where scripted demos of ``cfg`` are cached: one folder per env, options, count and seed (and, for the
    gymnasium tasks, expert file: see :func:`~torchrl_mpail2.experts.gym.expert_fingerprint`)."""
    t = cfg.train
    options = "".join(f"-{k}={v}" for k, v in sorted({**(t.env_kwargs or {}), **(t.expert_kwargs or {})}.items()))
    if t.demo_steps_after_success is not None:
        options += f"-stop{t.demo_steps_after_success}"
    if t.env.startswith("gym/"):
        options += f"-expert{expert_fingerprint(t.env.removeprefix('gym/'))}"
    return Path("demos") / f"{t.env.replace('/', '_')}-{t.obs}{options}-{t.num_demos}ep-seed{t.seed}"


def env_options(cfg: ExperimentConfig) -> dict:
    """The options the run builds its env with (``make_env``'s keyword arguments with ``obs``), as demonstration
    headers record them (``env_kwargs``)."""
    return {"obs": cfg.train.obs, **(cfg.train.env_kwargs or {})}


def load_or_record_demos(cfg: ExperimentConfig, env: EnvBase, env_fn: Callable) -> Demonstrations:
    """``train.demos`` if set (a folder or ``<format>:<path>``), else the cached scripted demos, recorded on first
    use with ``env_fn(seed=...)`` and the env's scripted expert. Two runs that record the same cache at once (the
    same env, options, count and seed, so the same episodes) both go on: the later one loads the earlier one's.
    With ``train.demo_keys`` the demonstrations keep only those observation keys (the cache keeps every key)."""
    t = cfg.train
    # with the default env_fn (make_env), so that demos refused for their shapes name the env options that differ
    options = env_options(cfg)
    if t.demos is not None:
        return load_demo_source(t.demos, env, progress=t.progress, keys=t.demo_keys, env_kwargs=options)
    path = default_demo_dir(cfg)
    if path.exists():
        return load_demos(path, env, keys=t.demo_keys, env_kwargs=options)
    seed = t.seed + DEMO_SEED_OFFSET
    demo_env = env_fn(seed=seed)
    # a scripted expert's own randomness (human-like styles, noise) is seeded like the demo episodes
    expert_options = {"seed": seed, **t.expert_kwargs} if t.expert_kwargs else {}
    expert = get_expert(t.env, demo_env, **expert_options)
    log.info("recording %d scripted demonstrations into %s", t.num_demos, path)
    try:
        demos = record_demos(demo_env, expert, t.num_demos, seed=seed, progress=t.progress,
                             steps_after_success=t.demo_steps_after_success,
                             env_id=t.env, env_kwargs=options)
    finally:
        # free the recorder's simulator and GL context now rather than at some later garbage collection; an env_fn
        # that hands back the training env itself keeps it open
        if demo_env is not env:
            demo_env.close()
    try:
        save_demos(demos, path)
    except FileExistsError:
        log.info("%s was written by another run meanwhile; using it", path)
        return load_demos(path, env, keys=t.demo_keys, env_kwargs=options)
    return demos if t.demo_keys is None else demos.with_keys(t.demo_keys)
