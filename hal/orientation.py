"""Rotations for the tracker on the camera: Euler angles, the camera's frame, mountings.

World axes: x east, y north, z up. An orientation (heading, roll, pitch) in degrees is the
rotation R = Rz(-heading) · Ry(roll) · Rx(pitch) whose columns are the device's axes in
the world (BNO055 Android-style ranges: heading 0..360 clockwise from north, roll ±90,
pitch ±180, so pitch −90 is no singularity). The tracker sits on the camera so that
looking straight down reads pitch −90: the camera's own frame at view (elevation,
azimuth) is Rz(-azimuth) · Rx(-elevation). A mounting M holds the chip's axes in the
camera's frame; an axis remap P (hal.bno055.AxisRemap) turns the chip's axes into the
ones the fusion reports: the reported frame is C · M · Pᵀ, right when P = M.
"""
from __future__ import annotations

import itertools
import math

import numpy as np

from hal.interfaces import Orientation, ViewAngles


def rot_x(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(deg: float) -> np.ndarray:
    c, s = math.cos(math.radians(deg)), math.sin(math.radians(deg))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def euler_matrix(o: Orientation) -> np.ndarray:
    return rot_z(-o.heading) @ rot_y(o.roll) @ rot_x(o.pitch)


def euler_angles(r: np.ndarray) -> Orientation:
    """The orientation of rotation `r` (the inverse of `euler_matrix`, roll kept in ±90)."""
    roll = math.degrees(math.asin(float(np.clip(-r[2, 0], -1.0, 1.0))))
    pitch = math.degrees(math.atan2(r[2, 1], r[2, 2]))
    heading = math.degrees(math.atan2(-r[1, 0], r[0, 0])) % 360.0
    return Orientation(heading=heading, roll=roll, pitch=pitch)


def camera_frame(view: ViewAngles) -> np.ndarray:
    return rot_z(-view.azimuth) @ rot_x(-view.elevation)


def up_in_device(o: Orientation) -> np.ndarray:
    """The world's up direction in the reporting device's axes: what its accelerometer feels.
    It needs roll and pitch only, so a compass that is off does not matter."""
    return euler_matrix(o)[2]


def up_in_camera(elevation: float) -> np.ndarray:
    """Up in the camera's frame at this elevation, whatever the azimuth."""
    return camera_frame(ViewAngles(elevation, 0.0))[2]


def _axis_rotations() -> tuple[np.ndarray, ...]:
    out = []
    for perm in itertools.permutations(range(3)):
        for signs in itertools.product((1.0, -1.0), repeat=3):
            m = np.zeros((3, 3))
            for row, (col, sign) in enumerate(zip(perm, signs)):
                m[row, col] = sign
            if np.linalg.det(m) > 0:
                out.append(m)
    return tuple(out)


AXIS_ROTATIONS = _axis_rotations()  # the 24 ways to mount a chip square to the camera

# Mountings of the chip on the camera, named for a person; "upright" is the one the runtime assumes.
MOUNTS: dict[str, np.ndarray] = {
    "upright": np.eye(3),
    "upside_down": rot_x(180.0),  # flipped over: looking straight down reads pitch +90
    "turned_90": rot_z(90.0),
    "turned_180": rot_z(180.0),
    "turned_270": rot_z(-90.0),
    "upside_down_turned_180": rot_y(180.0),
}


def fit_rotation(device: list[np.ndarray], camera: list[np.ndarray]) -> np.ndarray:
    """The rotation Q with device_i ≈ Qᵀ · camera_i (Kabsch, least squares); needs two
    directions that are not parallel."""
    h = sum(np.outer(c, d) for c, d in zip(camera, device))
    u, _, vt = np.linalg.svd(h)
    d = np.sign(np.linalg.det(u @ vt)) or 1.0
    return u @ np.diag([1.0, 1.0, d]) @ vt


def nearest_axis_rotation(q: np.ndarray) -> tuple[np.ndarray, float]:
    """The square mounting nearest rotation `q`, and how far (degrees) `q` is from it."""
    best = max(AXIS_ROTATIONS, key=lambda m: float(np.trace(m.T @ q)))
    cos = (float(np.trace(best.T @ q)) - 1.0) / 2.0
    return best, math.degrees(math.acos(max(-1.0, min(1.0, cos))))
