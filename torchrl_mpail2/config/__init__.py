"""The configuration, in one place: the networks, losses and planner (:mod:`.sections`, defaults from Table 4), the
training loop (:mod:`.train`), the paper's ablations (:mod:`.ablations`), the whole run with its overrides
(:mod:`.experiment`) and the named presets (:mod:`.presets`). Every bad field or value raises :class:`ConfigError`
naming it."""
from torchrl_mpail2.config.fields import (AT_LEAST_ONE, FINITE, NON_NEGATIVE, OPEN_UNIT_INTERVAL, POSITIVE,
                                          UNIT_INTERVAL, ConfigError, FieldKind, Range, build_section, check_fields,
                                          field_docs, field_kind)
from torchrl_mpail2.config.sections import (COMPILE_MODES, REMOVED_FIELDS, TERMINAL_VALUES, LossConfig, ModelConfig,
                                            PlannerConfig, migrate_config_data)
from torchrl_mpail2.config.ablations import (ABLATIONS, UPDATE_PRECISIONS, AgentSwitches, resolve_update_precision,
                                             runs_bf16_natively, switches_for, warn_if_bf16_emulated)
from torchrl_mpail2.config.train import (COLLECTORS, DEFAULT_EVAL_SEED, EVAL_ACTINGS, RESUME_FIELDS, TrainConfig)
from torchrl_mpail2.config.experiment import (ExperimentConfig, apply_overrides, apply_resume_overrides,
                                              read_run_config, resolve_for_run)
from torchrl_mpail2.config.presets import PRESETS, Preset, preset

__all__ = [
    "ABLATIONS", "AT_LEAST_ONE", "COLLECTORS", "COMPILE_MODES", "DEFAULT_EVAL_SEED", "EVAL_ACTINGS", "FINITE",
    "NON_NEGATIVE", "OPEN_UNIT_INTERVAL", "POSITIVE", "PRESETS", "REMOVED_FIELDS", "RESUME_FIELDS", "TERMINAL_VALUES",
    "UNIT_INTERVAL", "UPDATE_PRECISIONS", "AgentSwitches", "ConfigError", "ExperimentConfig", "FieldKind",
    "LossConfig", "ModelConfig", "PlannerConfig", "Preset", "Range", "TrainConfig", "apply_overrides",
    "apply_resume_overrides", "build_section", "check_fields", "field_docs", "field_kind", "migrate_config_data",
    "preset", "read_run_config", "resolve_for_run", "resolve_update_precision", "runs_bf16_natively", "switches_for",
    "warn_if_bf16_emulated",
]
