"""What each key of the robot's config may hold: the words a choice key takes and the numbers a
numeric key takes, both ends included (each item of a list key): what the robot, its packets and
its devices can use. A value outside is refused as the file is read (`onboard.config`)."""
from __future__ import annotations

from btf.capture_settings import MAX_BRACKETS
from radio.packets.base import INT64, MAX_FRAME_PIXELS, MAX_FRAME_SIDE, UINT32

CHOICES = {"hal.body": ("", "fake", "emulated", "real"), "hal.scene": ("black", "white", "mixed", "field"),
           "features.space": ("rgb", "hsv", "gray", "pca", "raw", "auto"),
           "segment.method": ("isodata", "mask", "scene"), "link.clock": ("rtc", "none")}
DAY = 86400.0
BOUNDS: dict[str, tuple[float, float]] = {
    "robot_id": (0, 0xFFFF), "outbox_quota_bytes": (4096, INT64), "disk_min_free_bytes": (0, INT64),
    "disk_reserve_bytes": (0, INT64),
    "hal.size": (8, MAX_FRAME_SIDE), "hal.fault_rate": (0.0, 1.0), "hal.fault_seed": (0, UINT32),
    "hal.seed": (0, UINT32), "hal.servo_baud": (1, UINT32), "hal.tracker_bus": (0, 0xFFFF),
    "link.baud": (1, UINT32), "link.node_id": (0, 255), "link.peer_id": (0, 255), "link.link_id": (0, 255),
    "link.mtu": (40, 4096), "link.heartbeat_s": (0.01, DAY), "link.failsafe_s": (0.02, DAY),
    "link.window": (1, 1024),
    "sweep.start": (0.0, 90.0), "sweep.stop": (0.0, 90.0), "sweep.step": (0.01, 180.0),
    "sweep.azimuths": (-3600.0, 3600.0), "sweep.settle_timeout_s": (0.001, DAY), "sweep.retries": (0, 100),
    "sweep.pose_tolerance_deg": (0.0, 90.0), "sweep.retry_skipped": (0, 10),
    "features.bins_16bit": (2, 65536),
    "segment.n_labels": (1, 256), "segment.k": (1, 128), "segment.min_samples": (1, MAX_FRAME_PIXELS),
    "segment.split_std": (1e-6, 1e9), "segment.merge_distance": (0.0, 1e9), "segment.max_merges": (0, 256),
    "segment.iterations": (1, 1000), "segment.subsample": (1, MAX_FRAME_PIXELS), "segment.refit_drift": (0.0, 1e9),
    "skip.min_pixels": (1, MAX_FRAME_PIXELS), "skip.unchanged_tolerance": (0.0, 65535.0),
    "camera.reference_label": (-1, 255), "camera.bracket_max": (1, MAX_BRACKETS),
}


def choices_said(dotted: str) -> str:
    """A key's choices as a person reads them: the empty one (unset) said in words."""
    return ", ".join(repr(c) if c else '"" (unset)' for c in CHOICES[dotted])
