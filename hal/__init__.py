"""Hardware seams: servo bus, orientation tracker, camera and arm, each with a real driver,
an emulator beneath the real driver, and a behavioural fake. `hal.Hal` holds one body's
devices (`hal.factory.build_hal` builds it)."""
from hal.devices import Hal
from hal.interfaces import Body, GroundTruth

__all__ = ["Body", "GroundTruth", "Hal"]
