"""A V4L2 driver as OpenCV's capture sees it, for the camera driver's tests."""
from __future__ import annotations

from collections import deque

import cv2
import numpy as np


class QueueingCapture:
    """A V4L2-like capture: `queued` stale frames wait in the driver's buffers before fresh ones.

    The driver holds at most `granted_buffers` frames. Frames carry their sequence
    number in pixel (0, 0); numbers < 100 are stale.
    """

    def __init__(self, queued: int, granted_buffers: int, grant: tuple[int, int] | None = None,
                 drops: int = 0, fourcc: str | None = None):
        self.queue = deque(range(queued), maxlen=max(granted_buffers, 1))
        self.fresh = 100
        self.granted_buffers = granted_buffers
        self.props: dict[int, float] = {}
        self.calls: list[tuple] = []
        self.grant = grant
        self.drops = drops
        self.fourcc = fourcc
        self.last: int | None = None
        self.released = False

    def isOpened(self):
        return True

    def set(self, prop, value):
        self.calls.append(("set", prop, value))
        self.props[prop] = value
        return True

    def get(self, prop):
        if prop == cv2.CAP_PROP_BUFFERSIZE:
            return self.granted_buffers
        if self.grant and prop == cv2.CAP_PROP_FRAME_WIDTH:
            return self.grant[0]
        if self.grant and prop == cv2.CAP_PROP_FRAME_HEIGHT:
            return self.grant[1]
        if self.fourcc and prop == cv2.CAP_PROP_FOURCC:
            return cv2.VideoWriter_fourcc(*self.fourcc)
        return self.props.get(prop, 0.0)

    def grab(self):
        if self.drops:
            self.drops -= 1
            return False
        if self.queue:
            self.last = self.queue.popleft()
        else:
            self.last, self.fresh = self.fresh, self.fresh + 1
        return True

    def retrieve(self):
        h, w = int(self.get(cv2.CAP_PROP_FRAME_HEIGHT)), int(self.get(cv2.CAP_PROP_FRAME_WIDTH))
        f = np.zeros((h, w, 3), np.uint8)
        f[0, 0, 0] = self.last  # BGR: blue channel
        return True, f

    def release(self):
        self.released = True
