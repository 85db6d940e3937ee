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

A section's root dataclass names its table with a ``SECTION`` class variable (``"adjust"``). One
declaration serves three readers:

- the TOML reading (:func:`from_table`);
- the command line: :func:`click_option` makes an option for a field (a dotted path into nested
  settings, ``"measure.eo_sigma_px"``) whose type, default, range and help come from the field;
- the reference page ``docs/settings.md`` (:func:`markdown_reference`, ``aerotri settings --markdown``).

:func:`resolve` gives the settings of a command over a project folder with their precedence: the
field's default, then ``project.toml``'s section, then an option given on the command line (click's
parameter source tells whether it was given); every field's source goes into the stage's report
(:meth:`Resolved.record`).
"""

from __future__ import annotations

import dataclasses
import json
import math
import types
import typing
from pathlib import Path

from aerotri.core.errors import ConfigError

_KEY = "aerotri_setting"


@dataclasses.dataclass(frozen=True)
class Constraints:
    """What a setting field allows and says: its choices (None: any), its range (``min`` / ``max``, None: open;
    ``min_open`` / ``max_open``: the bound itself excluded), whether it is a file name (``path``: relative to the
    project folder) and its help text."""

    choices: tuple | None = None
    min: float | None = None
    max: float | None = None
    min_open: bool = False
    max_open: bool = False
    path: bool = False
    crs: bool = False  # a CRS: a .wkt/.prj file's name is relative to the project folder, its WKT the value
    help: str = ""


def setting(default=dataclasses.MISSING, *, default_factory=dataclasses.MISSING, choices=None, min=None, max=None,
            min_open: bool = False, max_open: bool = False, path: bool = False, crs: bool = False, help: str = ""):
    """A dataclass field with its constraints (see the module docstring)."""
    meta = {_KEY: Constraints(choices=tuple(choices) if choices is not None else None, min=min, max=max,
                              min_open=min_open, max_open=max_open, path=path, crs=crs, help=help)}
    if default_factory is not dataclasses.MISSING:
        return dataclasses.field(default_factory=default_factory, metadata=meta)
    return dataclasses.field(default=default, metadata=meta)


def constraints(field: dataclasses.Field) -> Constraints:
    """The constraints ``setting`` gave the field (a plain field: none)."""
    return field.metadata.get(_KEY) or Constraints()


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


def _describe(cons: Constraints) -> str:
    if cons.choices is not None:
        return "one of " + ", ".join(str(c) for c in cons.choices)
    parts = []
    if cons.min is not None:
        parts.append(f"{'>' if cons.min_open else '>='} {cons.min:g}")
    if cons.max is not None:
        parts.append(f"{'<' if cons.max_open else '<='} {cons.max:g}")
    return " and ".join(parts)


def check_value(value, cons: Constraints, where: str) -> None:
    """Range and choice checks of one (scalar) value; ``ConfigError`` naming ``where`` (empty: the value alone,
    for an option's element, whose option click names)."""
    what = f"{where} = {value!r}" if where else repr(value)
    if cons.choices is not None and value not in cons.choices:
        raise ConfigError(f"{what}: expected {_describe(cons)}")
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        lo, hi = cons.min, cons.max
        if (lo is not None and (value < lo or (cons.min_open and value == lo))) or \
                (hi is not None and (value > hi or (cons.max_open and value == hi))):
            raise ConfigError(f"{what}: out of range, expected {_describe(cons)}")


def _convert(value, tp, cons: Constraints, where: str, base_dir):
    tp, _ = _unwrap_optional(tp)
    if dataclasses.is_dataclass(tp):
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a table of {', '.join(f.name for f in dataclasses.fields(tp))}")
        return from_table(tp, value, where, base_dir)
    origin = typing.get_origin(tp) or tp
    if cons.path:
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
        if cons.crs and base_dir is not None:  # (a file's WKT, so that stamps and index.json record the CRS itself)
            from aerotri.core.crs_files import crs_setting_text

            value = crs_setting_text(value, base_dir, where)
        return value
    if tp is Path:
        return _convert(value, str, dataclasses.replace(cons, path=True), where, base_dir)
    # anything else (typing.Any, untyped): scalar checks only
    check_value(value, cons, where)
    return value


def from_table(cls, table: dict, where: str, base_dir=None, *, sources: typing.Mapping[str, str] | None = None):
    """``cls(**table)`` with every key and value checked; ``where`` names the table (e.g.
    ``P/project.toml [corners]``), ``base_dir`` anchors relative file names. ``sources``: key -> what gave
    its value when not the file itself (e.g. ``--set flight.strips=0``); a refused value of such a key
    is named by it first, as the user typed it."""
    if not isinstance(table, dict):
        raise ConfigError(f"{where}: expected a table of settings")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls) if f.init}
    for key in table:
        if key not in fields:
            raise ConfigError(f"{where}: unknown key {key!r} (known: {', '.join(fields)})")
    required = [name for name, f in fields.items()
                if f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING]
    missing = [name for name in required if name not in table]
    if missing:
        raise ConfigError(f"{where}: missing key {missing[0]!r}" + (f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""))
    kwargs = {}
    for key, value in table.items():
        if dataclasses.is_dataclass(_unwrap_optional(hints[key])[0]):  # a sub-table: [match.sparse]
            sub = f"{where[:-1]}.{key}]" if where.endswith("]") else f"{where} [{key}]"
        else:
            sub = f"{where} {key}"
        try:
            kwargs[key] = _convert(value, hints[key], constraints(fields[key]), sub, base_dir)
        except ConfigError as exc:
            if sources and key in sources:
                raise ConfigError(f"{sources[key]}: {exc}") from None
            raise
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
    if cons.choices is not None and tp is str:
        return click.Choice([str(c) for c in cons.choices])
    if cons.path or tp is Path:
        return click.Path(path_type=Path)
    if tp is float:
        return FiniteFloatRange(min=cons.min, max=cons.max, min_open=cons.min_open, max_open=cons.max_open)
    if tp is int and (cons.min is not None or cons.max is not None):
        return click.IntRange(min=cons.min, max=cons.max, min_open=cons.min_open, max_open=cons.max_open)
    return {int: click.INT, bool: click.BOOL}.get(tp, click.STRING)


