"""Settings dataclasses of the stages: the constraints of a field, and reading one from a TOML table.

A stage's settings dataclass is the one place that holds its options, their defaults and their
allowed values; the command line and ``project.toml`` (the sections ``aerotri run`` reads) both go
through it. A field declares its constraints with :func:`setting`::

    @dataclasses.dataclass(frozen=True)
    class CornerSettings:
        min_edge_m: float = setting(5.0, min=0.5, help="...")
        roof: str = setting("flat", choices=("flat", "any"), help="...")

:func:`from_table` builds the dataclass from a TOML table with the same checks: the type from the
annotation (``float`` takes integers too; ``tuple`` takes a list or a comma-separated string),
``min``/``max`` (``min_open``/``max_open`` for strict bounds), ``choices`` (for a tuple, every
element), nested dataclasses as sub-tables (``[match.sparse]``), ``path=True`` for file names
(relative to ``base_dir``). An unknown key, a wrong type or an out-of-range value raises
``ConfigError`` naming the file, the section and the key. :func:`click_type` gives the click type
of a field for a command-line option, so both stop on the same values.
"""

from __future__ import annotations

import dataclasses
import math
import types
import typing
from pathlib import Path

from aerotri.core.errors import ConfigError

_KEY = "aerotri_setting"


def setting(default=dataclasses.MISSING, *, default_factory=dataclasses.MISSING, choices=None, min=None, max=None,
            min_open: bool = False, max_open: bool = False, path: bool = False, help: str = ""):
    """A dataclass field with its constraints (see the module docstring)."""
    meta = {_KEY: dict(choices=tuple(choices) if choices is not None else None, min=min, max=max,
                       min_open=min_open, max_open=max_open, path=path, help=help)}
    if default_factory is not dataclasses.MISSING:
        return dataclasses.field(default_factory=default_factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def constraints(field: dataclasses.Field) -> dict:
    return dict(field.metadata.get(_KEY) or dict(choices=None, min=None, max=None, min_open=False, max_open=False,
                                                 path=False, help=""))


def field_named(cls, name: str) -> dataclasses.Field:
    for f in dataclasses.fields(cls):
        if f.name == name:
            return f
    raise KeyError(f"{cls.__name__} has no field {name!r}")


def default_of(cls, name: str):
    """The default value of a field (also for ``default_factory`` fields)."""
    f = field_named(cls, name)
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    raise KeyError(f"{cls.__name__}.{name} has no default")


def _unwrap_optional(tp):
    """(inner type, optional) of ``X | None``."""
    if isinstance(tp, types.UnionType) or typing.get_origin(tp) is typing.Union:
        args = [a for a in typing.get_args(tp) if a is not type(None)]
        if len(args) == 1:
            return args[0], True
    return tp, False


def _describe(cons: dict) -> str:
    if cons["choices"] is not None:
        return "one of " + ", ".join(str(c) for c in cons["choices"])
    parts = []
    if cons["min"] is not None:
        parts.append(f"{'>' if cons['min_open'] else '>='} {cons['min']:g}")
    if cons["max"] is not None:
        parts.append(f"{'<' if cons['max_open'] else '<='} {cons['max']:g}")
    return " and ".join(parts)


def check_value(value, cons: dict, where: str) -> None:
    """Range and choice checks of one (scalar) value; ``ConfigError`` naming ``where``."""
    if cons["choices"] is not None and value not in cons["choices"]:
        raise ConfigError(f"{where} = {value!r}: expected {_describe(cons)}")
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        lo, hi = cons["min"], cons["max"]
        if (lo is not None and (value < lo or (cons["min_open"] and value == lo))) or \
                (hi is not None and (value > hi or (cons["max_open"] and value == hi))):
            raise ConfigError(f"{where} = {value!r}: out of range, expected {_describe(cons)}")


def _convert(value, tp, cons: dict, where: str, base_dir):
    tp, _ = _unwrap_optional(tp)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a table of {', '.join(f.name for f in dataclasses.fields(tp))}")
        return from_table(tp, value, where, base_dir)
    origin = typing.get_origin(tp) or tp
    if cons["path"]:
        if not isinstance(value, str) or not value.strip():
            raise ConfigError(f"{where} = {value!r}: expected a file name (text)")
        p = Path(value)
        return p if p.is_absolute() or base_dir is None else Path(base_dir) / p
    if origin in (tuple, list):
        if isinstance(value, str):
            value = [v.strip() for v in value.split(",") if v.strip()]
        if not isinstance(value, list):
            raise ConfigError(f"{where} = {value!r}: expected a list")
        args = [a for a in typing.get_args(tp) if a is not Ellipsis]
        if args and len(args) > 1 and len(args) != len(value):
            raise ConfigError(f"{where} = {value!r}: expected {len(args)} values")
        out = []
        for k, v in enumerate(value):
            et = (args[k] if len(args) > 1 else args[0]) if args else type(v)
            out.append(_convert(v, et, cons, where, base_dir))
        return tuple(out) if origin is tuple else out
    if tp is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where} = {value!r}: expected true or false")
        return value
    if tp is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where} = {value!r}: expected a whole number")
        check_value(value, cons, where)
        return value
    if tp is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
            raise ConfigError(f"{where} = {value!r}: expected a number")
        value = float(value)
        check_value(value, cons, where)
        return value
    if tp is str:
        if not isinstance(value, str):
            raise ConfigError(f"{where} = {value!r}: expected text")
        check_value(value, cons, where)
        return value
    if tp is Path:
        return _convert(value, str, dict(cons, path=True), where, base_dir)
    # anything else (typing.Any, untyped): scalar checks only
    check_value(value, cons, where)
    return value


