"""Behavioural fakes: fast in-process devices that behave (move, drift, render) over a clock.

Every fake takes a `Faults` and records its calls in a `history` list of
`Call(call, args, outcome)`, so tests can assert on what happened and what went wrong.
The servo bus and the tracker can also be unplugged (`unplug`, `replug`): meanwhile every call
raises `DeviceGone`, recorded with the outcome "gone".
"""
from __future__ import annotations

import random
from dataclasses import dataclass, field
from typing import Any, NamedTuple


class Call(NamedTuple):
    """One recorded call on a fake: its name, its arguments, and "ok" or the fault kind hit."""

    call: str
    args: tuple[Any, ...]
    outcome: str


@dataclass
class Faults:
    """Seeded fault injection: each `hit(kind)` fires with probability `rate` when `kind` is enabled.

    `kinds` empty means every kind is enabled. `force` names kinds that fire on every
    check regardless of rate (for tests that need a fault now); `remaining`, when set,
    caps how many more faults fire in total.
    """

    rate: float = 0.0
    seed: int = 0
    kinds: frozenset[str] = frozenset()
    force: set[str] = field(default_factory=set)
    remaining: int | None = None
    _rng: random.Random = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if not 0.0 <= self.rate <= 1.0:
            raise ValueError(f"fault rate must lie in [0, 1], got {self.rate}")
        self._rng = random.Random(self.seed)

    def hit(self, kind: str) -> bool:
        """Whether the fault `kind` fires at this check (draws from the seeded generator)."""
        if self.remaining is not None and self.remaining <= 0:
            return False
        fired = kind in self.force
        if not fired and self.rate > 0.0 and (not self.kinds or kind in self.kinds):
            fired = self._rng.random() < self.rate
        if fired and self.remaining is not None:
            self.remaining -= 1
        return fired



__all__ = ["Call", "Faults"]