# -- nested fields: dotted paths ----------------------------------------------------------------------
def _owner(cls, path: str):
    """(dataclass, field name) of the dotted ``path`` into ``cls`` (``"measure.eo_sigma_px"``)."""
    *heads, name = path.split(".")
    for h in heads:
        cls = _unwrap_optional(typing.get_type_hints(cls)[h])[0]
        if not dataclasses.is_dataclass(cls):
            raise KeyError(f"{path}: {h} is not a table of settings")
    field_named(cls, name)
    return cls, name


def leaf_paths(cls, prefix: str = "") -> list[str]:
    """Dotted paths of every setting of ``cls``, nested settings (sub-tables) flattened."""
    out = []
    hints = typing.get_type_hints(cls)
    for f in dataclasses.fields(cls):
        if not f.init:
            continue
        tp = _unwrap_optional(hints[f.name])[0]
        if dataclasses.is_dataclass(tp):
            out += leaf_paths(tp, f"{prefix}{f.name}.")
        else:
            out.append(prefix + f.name)
    return out


def get_path(obj, path: str):
    for part in path.split("."):
        obj = getattr(obj, part)
    return obj


def replace_path(obj, path: str, value):
    """``obj`` with the field at the dotted ``path`` replaced (``dataclasses.replace`` down the path)."""
    head, _, rest = path.partition(".")
    if not rest:
        return dataclasses.replace(obj, **{head: value})
    return dataclasses.replace(obj, **{head: replace_path(getattr(obj, head), rest, value)})


