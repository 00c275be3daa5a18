"""What a capture was taken with: the camera's settings, the reference's level, the brackets.

The robot fills one `CaptureSettings` per capture, MODELS carries it (a few bytes), the host
stores it and reads it back. Levels are linear in exposure times gain for the rgb and gray
feature spaces, so a model fitted at one exposure describes the region at any other one
scaled by their ratio (`scaled`): that is how bracketed regions and drift normalisation
come back to a common exposure on the host.
"""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

from btf.johnson import Family, Johnson

MAX_BRACKETS = 4  # shorter exposures one capture may take
MAX_SOURCE = 64  # bytes of UTF-8 a capture's source file name takes on the wire
LINEAR_SPACES = ("rgb", "gray")  # feature spaces whose levels scale with exposure


@dataclass(frozen=True, slots=True)
class CaptureSettings:
    """One capture's camera settings as the device reported them (None: not reported).

    `unlocked`: taken while the camera did not hold its manual lock (`[camera] allow_auto`).
    `reference`: the reference region's mean level per band, and `reference_clipped` the share
    of its pixels at a sensor limit (its level then understates the light). `brackets`: the
    shorter exposures taken (µs); `bracketed` maps a label fitted from one of them to its
    1-based index in `brackets` (the others come from `exposure_us`). `source`: the file the
    frame was read from (a replaying camera; `bounded_source` keeps a long path's end).
    """

    exposure_us: float | None = None
    gain: float | None = None
    white_balance_kelvin: float | None = None
    white_balance_gains: tuple[float, float] | None = None
    sensor_temperature_c: float | None = None
    unlocked: bool = False
    reference: tuple[float, ...] | None = None
    reference_clipped: float = 0.0
    brackets: tuple[float, ...] = ()
    bracketed: Mapping[int, int] = field(default_factory=dict)
    source: str | None = None

    def __post_init__(self) -> None:
        for name in ("exposure_us", "gain", "white_balance_kelvin", "sensor_temperature_c"):
            v = getattr(self, name)
            if v is not None and not math.isfinite(v):
                raise ValueError(f"capture settings: {name} must be finite, got {v}")
        if self.white_balance_gains is not None and self.white_balance_kelvin is not None:
            raise ValueError("capture settings: white balance is a temperature or gains, not both")
        if self.reference is not None and not all(math.isfinite(v) and v >= 0 for v in self.reference):
            raise ValueError(f"capture settings: reference levels must be finite and >= 0, got {self.reference}")
        if not 0.0 <= self.reference_clipped <= 1.0 or (self.reference is None and self.reference_clipped):
            raise ValueError(f"capture settings: reference_clipped {self.reference_clipped} outside [0, 1] "
                             "or without a reference")
        if len(self.brackets) > MAX_BRACKETS or not all(math.isfinite(e) and e > 0 for e in self.brackets):
            raise ValueError(f"capture settings: at most {MAX_BRACKETS} positive bracket exposures, "
                             f"got {self.brackets}")
        if self.brackets and self.exposure_us is None:
            raise ValueError("capture settings: brackets need the capture's own exposure")
        for label, index in self.bracketed.items():
            if not 1 <= index <= len(self.brackets):
                raise ValueError(f"capture settings: label {label} names bracket {index} of {len(self.brackets)}")
        if self.source is not None and (not self.source or not self.source.isprintable()
                                        or len(self.source.encode("utf-8")) > MAX_SOURCE):
            raise ValueError(f"capture settings: source must be printable, 1..{MAX_SOURCE} bytes of UTF-8, "
                             f"got {self.source!r}")

    def exposure_of(self, label: int) -> float | None:
        """The exposure (µs) the models of `label` were fitted at."""
        index = self.bracketed.get(label)
        return self.exposure_us if index is None else self.brackets[index - 1]


def bounded_source(path: str) -> str | None:
    """A frame's source file as a capture records it: the path itself when it fits MAX_SOURCE
    bytes, else "…" and as much of its end as fits (the file's name first); None for none."""
    text = "".join(c if c.isprintable() else "?" for c in str(path))
    if not text:
        return None
    if len(text.encode("utf-8")) <= MAX_SOURCE:
        return text
    room = MAX_SOURCE - len("…".encode())
    tail = text.encode("utf-8")[-room:].decode("utf-8", errors="ignore")
    return "…" + tail


def scaled(model: Johnson, factor: float) -> Johnson:
    """The distribution of factor * X for X ~ `model` (every Johnson family is location-scale)."""
    if not (math.isfinite(factor) and factor > 0):
        raise ValueError(f"scale factor must be positive and finite, got {factor}")
    if factor == 1.0:
        return model
    if model.family is Family.CONST:
        return Johnson.constant(model.xi * factor)
    return Johnson(model.family, model.gamma, model.delta, model.xi * factor, model.lam * factor)
