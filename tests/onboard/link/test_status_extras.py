"""STATUS carries the robot's state as packet extras, which hold at most MAX_EXTRAS keys: the
fullest status the robot can say must fit, or its last fields would be dropped unsaid."""
from onboard.link.status import flat
from radio.packets.base import MAX_EXTRAS


def test_the_fullest_status_fits_the_packet_extras():
    full = {
        "mode": "sweeping", "outbox": 3, "paused": "disk low", "disk": "low", "disk_free": 1 << 20,
        "rejected": {"stale": 2, "tag": 1},
        "sweep": {"id": 4, "next": 2, "poses": 10, "plan": {"start": 90, "stop": 30, "step": 10},
                  "skipped": [(1, 80.0, 0.0, "servo timeout")]},
        "failsafe": [{"since": 1.7e9, "until": 1.7e9 + 5.0}], "failsafe_s": 5.0, "torque": True,
        "faults": ["servo 1: overload"], "errors": ["OSError: disk full"],
    }
    extras = flat(full)
    assert len(extras) <= MAX_EXTRAS, sorted(extras)
    assert {"faults", "errors", "disk", "rejected", "plan", "torque"} <= set(extras)
