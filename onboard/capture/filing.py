"""Filing captures: each gets a sequence number that never repeats across restarts, and the
packets that carry it (MASK when its label map changed, UNCHANGED when its models did not
move since the last MODELS at that pose, else MODELS); the state they commit with is
returned to the caller, who commits packets and state in one outbox transaction."""
from __future__ import annotations

import dataclasses
import json
import logging
import time
from pathlib import Path
from typing import Any, Callable

import numpy as np

from btf.fit.features import PcaBasis
from onboard.capture import skip
from onboard.capture.pipeline import FittedView, PoseTiming, remember
from onboard.link import bodies as wire
from onboard.link.outbox import Outbox
from onboard.state import RuntimeState
from radio import packets as pk

log = logging.getLogger("btf.robot")
PCA_KEY = "pca"  # the scene's basis, in the outbox state with the packet that carries it
SPACE_KEY = "space_auto"  # the space `features.space = "auto"` chose, kept the same way


class Captures:
    def __init__(self, state: RuntimeState, outbox: Outbox, wall: Callable[[], float]) -> None:
        self.state, self.wall = state, wall
        self.seq = wire.SeqCounter(outbox, legacy=state.cfg.state_dir / "seq")
        self.last_labels: np.ndarray | None = None
        self.last_small: np.ndarray | None = None  # the last labels as MASK pools them, when known
        self.last_models: dict[tuple[int, int], int] = {}  # pose -> seq of its last MODELS
        self.last_timing: PoseTiming | None = None  # the last pose's compute by step, encode included

    @property
    def last_seq(self) -> int | None:
        return self.seq.last

    def packets(self, cap: FittedView) -> tuple[int, list[tuple[int, bytes]], dict[str, str]]:
        """(seq, the packets of one capture, the state entries to commit with them)."""
        cfg = self.state.cfg
        seq = self.seq.peek()
        state = self.seq.entry(seq)
        if cap.pca is not None:  # the scene's basis survives restarts with the packet carrying it
            state[PCA_KEY] = json.dumps(cap.pca.to_record())
        if cap.space_choice is not None:  # and the scene's automatic space, so a restart keeps it
            state[SPACE_KEY] = json.dumps({"space": cap.space, "reason": cap.space_choice})
        t0 = time.perf_counter()
        packets = []
        if cap.mask_changed:
            packets.append(wire.mask_body(cfg.robot_id, seq, cap.labels, cap.small))
        ref = self.last_models.get(skip.pose_key(cap.commanded))
        if cap.unchanged and ref is not None:
            packets.append(wire.unchanged_body(cfg.robot_id, seq, ref, self.wall(), cap))
        else:
            body, left_out = wire.fitting_models_body(cfg.robot_id, seq, self.wall(), cap.space or cfg.features.space,
                                                     cap)
            packets.append(body)
            if left_out:
                self._left_out(seq, cap, left_out)
        timing = self.last_timing = dataclasses.replace(cap.timing, encode=time.perf_counter() - t0)
        steps = ", ".join(f"{k} {getattr(timing, k) * 1e3:.1f}" for k in PoseTiming.STEPS)
        log.info("capture %d compute: %s; total %.1f ms", seq, steps, timing.total * 1e3,
                 extra={"fields": {"capture": seq, **timing.milliseconds()}})
        return seq, packets, state

    def _left_out(self, seq: int, cap: FittedView, labels: tuple[int, ...]) -> None:
        """Say which regions a capture's MODELS left out to fit the link's largest message."""
        n = len({label for label, _ in cap.results})
        shown = ", ".join(str(x) for x in labels[:12]) + (", ..." if len(labels) > 12 else "")
        text = (f"capture {seq}: the {len(labels)} smallest of its {n} regions left out (labels {shown}): all "
                f"{n} regions' models exceed the link's largest message, {pk.MAX_BODY} bytes; fewer "
                "segment.n_labels or features.bands keep every region")
        self.state.errors.append(text)
        log.warning("%s", text)

    def filed(self, cap: FittedView, seq: int) -> None:
        """`cap` was committed under `seq`."""
        self.seq.taken(seq)
        self.state.pose = cap.measured
        self.last_labels, self.last_small = cap.labels, cap.small
        key = skip.pose_key(cap.commanded)
        if not (cap.unchanged and key in self.last_models):
            remember(self.last_models, key, seq)

    def mask_packet(self, seq: int | None) -> tuple[int, bytes] | None:
        """The last label map as a MASK under `seq` (default: the last capture's); None before any."""
        if self.last_labels is None:
            return None
        return wire.mask_body(self.state.cfg.robot_id, int((self.seq.last or 0) if seq is None else seq),
                              self.last_labels, self.last_small)


def read_pca(text: str | None, legacy: Path) -> Any:
    """The scene's PCA basis saved before a restart (None if none or unreadable: refit)."""
    try:
        if text is None and legacy.exists():
            text = legacy.read_text()  # where the basis lived before it moved into the outbox
        return None if text is None else PcaBasis.from_record(json.loads(text))
    except (OSError, ValueError, TypeError, AttributeError, KeyError):
        return None


def read_space(text: str | None) -> tuple[str, str] | None:
    """(space, reason) the scene chose automatically before a restart (None: choose again)."""
    try:
        record = json.loads(text) if text is not None else None
        if record is None or record["space"] not in ("rgb", "hsv", "gray", "pca"):
            return None
        return str(record["space"]), str(record["reason"])
    except (ValueError, TypeError, KeyError):
        return None
