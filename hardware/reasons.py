"""Typed reasons: why a device holds, why a policy chunk is refused, why a real-time request was not granted,
where contact thresholds came from, why a collection stopped.

A reason is a kind (an Enum member: what code branches on, counts, and writes as a key; its value is the
stable spelling counters and JSON use) plus the values its message shows. The message is rendered from one
template per kind (MESSAGES, filled with str.format from the reason's detail) and nothing parses it back:
rewording a message is editing its template, and changes no behaviour (tests/test_reasons.py renders every
message through a translation table and checks that counters, states and commands stay the same).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from enum import Enum

# kind -> message template: a str.format string over the reason's detail, or a function of the detail (a
# message with a plural or an optional part)
MESSAGES: dict[Enum, str | Callable[..., str]] = {}


def messages(table: dict[Enum, str | Callable[..., str]]) -> None:
    """Register the message templates of one module's kinds (each kind has exactly one)."""
    MESSAGES.update(table)


@dataclass(frozen=True)
class Reason:
    """kind (an Enum member with a registered template) and detail ((name, value) pairs the message shows).
    str() is the message; .key the kind's stable spelling."""

    kind: Enum
    detail: tuple = ()

    @classmethod
    def of(cls, kind: Enum, **detail) -> Reason:
        return cls(kind, tuple(detail.items()))

    @property
    def key(self) -> str:
        """The kind's stable spelling (counter and JSON keys), independent of the message."""
        return str(self.kind.value)

    def get(self, name: str, default=None):
        """One detail value by name."""
        return dict(self.detail).get(name, default)

    def __str__(self) -> str:
        return render(self)


def render(reason: Reason | str | None) -> str:
    """The message of a reason (a plain note is itself; None is "")."""
    if reason is None:
        return ""
    if not isinstance(reason, Reason):
        return str(reason)
    template = MESSAGES[reason.kind]
    detail = dict(reason.detail)
    return template(**detail) if callable(template) else template.format(**detail)


def kind_of(reason) -> Enum | None:
    """The kind of a reason; None for a plain note or None."""
    return reason.kind if isinstance(reason, Reason) else None
