"""Checks of values read from a TOML file, each failing with a ConfigError that names the file (f), the
field (where) and the fix: unknown keys, a missing key, a table, an array of tables, a scalar of a type, a
value against a config dataclass field's annotation (str, int, float, bool, list[...], unions). Used by the
rig loader (hardware/rigs/rig.py).
"""

from __future__ import annotations

import typing

from hardware.errors import ConfigError


def unknown_keys(d: dict, allowed: set, f: str, where: str) -> None:
    for k in d:
        if k not in allowed:
            raise ConfigError(f"unknown key {k!r}", where=f"{f}: {where or 'top level'}",
                              fix=f"remove it or use one of {', '.join(sorted(allowed))}")


def need_key(d: dict, key: str, f: str, where: str, what: str):
    if key not in d:
        raise ConfigError(f"missing field {key!r}", where=f"{f}: {where}", fix=f"add {key} = ... ({what})")
    return d[key]


def as_table(v, f: str, where: str) -> dict:
    if not isinstance(v, dict):
        raise ConfigError(f"expected a table, got {type(v).__name__}", where=f"{f}: {where}",
                          fix=f"write it as [{where}] or {{ key = value }}")
    return v


def as_array(v, f: str, where: str) -> list:
    if not isinstance(v, list):
        raise ConfigError(f"expected an array of tables, got {type(v).__name__}", where=f"{f}: {where}",
                          fix=f"write each entry as [[{where}]]")
    return v


def typed_value(v, typ: type, f: str, where: str):
    ok = isinstance(v, typ) and not (typ is int and isinstance(v, bool))
    if typ is float and isinstance(v, int) and not isinstance(v, bool):
        return float(v)
    if not ok:
        raise ConfigError(f"expected {typ.__name__}, got {type(v).__name__} {v!r}", where=f"{f}: {where}",
                          fix=f"write a {typ.__name__}")
    return v


def _matches(v, t: str) -> bool:
    t = t.strip()
    if "|" in t and not t.startswith("list["):
        return any(_matches(v, part) for part in t.split("|"))
    if t == "None":
        return v is None
    if t.startswith("list[") and t.endswith("]"):
        return isinstance(v, list) and all(_matches(x, t[5:-1]) for x in v)
    if t == "dict":
        return isinstance(v, dict)
    scalar = {"str": str, "int": int, "float": (int, float), "bool": bool}.get(t)
    if scalar is None:
        return True
    return isinstance(v, scalar) and (t == "bool" or not isinstance(v, bool))


def check_type(v, hint, f: str, where: str):
    """Check a TOML value against a config field's annotation (str, int, float, bool, list[...], unions)."""
    t = hint if isinstance(hint, str) else _hint_str(hint)
    if not _matches(v, t):
        raise ConfigError(f"expected {t}, got {type(v).__name__} {v!r}", where=f"{f}: {where}",
                          fix=f"write a value of type {t}")
    if t == "float" and isinstance(v, int):
        return float(v)
    return v


def _hint_str(h) -> str:
    origin, args = typing.get_origin(h), typing.get_args(h)
    if origin in (typing.Union, getattr(__import__("types"), "UnionType", None)):
        return " | ".join(_hint_str(a) for a in args)
    if origin is list:
        return f"list[{_hint_str(args[0])}]" if args else "list[str]"
    if origin is dict or h is dict:
        return "dict"
    if h is type(None):
        return "None"
    return getattr(h, "__name__", str(h))
