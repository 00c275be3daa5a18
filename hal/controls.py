"""Camera controls: reading them from text, and judging whether a lock held.

Every camera body asks its device for `CameraControls`, reads back what it granted and
calls `with_lock_check` to fill in `lock_held` and the problems, so a camera that keeps
its automatics on, or grants something else than it was asked, is named the same way
whatever the device.
"""
from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from hal.interfaces import CameraControls, CameraSettings

AUTO = "auto"


@dataclass(frozen=True, slots=True)
class Tolerance:
    """How far a granted value may sit from the asked one: the larger of an absolute and a relative step."""

    exposure_us: float = 0.0
    gain: float = 0.0
    kelvin: float = 0.0
    relative: float = 0.02

    def near(self, asked: float, got: float | None, absolute: float) -> bool:
        return got is not None and math.isfinite(got) and abs(got - asked) <= max(absolute, self.relative * asked)


EXACT = Tolerance(relative=1e-9)
# Where a camera that does not report a control is asked to lock it.
FALLBACK_LOCK = CameraControls(exposure_us=10_000.0, gain=1.0, white_balance_kelvin=5000.0)


def hold(now: CameraSettings) -> CameraControls:
    """A manual lock at the values the camera stands at (`FALLBACK_LOCK`'s where it reports none)."""
    if now.white_balance_kelvin is None and now.white_balance_gains is not None:
        wb: dict = {"white_balance_gains": now.white_balance_gains}
    else:
        wb = {"white_balance_kelvin": now.white_balance_kelvin or FALLBACK_LOCK.white_balance_kelvin}
    return CameraControls(now.exposure_us or FALLBACK_LOCK.exposure_us,
                          FALLBACK_LOCK.gain if now.gain is None else now.gain, **wb)


def _number(text: str | float, name: str) -> float | None:
    if isinstance(text, str) and text.strip().lower() == AUTO:
        return None
    try:
        value = float(text)
    except (TypeError, ValueError):
        raise ValueError(f"camera {name} must be a number or 'auto', got {text!r}") from None
    return value


def parse_controls(exposure: str | float = AUTO, gain: str | float = AUTO,
                   white_balance: str | float = AUTO) -> CameraControls:
    """Controls from text: exposure in µs, gain, and white balance as 'auto', '5500K' (or a
    number of kelvin) or 'RED,BLUE' gains. ValueError names the value that does not parse."""
    wb_kelvin = None
    wb_gains = None
    wb = str(white_balance).strip()
    if "," in wb:
        parts = [p.strip() for p in wb.split(",")]
        try:
            red, blue = (float(p) for p in parts)
        except ValueError:
            raise ValueError(f"camera white balance gains must be 'RED,BLUE', got {white_balance!r}") from None
        wb_gains = (red, blue)
    elif wb.lower() != AUTO:
        wb_kelvin = _number(wb[:-1] if wb[-1:] in ("K", "k") else wb, "white balance")
    return CameraControls(_number(exposure, "exposure"), _number(gain, "gain"), wb_kelvin, wb_gains)


def with_lock_check(asked: CameraControls, got: CameraSettings, tolerance: Tolerance) -> CameraSettings:
    """`got` with `lock_held` and `problems` judged against what was asked."""
    problems = list(got.problems)
    if asked.exposure_us is not None:
        if got.auto_exposure:
            problems.append(f"exposure asked manual {asked.exposure_us:g} us, the device still runs auto exposure")
        elif not tolerance.near(asked.exposure_us, got.exposure_us, tolerance.exposure_us):
            problems.append(f"exposure asked {asked.exposure_us:g} us, granted {_text(got.exposure_us)} us")
    if asked.gain is not None:
        if got.auto_gain:
            problems.append(f"gain asked manual {asked.gain:g}, the device still runs auto gain")
        elif not tolerance.near(asked.gain, got.gain, tolerance.gain):
            problems.append(f"gain asked {asked.gain:g}, granted {_text(got.gain)}")
    if asked.manual_white_balance:
        if got.auto_white_balance:
            problems.append("white balance asked manual, the device still runs auto white balance")
        elif asked.white_balance_kelvin is not None:
            if not tolerance.near(asked.white_balance_kelvin, got.white_balance_kelvin, tolerance.kelvin):
                problems.append(f"white balance asked {asked.white_balance_kelvin:g} K, "
                                f"granted {_text(got.white_balance_kelvin)} K")
        elif asked.white_balance_gains is not None:
            granted = got.white_balance_gains or (None, None)
            if not all(tolerance.near(a, g, 0.0) for a, g in zip(asked.white_balance_gains, granted)):
                problems.append(f"white balance gains asked {asked.white_balance_gains}, granted {got.white_balance_gains}")
    return dataclasses.replace(got, lock_held=not problems, problems=tuple(problems))


def _text(value: float | None) -> str:
    return "nothing" if value is None else f"{value:g}"


def describe(s: CameraSettings) -> str:
    """One line for a person: what the camera captures with and whether the lock held."""
    def part(name: str, value: float | None, unit: str, auto: bool) -> str:
        shown = "?" if value is None else f"{value:g}{unit}"
        return f"{name} {'auto ' if auto else ''}{shown}"

    wb = (f"{s.white_balance_kelvin:g} K" if s.white_balance_kelvin is not None
          else f"gains {s.white_balance_gains[0]:g},{s.white_balance_gains[1]:g}" if s.white_balance_gains
          else "?")
    text = ", ".join([part("exposure", s.exposure_us, " us", s.auto_exposure), part("gain", s.gain, "", s.auto_gain),
                      f"white balance {'auto ' if s.auto_white_balance else ''}{wb}"])
    if s.sensor_temperature_c is not None:
        text += f", sensor {s.sensor_temperature_c:.1f} C"
    return text + ("; locked" if s.locked else "; NOT locked" + (": " + "; ".join(s.problems) if s.problems else ""))