def replace_paths(obj, values: dict):
    """``obj`` with every field of ``values`` (dotted path -> value) replaced at once (one ``dataclasses.replace``
    per table, so the dataclass's own checks see the new values together)."""
    heads: dict = {}
    for path, value in values.items():
        head, _, rest = path.partition(".")
        heads.setdefault(head, {})[rest] = value
    changes = {head: (replace_paths(getattr(obj, head), rest) if "" not in rest else rest[""])
               for head, rest in heads.items()}
    return dataclasses.replace(obj, **changes)


def _in_table(table: dict, path: str) -> bool:
    for part in path.split("."):
        if not isinstance(table, dict) or part not in table:
            return False
        table = table[part]
    return True


def default_settings(cls):
    """``cls()``, or None for a class with required fields."""
    try:
        return cls()
    except TypeError:
        return None


def field_default(cls, path: str):
    """The default of the field at ``path`` as the root class has it (a sub-table's defaults may differ from its
    class's own, e.g. the dense features of the tie-point stage)."""
    root = default_settings(cls)
    if root is not None:
        return get_path(root, path)
    owner, name = _owner(cls, path)
    return default_of(owner, name)


def toml_key(cls, path: str) -> str:
    """Where a field lives in project.toml: ``[control.measure] eo_sigma_px``."""
    *heads, name = path.split(".")
    section = getattr(cls, "SECTION", None)
    table = ".".join(([section] if section else []) + heads)
    return f"[{table}] {name}" if table else name


def toml_value(v) -> str:
    """A value as TOML text: booleans, numbers, strings (basic strings) and lists of them."""
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (int, float)):
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v, ensure_ascii=False)  # a JSON string is a TOML basic string
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(toml_value(x) for x in v) + "]"
    raise ConfigError(f"cannot write {v!r} as a TOML value")


def sections_toml(tables: dict, prefix: str = "") -> str:
    """Tables ``{section: {key: value}}`` as TOML sections (``[section]``, sub-tables ``[section.sub]``)."""
    out = []
    for section, table in tables.items():
        name = f"{prefix}{section}"
        plain = {k: v for k, v in table.items() if not isinstance(v, dict)}
        out.append(f"\n[{name}]\n" + "".join(f"{k} = {toml_value(v)}\n" for k, v in plain.items()))
        sub = {k: v for k, v in table.items() if isinstance(v, dict)}
        if sub:
            out.append(sections_toml(sub, f"{name}."))
    return "".join(out)


# -- the command line ---------------------------------------------------------------------------------
COMMAND_LINE, PROJECT_TOML, DEFAULT = "command line", "project.toml", "default"


class SettingOption:
    """Marker mix-in: the option sets the field ``field`` (dotted path) of the settings ``settings_cls``."""


def _option_class():
    import click

    class _SettingOption(click.Option, SettingOption):
        def __init__(self, *args, settings_cls, field: str, **kwargs):
            super().__init__(*args, **kwargs)
            self.settings_cls, self.field = settings_cls, field

    return _SettingOption


_OPTION_CLASS = None


def _comma_list(owner, name):
    """Callback of a tuple field given as comma-separated text (``--self-cal pp,radial``, ``--classes 3,4,5``): the
    tuple, each element of the field's element type (``tuple[int, ...]``: whole numbers) and checked against the
    field's choices and range."""
    import click

    cons = constraints(field_named(owner, name))
    args = [a for a in typing.get_args(_unwrap_optional(typing.get_type_hints(owner)[name])[0]) if a is not Ellipsis]
    kind = args[0] if len(args) == 1 and args[0] in (int, float) else str
    what = {int: "whole numbers", float: "numbers", str: "names"}[kind]

    def callback(ctx, param, value):
        if value is None or isinstance(value, tuple):
            return value
        try:
            items = tuple(kind(v.strip()) for v in str(value).split(",") if v.strip())
        except ValueError:
            raise click.BadParameter(f"{value!r}: expected comma-separated {what}", ctx=ctx, param=param) from None
        for v in items:
            try:
                check_value(v, cons, "")
            except ConfigError as exc:
                raise click.BadParameter(f"{exc} (a comma-separated list)", ctx=ctx, param=param) from None
        return items

    return callback