def from_table(cls, table: dict, where: str, base_dir=None):
    """``cls(**table)`` with every key and value checked; ``where`` names the table (e.g.
    ``P/project.toml [corners]``), ``base_dir`` anchors relative file names."""
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: expected a table of settings")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    for key in table:
        if key not in fields:
            raise ConfigError(f"{where}: unknown key {key!r} (known: {', '.join(fields)})")
    kwargs = {}
    for key, value in table.items():
        sub = f"{where[:-1]}.{key}]" if where.endswith("]") and dataclasses.is_dataclass(
            _unwrap_optional(hints[key])[0]) else f"{where} {key}"
        kwargs[key] = _convert(value, hints[key], constraints(fields[key]), sub, base_dir)
    try:
        return cls(**kwargs)
    except ConfigError:
        raise
    except (TypeError, ValueError) as exc:  # the dataclass's own checks (__post_init__)
        raise ConfigError(f"{where}: {exc}") from None


def to_table(obj) -> dict:
    """The settings as plain TOML/JSON values (for stamps and summaries): paths as text, tuples as lists."""
    def plain(v):
        if dataclasses.is_dataclass(v):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, (list, tuple)):
            return [plain(x) for x in v]
        if isinstance(v, Path):
            return str(v)
        return v

    return plain(obj)


def click_type(cls, name: str):
    """The click parameter type of a field: a Choice, an Int/FloatRange (floats finite, as in
    ``from_table``), a Path for file names, or the plain type."""
    import click

    from aerotri.core.commands import FiniteFloatRange

    f = field_named(cls, name)
    cons = constraints(f)
    tp, _ = _unwrap_optional(typing.get_type_hints(cls)[name])
    if cons["choices"] is not None and tp is str:
        return click.Choice([str(c) for c in cons["choices"]])
    if cons["path"] or tp is Path:
        return click.Path(path_type=Path)
    if tp is float:
        return FiniteFloatRange(min=cons["min"], max=cons["max"], min_open=cons["min_open"], max_open=cons["max_open"])
    if tp is int and (cons["min"] is not None or cons["max"] is not None):
        return click.IntRange(min=cons["min"], max=cons["max"], min_open=cons["min_open"], max_open=cons["max_open"])
    return {int: click.INT, bool: click.BOOL}.get(tp, click.STRING)


def click_option(cls, name: str, *decls: str, **kw):
    """A click option for the field ``name`` of the settings dataclass ``cls``: its type (``click_type``),
    default and help from the field, the parameter named after the field. ``decls`` are the option's
    names (``"--tol-px"``; for a boolean field a flag pair ``"--chips/--no-chips"``, or a single flag
    for a field that defaults to false); ``kw`` overrides or adds click arguments (e.g. ``metavar``)."""
    import click

    f = field_named(cls, name)
    tp, _ = _unwrap_optional(typing.get_type_hints(cls)[name])
    opts = dict(default=default_of(cls, name), show_default=True, help=constraints(f)["help"])
    if tp is bool:
        if not any("/" in d for d in decls):
            opts["is_flag"] = True
    else:
        opts["type"] = click_type(cls, name)
    opts.update(kw)
    return click.option(*decls, name, **opts)
