"""One strict reader for every description the toolkit takes (training config, export config,
scene TOML, capture.toml): unknown keys are refused naming the closest known key, wrong types
naming the expected type, and a frozen dataclass round-trips through TOML (tomli_w; ``inf``
included).

A *spec* is what a value must be: ``bool``, ``int`` (not a float, not a bool), ``float`` (an int
is accepted), ``str``, ``tuple[T, ...]`` / ``list[T]`` (a TOML array of T), ``A | B``, ``dict``
(any table), ``object`` (anything), or a dict of specs (a sub-table with those keys). A frozen
dataclass is a table whose keys are its fields and whose specs are their annotations; a field
whose annotation is itself a dataclass is a ``[section]``.

SYNOPSIS

    >>> from dataclasses import dataclass, field
    >>> @dataclass(frozen=True)
    ... class Optim:
    ...     steps: int = 10
    ...     lr: float = 1e-3
    >>> @dataclass(frozen=True)
    ... class Config:
    ...     optim: Optim = field(default_factory=Optim)
    >>> cfg = from_table(Config, apply_overrides({}, ["optim.steps=4"], ValueError), "cfg", ValueError)
    >>> cfg.optim.steps, cfg.optim.lr
    (4, 0.001)
    >>> from_table(Config, {"optim": {"stpes": 4}}, "cfg", ValueError)
    Traceback (most recent call last):
    ...
    ValueError: cfg: unknown key 'optim.stpes' (did you mean 'optim.steps'?); [optim] has: lr, steps
    >>> check_table({"steps": 4.0}, {"steps": int}, "capture.toml [pattern]", ValueError)
    Traceback (most recent call last):
    ...
    ValueError: capture.toml [pattern]: steps = 4.0: expected an integer, got a float
    >>> to_table(Config(Optim(lr=float("inf"))))
    {'optim': {'steps': 10, 'lr': inf}}
"""
from __future__ import annotations

import copy
import dataclasses
import difflib
import sys
import tomllib
import types
import typing
from pathlib import Path

_NAMES = {bool: "a boolean (true / false)", int: "an integer", float: "a number", str: "a string",
          dict: "a table", list: "an array", tuple: "an array"}


def _type_name(value) -> str:
    for t in (bool, int, float, str, dict, list):
        if isinstance(value, t):
            return {bool: "a boolean", int: "an integer", float: "a float", str: "a string", dict: "a table",
                    list: "an array"}[t]
    return type(value).__name__


def expected(spec) -> str:
    """Words for what ``spec`` accepts (used in the refusals)."""
    if isinstance(spec, dict):
        return "a table"
    if spec is object or spec is typing.Any:
        return "anything"
    if spec in _NAMES:
        return _NAMES[spec]
    origin, args = typing.get_origin(spec), typing.get_args(spec)
    if origin in (types.UnionType, typing.Union):
        return " or ".join(expected(a) for a in args)
    if origin in (tuple, list):
        inner = args[0] if args else object
        return "an array" if inner is object else f"an array of {expected(inner).split(' ', 1)[1]}s"
    if dataclasses.is_dataclass(spec):
        return "a table"
    return getattr(spec, "__name__", str(spec))


def _ok(value, spec) -> bool:
    if isinstance(spec, dict) or dataclasses.is_dataclass(spec):
        return isinstance(value, dict)
    if spec is object or spec is typing.Any:
        return True
    if spec is bool:
        return isinstance(value, bool)
    if spec is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if spec is float:
        return isinstance(value, (int, float)) and not isinstance(value, bool)
    if spec in (str, dict):
        return isinstance(value, spec)
    origin, args = typing.get_origin(spec), typing.get_args(spec)
    if origin in (types.UnionType, typing.Union):
        return any(_ok(value, a) for a in args)
    if spec in (list, tuple) or origin in (tuple, list):
        inner = args[0] if args else object
        return isinstance(value, (list, tuple)) and all(_ok(v, inner) for v in value)
    raise TypeError(f"not a spec: {spec!r}")


def check_value(value, spec, name: str, where: str, error):
    """``value`` if it is what ``spec`` accepts, else ``error`` naming ``name`` and the expected type."""
    if not _ok(value, spec):
        raise error(f"{where}: {name} = {value!r}: expected {expected(spec)}, got {_type_name(value)}")
    return value


def check_keys(table: dict, known, where: str, error, prefix: str = "", sections: bool = False):
    """Refuse a key of ``table`` that is not in ``known``, naming the closest known key
    (``sections``: the known keys are ``[section]`` tables)."""
    for key in table:
        if key in known:
            continue
        close = difflib.get_close_matches(str(key), [str(k) for k in known], n=1, cutoff=0.6)
        names = ", ".join(sorted(str(k) for k in known)) or "none"
        if sections:
            hint = f" (did you mean [{prefix}{close[0]}]?)" if close else ""
            raise error(f"{where}: unknown section [{prefix}{key}]{hint}; sections: {names}")
        hint = f" (did you mean '{prefix}{close[0]}'?)" if close else ""
        section = f"[{prefix[:-1]}] has" if prefix else "known keys"
        raise error(f"{where}: unknown key '{prefix}{key}'{hint}; {section}: {names}")


