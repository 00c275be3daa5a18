"""Hardware seams: servo bus, orientation tracker, camera and arm, each with a real driver,
an emulator beneath the real driver, and a behavioural fake. `hal.Hal` holds one body's
devices (`hal.factory.build_hal` builds it)."""
from __future__ import annotations

from typing import Any

__all__ = ["Body", "GroundTruth", "Hal"]


def __getattr__(name: str) -> Any:
    if name == "Hal":
        from hal.devices import Hal  # on first use: a host command reading image files skips the devices
        return Hal
    if name in ("Body", "GroundTruth"):
        from hal import interfaces  # on first use, as Hal
        return getattr(interfaces, name)
    raise AttributeError(f"module 'hal' has no attribute {name!r}")