def click_option(cls, path: str, *decls: str, **kw):
    """A click option for the field at ``path`` (a dotted path for nested settings) of the settings dataclass
    ``cls``: its type (``click_type``), default and help from the field, the parameter named after the path
    (dots as ``__``). ``decls`` are the option's names (``"--tol-px"``; for a boolean field a flag pair
    ``"--chips/--no-chips"``, or a single flag that sets the field to the flag's ``flag_value``); a tuple
    field takes comma-separated text (each element checked against the choices) unless ``multiple`` or
    ``nargs`` say otherwise; ``kw`` overrides or adds click arguments. :func:`resolve` applies the option when
    it was given on the command line."""
    import click

    global _OPTION_CLASS
    if _OPTION_CLASS is None:
        _OPTION_CLASS = _option_class()
    owner, name = _owner(cls, path)
    tp, _ = _unwrap_optional(typing.get_type_hints(owner)[name])
    help_text = constraints(field_named(owner, name)).help
    if getattr(cls, "SECTION", None) is not None:
        help_text = f"{help_text} (project.toml {toml_key(cls, path)})".strip()
    opts = dict(default=field_default(cls, path), show_default=True, help=help_text)
    if tp is bool:
        if not any("/" in d for d in decls):
            opts["is_flag"] = True
    elif typing.get_origin(tp) in (tuple, list) or tp in (tuple, list):
        if not kw.get("multiple") and not kw.get("nargs"):
            opts.update(type=click.STRING, callback=_comma_list(owner, name))
            choices = constraints(field_named(owner, name)).choices
            if choices is not None:
                opts["help"] = f"{opts['help']} Comma-separated: {', '.join(map(str, choices))}."
            d = opts["default"]
            opts["default"] = ",".join(map(str, d)) if d else None
            opts["show_default"] = bool(d)
    else:
        opts["type"] = click_type(owner, name)
    opts.update(kw)
    if opts.get("required") and opts.get("default") is None:
        # click >= 8.3 takes an explicit default of None as a value: a required option would never be missing
        del opts["default"]
    return click.option(*decls, path.replace(".", "__"), cls=_OPTION_CLASS, settings_cls=cls, field=path, **opts)


def option_given(ctx, name: str) -> bool:
    """True when the parameter ``name`` was given (command line, environment, prompt), not defaulted."""
    from click.core import ParameterSource

    return ctx.get_parameter_source(name) not in (None, ParameterSource.DEFAULT, ParameterSource.DEFAULT_MAP)


def setting_options(command, cls=None) -> list:
    """The :class:`SettingOption` s of a click command (those of ``cls`` when given)."""
    return [p for p in command.params if isinstance(p, SettingOption) and (cls is None or p.settings_cls is cls)]


# -- precedence: default < project.toml < command line ------------------------------------------------
@dataclasses.dataclass(frozen=True)
class Resolved:
    """Settings with the source of every field (dotted path -> ``default``, ``project.toml``, ``command
    line``, or what else set it, e.g. ``aerotri run``) and notes on values a stage changed (path -> why)."""

    settings: typing.Any
    sources: dict
    notes: dict = dataclasses.field(default_factory=dict)

    def replace(self, path: str, value, source: str, note: str | None = None) -> "Resolved":
        """The settings with the field at ``path`` set to ``value`` by ``source`` (and why, ``note``)."""
        notes = dict(self.notes)
        if note:
            notes[path] = note
        return Resolved(replace_path(self.settings, path, value), {**self.sources, path: source}, notes)

    def record(self) -> dict:
        """The settings for a report: ``{path: {"value": ..., "source": ...[, "note": ...]}}`` (plain JSON
        values: paths as text, tuples as lists)."""
        out = {}
        for path in leaf_paths(type(self.settings)):
            row = {"value": to_table(get_path(self.settings, path)), "source": self.sources.get(path, DEFAULT)}
            if path in self.notes:
                row["note"] = self.notes[path]
            out[path] = row
        return out