def check_table(table, schema: dict, where: str, error, prefix: str = "") -> dict:
    """Check ``table`` (a parsed TOML table) against ``schema`` (key -> spec; a dict spec is a
    sub-table): unknown keys and wrong types raise ``error``. Returns ``table``."""
    if not isinstance(table, dict):
        raise error(f"{where}: {prefix[:-1] or 'the description'} = {table!r}: expected a table, "
                    f"got {_type_name(table)}")
    check_keys(table, schema, where, error, prefix, sections=bool(schema) and all(
        isinstance(v, dict) for v in schema.values()))
    for key, value in table.items():
        spec = schema[key]
        if isinstance(spec, dict):
            check_table(value, spec, where, error, f"{prefix}{key}.")
        else:
            check_value(value, spec, f"{prefix}{key}", where, error)
    return table


def _specs(cls) -> dict:
    """field name -> spec of a dataclass: a section's dataclass (its ``default_factory``), else the
    field's annotation evaluated in the class's module."""
    out = {}
    for f in dataclasses.fields(cls):
        factory = f.default_factory
        if isinstance(factory, type) and dataclasses.is_dataclass(factory):
            out[f.name] = factory
        elif isinstance(f.type, str):
            out[f.name] = eval(f.type, vars(sys.modules[cls.__module__]), {})  # noqa: S307 (an annotation)
        else:
            out[f.name] = f.type
        if dataclasses.is_dataclass(out[f.name]) and not isinstance(out[f.name], type):
            raise TypeError(f"{cls.__name__}.{f.name}: a section's annotation must be its dataclass")
    return out


def schema_of(cls) -> dict:
    """The schema (key -> spec) of a dataclass: its fields' annotations, sections as sub-schemas."""
    return {k: schema_of(v) if dataclasses.is_dataclass(v) else v for k, v in _specs(cls).items()}


def _frozen(value):
    return tuple(_frozen(v) for v in value) if isinstance(value, list) else value


def from_table(cls, table: dict, where: str, error):
    """A ``cls`` (dataclass) from a parsed TOML table: absent keys keep their defaults, arrays
    become tuples, an int given for a float becomes a float; unknown keys / wrong types raise
    ``error``."""
    check_table(table, schema_of(cls), where, error)
    return _build(cls, table)


def _build(cls, table: dict, base=None):
    """``cls`` from ``table``; keys the table leaves out keep ``base``'s values (a section's
    default instance), else the field defaults."""
    hints = _specs(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    kw = {}
    for key, value in table.items():
        spec = hints[key]
        if dataclasses.is_dataclass(spec):
            factory = fields[key].default_factory
            kw[key] = _build(spec, value, None if factory is dataclasses.MISSING else factory())
        elif spec is float:
            kw[key] = float(value)
        else:
            kw[key] = _frozen(value)
    return cls(**kw) if base is None else dataclasses.replace(base, **kw)


def to_table(obj) -> dict:
    """A dataclass as a TOML-able dict (tuples as lists, sections as tables); ``tomli_w.dumps``
    of it is read back by :func:`from_table` to an equal object."""
    def plain(v):
        if dataclasses.is_dataclass(v):
            return {f.name: plain(getattr(v, f.name)) for f in dataclasses.fields(v)}
        if isinstance(v, (tuple, list)):
            return [plain(x) for x in v]
        if isinstance(v, Path):
            return str(v)
        return v
    return plain(obj)


def parse_override(text: str, error) -> tuple[list, object]:
    """``section.key=value`` -> (["section", "key"], value); the value is read as TOML (a bare
    word is a string)."""
    if "=" not in text or "." not in text.split("=", 1)[0]:
        raise error(f"override {text!r}: expected section.key=value, e.g. optim.lr=1e-3")
    name, raw = text.split("=", 1)
    try:
        value = tomllib.loads(f"v = {raw.strip()}")["v"]
    except tomllib.TOMLDecodeError:
        value = raw.strip()
    return [p.strip() for p in name.split(".")], value


def apply_overrides(tree: dict, overrides, error) -> dict:
    """A copy of ``tree`` (a parsed TOML table) with ``section.key=value`` overrides set."""
    out = copy.deepcopy(tree)
    for text in overrides or ():
        path, value = parse_override(text, error)
        node = out
        for part in path[:-1]:
            node = node.setdefault(part, {})
            if not isinstance(node, dict):
                raise error(f"override {text!r}: {part} is not a table")
        node[path[-1]] = value
    return out


def read_toml_text(path, error, what: str = "description") -> tuple[str, dict]:
    """(text, parsed table) of the TOML file ``path``; ``error`` naming the file (``what``: the
    kind of description) when it is missing or not TOML."""
    p = Path(path)
    try:
        text = p.read_text()
        return text, tomllib.loads(text)
    except FileNotFoundError:
        raise error(f"{what} {p}: no such file") from None
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise error(f"{what} {p}: not valid TOML ({exc})") from None


def read_toml(path, error, what: str = "description") -> dict:
    """The parsed TOML file ``path`` (:func:`read_toml_text`)."""
    return read_toml_text(path, error, what)[1]
