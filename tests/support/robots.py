"""A fake robot's configuration, written once.

`robot_toml(*changes, **top)` is the TOML of a small fake robot (the fake HAL on the mixed
plate at 40 x 60, segmentation by the scene's ground truth, regions of 20 pixels kept), with
each change (a mapping of sections to keys) merged over it: a key's value replaces the
default's, None removes it. `top` holds the keys above the sections (robot_id, state_dir).
LINKED and IDLE are the changes most tests share.
"""
from __future__ import annotations

import json
from typing import Any, Mapping

FAKE_ROBOT: dict[str, dict[str, Any]] = {
    "hal": {"body": "fake", "scene": "mixed", "size": [40, 60]},
    "segment": {"method": "scene"},
    "skip": {"min_pixels": 20},
}
# A robot on a real link: its key beside the config, a quick heartbeat, a failsafe that waits.
LINKED = {"link": {"key_file": "robot.key", "heartbeat_s": 0.2, "failsafe_s": 30}}
# A robot that waits for a SWEEP command instead of sweeping at boot.
IDLE = {"sweep": {"autostart": False}}
# Every pose measured, even one the robot already stands at.
EVERY_POSE = {"skip": {"skip_measured_pose": False}}


def merged(*changes: Mapping[str, Mapping[str, Any] | None]) -> dict[str, dict[str, Any]]:
    """FAKE_ROBOT with `changes` applied in order (a section given as None is removed)."""
    out = {name: dict(keys) for name, keys in FAKE_ROBOT.items()}
    for change in changes:
        for name, keys in change.items():
            if keys is None:
                out.pop(name, None)
                continue
            section = out.setdefault(name, {})
            for key, value in keys.items():
                if value is None:
                    section.pop(key, None)
                else:
                    section[key] = value
    return out


def _value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_value(x) for x in v) + "]"
    if isinstance(v, str):
        return json.dumps(v)  # a TOML basic string is a JSON string
    return repr(v)


def robot_toml(*changes: Mapping[str, Mapping[str, Any] | None], **top: Any) -> str:
    lines = [f"{k} = {_value(v)}" for k, v in top.items()]
    for name, keys in merged(*changes).items():
        lines.append(f"[{name}]")
        lines += [f"{k} = {_value(v)}" for k, v in keys.items()]
    return "\n".join(lines) + "\n"
# The smallest frame the tests use, on the fake HAL's default (black) plate.
SMALL = {"hal": {"size": [24, 32], "scene": None}}
# A sweep from the zenith down in 2 degree steps, at two azimuths.
SWEEP_TWO_AZIMUTHS = {"sweep": {"step": 2.0, "azimuths": [0, 90]}}