def _plain_numbers(value):
    """numpy scalars as Python numbers, arrays as lists (of them), through lists; anything else as it is."""
    import numpy as np

    if isinstance(value, np.ndarray):
        return [_plain_numbers(v) for v in value.tolist()]
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, (list, tuple)):
        return [_plain_numbers(v) for v in value]
    return value


def _same(value, default) -> bool:
    try:
        return type(value) is type(default) and bool(value == default)
    except (TypeError, ValueError):  # arrays and the like
        return False


def checked_settings(settings, where: str | None = None):
    """Settings made in code (``AdjustSettings(alpha=5)``) put through the checks and conversions of ``from_table``:
    ``ConfigError`` naming the class and the field, else a copy with the values as project.toml would give them
    (``self_calibration="pp"`` -> ``("pp",)``, which a string's letters were before). The command line and
    project.toml refused such values while a library call passed them on (trial-api F4: alpha 5, meant as 5 %,
    switched the data snooping off without a word). None stays None."""
    cls = type(settings)
    where = where or cls.__name__
    hints = typing.get_type_hints(cls)
    changed = {}
    for f in dataclasses.fields(cls):
        value = getattr(settings, f.name)
        if not f.init or value is None or (f.default is not dataclasses.MISSING and _same(value, f.default)):
            continue  # a default is allowed by definition (some are no number a table could hold: inf)
        sub = f"{where}.{f.name}"
        if dataclasses.is_dataclass(value):
            new = checked_settings(value, sub)
        else:
            # numpy scalars and arrays as the plain values a table holds (a lever arm as an array, alpha as float32)
            new = _convert(_plain_numbers(to_table(value)), hints[f.name], constraints(f), sub, None)
        if new is not value and not _same(new, value):
            changed[f.name] = new
    if not changed:
        return settings
    try:
        return dataclasses.replace(settings, **changed)
    except (TypeError, ValueError) as exc:  # the dataclass's own checks (__post_init__)
        raise ConfigError(f"{where}: {exc}") from None


def unresolved(settings) -> Resolved:
    """Settings a library caller made itself (checked as project.toml's are: ``checked_settings``): every field's
    source is ``library call``."""
    settings = checked_settings(settings)
    return Resolved(settings, {p: "library call" for p in leaf_paths(type(settings))})


def settings_of(value, cls, project=None) -> Resolved:
    """A stage's settings argument as :class:`Resolved`: None -> the project's section (``resolve``, no command
    line), a ``cls`` instance -> the caller's own (source ``library call``), a ``Resolved`` as it is."""
    if value is None:
        return resolve(cls, project)
    if isinstance(value, Resolved):
        return value
    return unresolved(value)


def resolve(cls, project=None, ctx=None, *, section: str | None = None) -> Resolved:
    """The settings of ``cls`` for a command over ``project`` (an ``aerotri.core.project.Project``; None: a
    command over plain files): the defaults, overridden by the project's section (``section``, default
    ``cls.SECTION``; every key checked, ``ConfigError`` naming the file, the section and the key), overridden
    by the options of ``ctx`` (a click context) that set a field of ``cls`` and were given on the command
    line. Each option overrides only its own field."""
    from aerotri.core.errors import OptionError

    section = section if section is not None else getattr(cls, "SECTION", None)
    table, where, base = {}, f"[{section}]", None
    if project is not None and section is not None:
        table = project.stage_table(section)  # "": the whole file, one sub-table per section
        where = f"{project.config_path} [{section}]" if section else str(project.config_path)
        base = project.root
    settings = from_table(cls, table, where, base)
    sources = {p: PROJECT_TOML if _in_table(table, p) else DEFAULT for p in leaf_paths(cls)}
    given = [p for p in (setting_options(ctx.command, cls) if ctx is not None else []) if option_given(ctx, p.name)]
    if given:
        try:
            settings = replace_paths(settings, {p.field: ctx.params[p.name] for p in given})
        except (TypeError, ValueError) as exc:  # the dataclass's own checks (__post_init__)
            raise OptionError(str(exc), param=" / ".join(p.opts[0] for p in given)) from None
        sources.update({p.field: COMMAND_LINE for p in given})
    return Resolved(settings, sources)


