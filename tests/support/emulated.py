"""The robot's real drivers on the emulators, with the emulators at hand: the Dynamixel driver
on the servo chain's pty (`DxlEmulator`) and the BNO055 driver on its register map
(`EmulatedSMBus`), looking at the fake scene, so a test can unplug either mid-sweep."""
from __future__ import annotations

from dataclasses import dataclass

from hal.arm import Arm, ArmCalibration
from hal.bno055 import BNO055Tracker
from hal.devices import Hal
from hal.dynamixel import DynamixelServoBus
from hal.emulators.bno055 import EmulatedSMBus
from hal.emulators.dxl import DxlEmulator
from hal.factory import world_view
from hal.fakes.camera import FakeCamera
from hal.interfaces import Body, Orientation, ViewAngles


@dataclass
class Emulated:
    hal: Hal
    servos: DxlEmulator
    i2c: EmulatedSMBus


def emulated_hal(size: tuple[int, int] = (24, 32), scene: str = "mixed") -> Emulated:
    """Both drivers on their emulators; the camera is the fake scene's (its ground truth too), at
    the view the emulated servos hold. `hal.close()` closes the emulators as well."""
    cal = ArmCalibration()
    servos = DxlEmulator(tuple(cal.servo_ids))
    for sid in cal.servo_ids:  # parked looking straight down, as the factory parks them
        joint = cal.tilt if sid == cal.tilt.servo_id else cal.yaw
        servos.servos[sid].position = 2048.0 + joint.servo_deg(0.0) * 4096.0 / 360.0

    def view() -> ViewAngles:
        return world_view(cal, {sid: servos.position_deg(sid) for sid in cal.servo_ids})

    def orientation() -> Orientation:
        v = view()
        return Orientation(heading=v.azimuth, roll=0.0, pitch=-v.elevation)

    bus = DynamixelServoBus(servos.port, latency_ms=16.0)  # the SDK's own: a busy machine's emulator thread answers in time
    i2c = EmulatedSMBus(orientation_source=orientation)
    camera = FakeCamera(scene, view, size=size)
    camera.open(size[1], size[0])
    hal = Hal(Body.EMULATED, bus, Arm(bus, cal), BNO055Tracker(i2c, sleep=lambda s: None), camera, size,
              (servos.close,), ground_truth=camera)
    return Emulated(hal, servos, i2c)
