"""A run's whole configuration (loop, networks, losses, planner) as one object: built from JSON, changed by
command-line overrides checked field by field, resolved into what a run saves, and read back from a run folder."""
from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any

from torchrl_mpail2.config.ablations import ABLATIONS, resolve_update_precision
from torchrl_mpail2.config.fields import ConfigError, build_section, field_kind
from torchrl_mpail2.config.sections import LossConfig, ModelConfig, PlannerConfig, migrate_config_data
from torchrl_mpail2.config.train import RESUME_FIELDS, TrainConfig
from torchrl_mpail2.data.sources import resolve_demo_source


@dataclass
class ExperimentConfig:
    """Everything a run needs: loop, networks, losses, planner."""

    train: TrainConfig = field(default_factory=TrainConfig)
    model: ModelConfig = field(default_factory=ModelConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    planner: PlannerConfig = field(default_factory=PlannerConfig)

    def to_dict(self) -> dict:
        return asdict(self)

    def to_json(self) -> str:
        return json.dumps(self.to_dict(), indent=2)

    @classmethod
    def from_dict(cls, data: dict) -> "ExperimentConfig":
        unknown = sorted(set(data) - {f.name for f in fields(cls)})
        if unknown:
            raise ConfigError(f"unknown config section(s) {unknown}; sections: train, model, loss, planner")
        data = migrate_config_data(data)
        parts = {}
        for f in fields(cls):
            section_cls = type(getattr(cls(), f.name))
            parts[f.name] = build_section(section_cls, data.get(f.name, {}))
        return cls(**parts)



def _parse_scalar(text: str, base: type | None):
    """``text`` as ``base`` (bool, int, float, str; JSON or the text itself when untyped); ValueError if it is not one."""
    if base is bool:
        if text.lower() in ("1", "true", "yes"):
            return True
        if text.lower() in ("0", "false", "no"):
            return False
        raise ValueError(text)
    if base in (int, float):
        return base(text)
    if base is str:
        return text
    try:
        return json.loads(text) if text[:1] in "0123456789-[{" else text
    except json.JSONDecodeError:
        return text


def _parse_value(text: str, section_cls: type, section: str, name: str):
    """``text`` of an override of ``section.name`` as the field's annotated type (errors name field, value and type)."""
    kind = field_kind(section_cls, name)
    if kind.optional and text.lower() in ("null", "none"):
        return None
    items = [t.strip() for t in text.split(",") if t.strip()] if kind.is_tuple else [text]
    if kind.is_tuple and text.strip().startswith("["):  # a JSON list, as the dict fields take JSON
        try:
            items = [str(item) for item in json.loads(text)]
        except json.JSONDecodeError:
            raise ConfigError(f"{section}.{name}={text!r}: expected {kind.describe()} (comma-separated or a JSON "
                              "list)") from None
    parsed = []
    for item in items:
        try:
            parsed.append(_parse_scalar(item, kind.base))
        except ValueError:
            which = f" (item {item!r})" if kind.is_tuple else ""
            raise ConfigError(f"{section}.{name}={text!r}{which}: expected {kind.describe()}") from None
    return tuple(parsed) if kind.is_tuple else parsed[0]


def apply_overrides(cfg: ExperimentConfig, overrides: list[str] | Mapping[str, Any]) -> ExperimentConfig:
    """Returns a new config with overrides applied: command-line strings ``section.field=value`` (or
    ``--section.field value``), or, from Python, a mapping ``{"section.field": value}`` of typed values (checked
    like the rest: an unknown field or an impossible value names the field).

    Examples:
        >>> cfg = apply_overrides(ExperimentConfig(), ["planner.num_candidates=256", "--model.hidden_dims", "64,64"])
        >>> cfg.planner.num_candidates, cfg.model.hidden_dims
        (256, (64, 64))
        >>> apply_overrides(cfg, {"train.max_wall_s": 90.0, "model.hidden_dims": (32,)}).model.hidden_dims
        (32,)
    """
    data = cfg.to_dict()
    typed = isinstance(overrides, Mapping)
    pairs = list(overrides.items()) if typed else _pairs(overrides)
    for path, value in pairs:
        section, _, name = _field_path(path).partition(".")
        if section not in data:
            raise ConfigError(f"unknown config section {section!r} in override {path!r}; sections: {sorted(data)}")
        if name not in data[section]:
            raise ConfigError(f"unknown field {section}.{name}; known: {sorted(data[section])}")
        data[section][name] = value if typed else _parse_value(value, type(getattr(cfg, section)), section, name)
    return ExperimentConfig.from_dict(data)


def _pairs(overrides: list[str]) -> list[tuple[str, str]]:
    """``section.field=value`` and ``--section.field value`` items as ``(path, text)``."""
    pairs, i = [], 0
    while i < len(overrides):
        item = overrides[i].removeprefix("--")
        if "=" in item:
            pairs.append(tuple(item.split("=", 1)))
            i += 1
        elif i + 1 < len(overrides):
            pairs.append((item, overrides[i + 1]))
            i += 2
        else:
            raise ConfigError(f"override {overrides[i]!r} has no value")
    return pairs


def _field_path(path: str) -> str:
    section, _, name = path.partition(".")
    if not name:  # bare names go to the train section
        section, name = "train", section
    return f"{section.replace('-', '_')}.{name.replace('-', '_')}"


def apply_resume_overrides(cfg: ExperimentConfig, overrides: list[str] | Mapping[str, Any]) -> ExperimentConfig:
    """:func:`apply_overrides` for a resumed run: only the fields of :data:`RESUME_FIELDS` may change (strings or,
    from Python, a mapping of typed values, as there).

    Examples:
        >>> apply_resume_overrides(ExperimentConfig(), ["train.total_episodes=500"]).train.total_episodes
        500
        >>> apply_resume_overrides(ExperimentConfig(), {"train.max_wall_s": 60.0}).train.max_wall_s
        60.0
    """
    paths = list(overrides) if isinstance(overrides, Mapping) else [path for path, _ in _pairs(overrides)]
    refused = [path for path in paths if _field_path(path) not in RESUME_FIELDS]
    if refused:
        raise ConfigError(f"a resumed run keeps its saved config; {refused} cannot change (resumable: {list(RESUME_FIELDS)})")
    return apply_overrides(cfg, overrides)


def resolve_for_run(cfg: ExperimentConfig, run_dir: str | Path) -> ExperimentConfig:
    """A copy of ``cfg`` as a run saves it: its run folder is ``run_dir``, its paths are absolute (the saved config
    resumes from any working directory), ``update_precision=auto`` is replaced by what it picks on this machine (a
    resumed run keeps that choice) and ``model.policy_horizon`` by the plan length of the policy the agent builds
    (1 for the model-free ablations)."""
    t = cfg.train
    precision = t.update_precision  # a concrete one is checked (and warned about) where the agent is built
    if precision == "auto":
        precision = resolve_update_precision(precision, t.device, world_model=ABLATIONS[t.ablation].world_model,
                                             images=t.obs != "state")
    train = dataclasses.replace(t, run_dir=str(Path(run_dir).resolve()), update_precision=precision,
                                demos=None if t.demos is None else resolve_demo_source(t.demos))
    policy_horizon = ABLATIONS[t.ablation].policy_horizon(cfg.model.horizon, cfg.model.policy_horizon)
    model = dataclasses.replace(cfg.model, policy_horizon=policy_horizon)
    return dataclasses.replace(cfg, train=train, model=model)


def read_run_config(run_dir: str | Path) -> ExperimentConfig:
    """The config a run saved (``RUN/config.json``), to resume it.

    Raises:
        FileNotFoundError: ``run_dir`` holds no ``config.json`` (not a run folder).
        ValueError: the file is not valid JSON (the message names it).
    """
    config_file = Path(run_dir) / "config.json"
    if not config_file.is_file():
        raise FileNotFoundError(f"cannot resume {run_dir}: {config_file} is missing (not a run folder?)")
    try:
        data = json.loads(config_file.read_text())
    except json.JSONDecodeError as error:
        raise ValueError(f"cannot resume {run_dir}: {config_file} is not valid JSON ({error})") from error
    return ExperimentConfig.from_dict(data)