def settings_lines(record: dict | None, title: str = "Settings (value, and where it came from)") -> list[str]:
    """A text table of a settings record (:meth:`Resolved.record`): one line per setting."""
    if not record:
        return []
    width = max(len(k) for k in record)
    lines = [title]
    for key, row in record.items():
        v = row["value"]
        text = "-" if v is None or v == [] else ", ".join(map(str, v)) if isinstance(v, list) else str(v)
        lines.append(f"  {key:<{width}} : {text}  [{row['source']}]" + (f" ({row['note']})" if row.get("note") else ""))
    return lines + [""]


# -- the reference page ---------------------------------------------------------------------------
_UNITS = (("_m2", "m²"), ("_m_per_km", "m/km"), ("_m_per_s", "m/s"), ("_mm", "mm"), ("_hz", "Hz"), ("_dn", "DN"),
          ("_mps", "m/s"), ("_px", "px"), ("_deg", "deg"), ("_pct", "%"),
          ("_mb", "MB"), ("_s", "s"), ("_m", "m"))


def unit_of(name: str) -> str:
    """The unit a field's name states (``res_m`` -> m, ``tol_px`` -> px), or ""."""
    for suffix, unit in _UNITS:
        if name.endswith(suffix):
            return unit
    return ""


def _type_name(tp) -> str:
    tp, optional = _unwrap_optional(tp)
    origin = typing.get_origin(tp)
    if origin in (tuple, list):
        args = [a for a in typing.get_args(tp) if a is not Ellipsis]
        name = f"{len(args)} numbers" if len(args) > 1 else f"list of {_type_name(args[0]) if args else 'values'}"
    elif origin is dict or tp is dict:
        name = "table"
    else:
        name = {float: "number", int: "integer", bool: "true/false", str: "text", Path: "file"}.get(tp, str(tp))
    return name + (" or none" if optional else "")


def _md_value(v) -> str:
    if v is None:
        return "none"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (tuple, list)):
        return "[" + ", ".join(_md_value(x) for x in v) + "]" if v else "[]"
    if isinstance(v, dict):
        return "{}" if not v else str(v)
    if isinstance(v, float):
        return f"{v:g}"
    return str(v)


def _first_paragraph(doc: str | None) -> str:
    return " ".join(line.strip() for line in (doc or "").strip().split("\n\n")[0].splitlines())


def markdown_reference(sections: list[tuple[str, list, str]], options: dict) -> str:
    """The settings reference (Markdown): per section (``(name, [dataclasses], what reads it)``; a section two
    dataclasses share lists both) a table of its keys with type, unit, default, allowed values, the
    command-line options that set it (``options``: ``{(dataclass, path): ["aerotri adjust --gnss-correction",
    ...]}``) and help."""
    out = []
    for name, classes, readers in sections:
        out += [f"## [{name}]", ""] + [_first_paragraph(c.__doc__) for c in classes] + [
            "", f"Read by: {readers}.", "", "| key | type | unit | default | allowed | command line | meaning |",
            "|---|---|---|---|---|---|---|"]
        for cls, path in [(c, p) for c in classes for p in leaf_paths(c)]:
            owner, fname = _owner(cls, path)
            f = field_named(owner, fname)
            cons = constraints(f)
            tp = typing.get_type_hints(owner)[fname]
            allowed = _describe(cons) if (cons.choices is not None or cons.min is not None
                                          or cons.max is not None) else ""
            opts = "<br>".join(f"`{o}`" for o in options.get((cls, path), []))
            try:
                default = f"`{_md_value(field_default(cls, path))}`"
            except KeyError:  # a required key (the simulator's preset tables)
                default = "required"
            key = toml_key(cls, path).replace(f"[{name}] ", "")
            help_text = cons.help.replace("|", "\\|").replace("\n", " ")
            out.append(f"| `{key}` | {_type_name(tp)} | {unit_of(fname)} | {default} | "
                       f"{allowed} | {opts} | {help_text} |")
        out.append("")
    return "\n".join(out)
