"""Command-line forms of dataclass fields, declared once in each field's metadata (`option(...)`), and what is
generated from them for a tree of dataclasses (a field whose metadata names `nested` is a dataclass of its
own): the argparse flags (`add_arguments`), the dataclass parsed back from them (`from_args`), the argv that
parses back to the same dataclass (`to_argv`: the torchrun relaunch), and the meta entries that must be
unchanged for `--resume` (`resume_keys`: each field names the one that checks it).
"""

from __future__ import annotations

import argparse
from dataclasses import MISSING, field, fields

from hardware.errors import UserError


def option(default=MISSING, *, flag: Flag | None = None, resume: str = "", factory=MISSING, nested=None):
    """A dataclass field with its command-line form (`flag`, None: none) and `resume`: the checkpoint meta
    entry ("method", "train.lr", "policy" for the model config, "data_hash", "phases") that must be unchanged
    for `--resume` to continue the run; "": the field may change. `nested`: the field is that dataclass."""
    meta = {"flag": flag, "resume": resume, "nested": nested}
    if factory is not MISSING:
        return field(default_factory=factory, metadata=meta)
    return field(default=default, metadata=meta)


class Flag:
    """`--name VALUE` (or a positional `name` with nargs "+"), parsed with `type`, written back with str()
    (floats too: str(float) reads back to the same float). optional: the flag's default is None, meaning
    "not given" (the field's default, or one the owner derives); at_least / above: bounds checked on parsing;
    group: flags of one group are mutually exclusive (to_argv writes the first with a value); relaunch: False
    for a flag of the launcher only (not passed to the processes it starts); required: it must be given."""

    def __init__(self, name: str, help: str = "", *, type=str, choices=None, metavar=None, unit: str = "",
                 optional: bool = False, at_least=None, above=None, group: str = "", relaunch: bool = True,
                 required: bool = False):
        self.name, self.help, self.type, self.choices, self.metavar = name, help, type, choices, metavar
        self.unit, self.optional, self.at_least, self.above = unit, optional, at_least, above
        self.group, self.relaunch, self.required = group, relaunch, required

    def names(self) -> list[str]:
        """The command-line words this flag adds (a flag may add more than one: --thresholds, --no-tare)."""
        return [self.name]

    @property
    def positional(self) -> bool:
        return not self.name.startswith("-")

    def _help(self) -> str | None:
        text = f"{self.help} [{self.unit}]" if self.unit else self.help
        return text or None

    def add(self, p, dest: str, default) -> None:
        if self.positional:
            p.add_argument(dest, type=self.type, nargs="+", metavar=self.metavar, help=self._help())
            return
        metavar = self.metavar or (None if self.choices else self.name[2:].upper().replace("-", "_"))
        p.add_argument(self.name, dest=dest, type=self.type, default=None if self.optional else default,
                       choices=list(self.choices) if self.choices is not None else None, metavar=metavar,
                       help=self._help(), **({"required": True} if self.required else {}))

    def value(self, ns, dest: str):
        """The parsed value, MISSING when not given (an optional flag); UserError when out of bounds."""
        v = getattr(ns, dest)
        if v is None and self.optional:
            return MISSING
        if v is not None and self.at_least is not None and v < self.at_least:
            raise UserError(f"{self.name} must be >= {self.at_least}, got {v}")
        if v is not None and self.above is not None and not v > self.above:
            raise UserError(f"{self.name} must be > {self.above}, got {v}")
        return v

    def argv(self, value, default) -> list[str]:
        """The flag and its text for `value`; [] for None, and for the field's default where not giving the
        flag gives that default (an optional flag's default may be derived: it is written out)."""
        if value is None or (not self.optional and not self.positional and value == default):
            return []
        if self.positional:
            return [str(v) for v in value]
        return [self.name, str(value)]


class Switch(Flag):
    """A flag without a value that flips the field's default (store_true for a False field, store_false for a
    True one, as `--no-progress` sets progress False)."""

    def add(self, p, dest: str, default) -> None:
        p.add_argument(self.name, dest=dest, action="store_false" if default else "store_true",
                       help=self._help())

    def value(self, ns, dest: str):
        return bool(getattr(ns, dest))

    def argv(self, value, default) -> list[str]:
        return [self.name] if bool(value) != bool(default) else []


def _walk(cls, prefix: str = ""):
    """(dotted path, field) of every leaf field of a dataclass tree, in declaration order."""
    for f in fields(cls):
        nested = f.metadata.get("nested")
        if nested is not None:
            yield from _walk(nested, f"{prefix}{f.name}.")
        else:
            yield prefix + f.name, f


def _dest(path: str) -> str:
    return path.replace(".", "__")


def _default(f):
    return f.default_factory() if f.default_factory is not MISSING else f.default


def add_arguments(p: argparse.ArgumentParser, cls) -> None:
    """Every flag of the dataclass tree `cls`, with its help, choices, unit and default."""
    groups: dict = {}
    for path, f in _walk(cls):
        flag = f.metadata.get("flag")
        if flag is None:
            continue
        target = p
        if flag.group:
            if flag.group not in groups:
                groups[flag.group] = p.add_mutually_exclusive_group()
            target = groups[flag.group]
        flag.add(target, _dest(path), _default(f))


def from_args(cls, ns, prefix: str = ""):
    """The dataclass tree `cls` from a namespace parsed by add_arguments' flags (fields without a flag, and
    optional flags not given: their defaults)."""
    kw = {}
    for f in fields(cls):
        nested = f.metadata.get("nested")
        flag = f.metadata.get("flag")
        if nested is not None:
            kw[f.name] = from_args(nested, ns, f"{prefix}{f.name}.")
        elif flag is not None:
            v = flag.value(ns, _dest(prefix + f.name))
            if v is not MISSING:
                kw[f.name] = v
    return cls(**kw)


def given(ns, path: str) -> bool:
    """Whether the flag of the field at `path` ("train.epochs") was given on the command line."""
    return getattr(ns, _dest(path), None) is not None


def _get(obj, path: str):
    for part in path.split("."):
        obj = getattr(obj, part)
    return obj


def to_argv(obj) -> list[str]:
    """obj's values as the flags add_arguments made (positional ones first): parsed back, they give obj again
    (less the fields without a flag or with relaunch=False)."""
    first: list[str] = []
    rest: list[str] = []
    done_groups: set = set()
    for path, f in _walk(type(obj)):
        flag = f.metadata.get("flag")
        if flag is None or not flag.relaunch:
            continue
        value = _get(obj, path)
        if flag.group:
            if flag.group in done_groups or not value:
                continue
            done_groups.add(flag.group)
        (first if flag.positional else rest).extend(flag.argv(value, _default(f)))
    return first + rest


def resume_keys(cls) -> list[str]:
    """The meta entries that must be unchanged for --resume, from the fields' `resume` (in field order)."""
    out: list[str] = []
    for _, f in _walk(cls):
        key = f.metadata.get("resume", "")
        if key and key not in out:
            out.append(key)
    return out


def flag_names(cls) -> list[str]:
    """Every flag the tree declares (positional ones by name), for tests and the docs."""
    out = []
    for _, f in _walk(cls):
        flag = f.metadata.get("flag")
        if flag is not None:
            out += flag.names()
    return out
