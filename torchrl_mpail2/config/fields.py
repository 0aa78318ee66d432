"""How a config field is described and checked: its docstring, its annotated kind, the interval its value must lie
in, and :class:`ConfigError`, which names the offending field."""
from __future__ import annotations

import ast
import inspect
import math
import textwrap
import typing
from dataclasses import dataclass, fields
from typing import ClassVar


class ConfigError(ValueError):
    """A configuration value is unknown or impossible."""


@dataclass(frozen=True)
class Range:
    """Interval a numeric config field must lie in (every numeric field must also be finite).

    Examples:
        >>> 0.5 in UNIT_INTERVAL, 0 in POSITIVE, str(Range(0.0, 1.0, high_open=True))
        (True, False, '[0, 1)')
    """

    low: float = -math.inf
    high: float = math.inf
    low_open: bool = False
    high_open: bool = False

    def __contains__(self, value: float) -> bool:
        above = value > self.low if self.low_open else value >= self.low
        below = value < self.high if self.high_open else value <= self.high
        return above and below

    def __str__(self) -> str:
        if self.high == math.inf:
            return "any finite number" if self.low == -math.inf else f"{'>' if self.low_open else '>='} {self.low:g}"
        return f"{'(' if self.low_open else '['}{self.low:g}, {self.high:g}{')' if self.high_open else ']'}"

    def requirement(self) -> str:
        """``"be > 0"`` or ``"lie in [0, 1)"``, for error messages."""
        return f"{'be' if self.high == math.inf else 'lie in'} {self}"


FINITE = Range()
POSITIVE = Range(0.0, low_open=True)
NON_NEGATIVE = Range(0.0)
UNIT_INTERVAL = Range(0.0, 1.0)
OPEN_UNIT_INTERVAL = Range(0.0, 1.0, low_open=True, high_open=True)
AT_LEAST_ONE = Range(1.0)


@dataclass(frozen=True)
class FieldKind:
    """What a config field holds, read from its type annotation: a scalar ``base`` type, a tuple of them, or None."""

    base: type | None
    optional: bool = False
    is_tuple: bool = False

    @property
    def numeric(self) -> bool:
        return self.base in (int, float)

    def describe(self) -> str:
        name = {int: "an integer", float: "a number", bool: "a boolean", str: "a string"}.get(self.base, "a value")
        if self.is_tuple:
            name = f"comma-separated values, each {name}"
        return f"{name} or null" if self.optional else name


def field_docs(cls: type) -> dict[str, str]:
    """The one-line-or-more docstrings written under the fields of the config dataclass ``cls`` (the string literal
    that follows each annotated field in its source), by field name; a field without one maps to ``""``."""
    body = ast.parse(textwrap.dedent(inspect.getsource(cls))).body[0].body
    docs = {}
    for node, after in zip(body, [*body[1:], None]):
        if isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name):
            text = after.value.value if (isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant)
                                         and isinstance(after.value.value, str)) else ""
            docs[node.target.id] = inspect.cleandoc(text)
    return {f.name: docs.get(f.name, "") for f in fields(cls)}


def field_kind(cls: type, name: str) -> FieldKind:
    """The :class:`FieldKind` of field ``name`` of the config dataclass ``cls``."""
    hint = typing.get_type_hints(cls)[name]
    args = typing.get_args(hint)
    optional = type(None) in args
    if optional:
        (hint,) = [a for a in args if a is not type(None)] or [None]
        args = typing.get_args(hint)
    if typing.get_origin(hint) is tuple:
        return FieldKind(args[0] if args else None, optional, True)
    return FieldKind(hint if hint in (int, float, bool, str) else None, optional)


def _check_scalar(where: str, value, kind: FieldKind, allowed: Range | None) -> None:
    base = kind.base
    if base is bool or base is str:
        if not isinstance(value, base):
            raise ConfigError(f"{where} must be {kind.describe()}, got {value!r}")
        return
    if not kind.numeric:
        return
    if isinstance(value, bool) or not isinstance(value, (int, float)) or (base is int and not isinstance(value, int)):
        raise ConfigError(f"{where} must be {kind.describe()}, got {value!r}")
    if not math.isfinite(value):
        raise ConfigError(f"{where} must be finite, got {value!r}")
    if allowed is not None and value not in allowed:
        raise ConfigError(f"{where} must {allowed.requirement()}{' (or null)' if kind.optional else ''}, got {value!r}")


def check_fields(config) -> None:
    """Checks every field of a config dataclass against its annotation and its class's ``RANGES``.

    Booleans and strings must have their type; numbers must have their type (an integer field takes no
    float), be finite and lie in the field's :class:`Range`; ``None`` only where the annotation allows it.

    Raises:
        ConfigError: naming the field, the value and what was expected.
    """
    cls = type(config)
    ranges = getattr(cls, "RANGES", {})
    for f in fields(config):
        where, value, kind = f"{cls.__name__}.{f.name}", getattr(config, f.name), field_kind(cls, f.name)
        if value is None:
            if not kind.optional:
                raise ConfigError(f"{where} must be {kind.describe()}, got None")
            continue
        if kind.is_tuple:
            if not isinstance(value, (tuple, list)):
                raise ConfigError(f"{where} must be {kind.describe()}, got {value!r}")
            for item in value:
                _check_scalar(where, item, kind, ranges.get(f.name))
        else:
            _check_scalar(where, value, kind, ranges.get(f.name))


def build_section(section_cls: type, values: dict):
    """``section_cls(**values)`` from JSON data: lists become the tuples the fields declare; an unknown field is
    refused by name."""
    known = {f.name for f in fields(section_cls)}
    unknown = sorted(set(values) - known)
    if unknown:
        raise ConfigError(f"unknown {section_cls.__name__} field(s) {unknown}; known: {sorted(known)}")
    kwargs = {k: tuple(v) if field_kind(section_cls, k).is_tuple and isinstance(v, list) else v for k, v in values.items()}
    return section_cls(**kwargs)
