"""Every packet body the robot sends, as (outbox kind, body), and the capture numbers they carry.

MODELS, UNCHANGED and MASK for a capture (`onboard.capture.pipeline.FittedView`), STATUS, and the
ACK or NACK answering a command. Sequence numbers come from `SeqCounter`, kept in the
outbox database so a restart never reuses one.
"""
from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Any

import numpy as np

from btf.fit import space_choice
from hal.interfaces import ViewAngles
from onboard.capture.pipeline import FittedView
from radio import packets as pk
from radio.packets.base import iso_time  # noqa: F401  (the robot's log lines show times with it)
from radio.packets.commands import fit_answer


class SeqCounter:
    """Capture sequence numbers that never repeat across restarts.

    The next number is a state entry of the outbox database, committed in the same
    transaction as the packets that use it (`entry`), then `taken`: a kill before the
    commit reuses the number for the same pose, a kill after it never reuses it.
    """

    KEY = "next_seq"

    def __init__(self, db: Any, legacy: Path | None = None) -> None:
        text = db.state(self.KEY)
        try:
            if text is None and legacy is not None and legacy.exists():
                text = legacy.read_text()  # the file this counter used to live in
            self._next = max(1, int(text.strip())) if text is not None else 1
        except (OSError, ValueError):
            self._next = int(time.time())  # unreadable: jump ahead rather than reuse
        self.last: int | None = self._next - 1 if self._next > 1 else None

    def peek(self) -> int:
        """The number the next committed capture gets."""
        return self._next

    def entry(self, seq: int) -> dict[str, str]:
        return {self.KEY: str(seq + 1)}

    def taken(self, seq: int) -> None:
        """`seq` was committed with its packets."""
        self._next = max(self._next, seq + 1)
        self.last = seq


def _pose(v: ViewAngles) -> tuple[float, float]:
    return (float(v.elevation), float(v.azimuth))


def models_body(robot_id: int, seq: int, now: float, space: str, cap: FittedView) -> tuple[int, bytes]:
    """MODELS for a capture, with its dependence when measured; the first capture of a PCA
    scene carries the basis in its extras."""
    extras = dict(cap.pca.to_extras()) if cap.pca is not None else {}
    if cap.space_choice is not None:  # the scene's space was chosen automatically: say why, once
        extras[space_choice.EXTRA_KEY] = cap.space_choice
    body = pk.encode_models(cap.results, robot_id=robot_id, seq=seq, time=now,
                            commanded=_pose(cap.commanded), measured=_pose(cap.measured),
                            feature_space=space, bands=cap.band_names, levels=cap.levels,
                            extras=extras, dependence=cap.dependence, camera=cap.camera)
    return int(pk.Kind.MODELS), body


def fitting_models_body(robot_id: int, seq: int, now: float, space: str,
                        cap: FittedView) -> tuple[tuple[int, bytes], tuple[int, ...]]:
    """MODELS for a capture within the link's largest message (`pk.MAX_BODY`), and the regions
    left out to fit: none unless every region's models would not fit (many labels of many 16-bit
    bands), then the fewest, smallest by pixel count first."""
    try:
        return models_body(robot_id, seq, now, space, cap), ()
    except pk.PacketTooLarge:
        pass
    counts: dict[int, int] = {}
    for (label, _), r in cap.results.items():
        counts[label] = int(r.count)
    order = sorted(counts, key=lambda lab: (-counts[lab], lab))  # the largest regions kept first
    best, fits, over = models_body(robot_id, seq, now, space, only_labels(cap, ())), 0, len(order)
    while over - fits > 1:  # the first `fits` regions fit, the first `over` do not
        mid = (fits + over) // 2
        try:
            best, fits = models_body(robot_id, seq, now, space, only_labels(cap, order[:mid])), mid
        except pk.PacketTooLarge:
            over = mid
    return best, tuple(sorted(order[fits:]))


def only_labels(cap: FittedView, labels) -> FittedView:
    """`cap` with the models, dependence and brackets of `labels` only."""
    keep = set(labels)
    camera = cap.camera
    if camera is not None and camera.bracketed:
        camera = dataclasses.replace(camera, bracketed={k: v for k, v in camera.bracketed.items() if k in keep})
    return dataclasses.replace(
        cap, results={k: r for k, r in cap.results.items() if k[0] in keep}, camera=camera,
        dependence=None if cap.dependence is None else {k: d for k, d in cap.dependence.items() if k in keep})


def unchanged_body(robot_id: int, seq: int, ref_seq: int, now: float, cap: FittedView) -> tuple[int, bytes]:
    packet = pk.UnchangedPacket(robot_id, seq, now, _pose(cap.commanded), _pose(cap.measured), ref_seq)
    return int(pk.Kind.UNCHANGED), pk.encode(packet)


def mask_body(robot_id: int, seq: int, labels: np.ndarray, pooled: np.ndarray | None = None) -> tuple[int, bytes]:
    """MASK for a label map; `pooled`: the map the segmentation already pooled from it."""
    return int(pk.Kind.MASK), pk.encode_mask(labels, robot_id=robot_id, seq=seq, pooled=pooled)


def status_body(robot_id: int, now: float, state: pk.RobotState, pose: ViewAngles | None,
                pending: int, used: int, last_seq: int | None, text: str,
                report: pk.StatusReport | None = None) -> tuple[int, bytes]:
    packet = pk.StatusPacket(robot_id, now, state, None if pose is None else _pose(pose),
                             pending, used, last_seq, text, report=report or pk.StatusReport())
    return int(pk.Kind.STATUS), pk.encode(packet)


def reply_body(command_id: int, ok: bool, text: str, answer: dict | pk.StatusReport | None = None,
               reason: pk.Reason = pk.Reason.INTERNAL) -> tuple[int, bytes]:
    """The ACK (text: the command's name; `answer`: its values, or STATUS's report) or the NACK
    of a command. The encoder cuts a long text visibly."""
    if not ok:
        return int(pk.Kind.NACK), pk.encode(pk.NackPacket(command_id, reason, text))
    if isinstance(answer, pk.StatusReport):
        return int(pk.Kind.ACK), pk.encode(pk.AckPacket(command_id, text, status=answer))
    name = pk.CommandName.__members__.get(text)
    values = fit_answer(name, dict(answer or {})) if name is not None else dict(answer or {})
    return int(pk.Kind.ACK), pk.encode(pk.AckPacket(command_id, text, values))
