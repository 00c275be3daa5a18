"""One pose, end to end: move, settle, read the tracker, capture, features, segment, fit.

The result is a `FittedView`; `onboard.packet_bodies` turns it into the bodies sent.

The measured view (from the tracker) is what a capture is filed under. Each device
step gets bounded retries; when they run out the pose is skipped with a reason
(`PoseSkipped`) and the caller records it. The fitter is preallocated once and reset
per capture, so memory does not grow with the mission.

Given a `pump` (the runtime's link service), the pipeline keeps the link serviced while the
arm works: between polls of a moving arm, and while a camera frame or its processing, which
take longer the larger the frame, runs in a worker thread. So the failsafe holds the arm
within `link.failsafe_s` of the base falling silent at any frame size. Only this thread
touches the link, the arm and the runtime's state; the worker touches the camera and numbers.
"""
from __future__ import annotations

import concurrent.futures
import time
from dataclasses import dataclass, field
from typing import Any, Callable, TypeVar

import numpy as np

from btf.dependence import Dependence
from btf.record import FittedModel
from hal.interfaces import Hal, HalError, ViewAngles, view_from_orientation
from onboard import dependence, skip
from onboard.config import Config
from onboard.features import FeatureFrame, FeatureSpace, FeatureSpec, PcaBasis, compute
from onboard.fit import FrameFitter

T = TypeVar("T")
MAX_POSES_REMEMBERED = 512  # previous models kept per pose for the UNCHANGED rule
PUMP_S = 0.01  # how often the link is serviced while a step runs in the worker


class PoseSkipped(Exception):
    """A pose could not be measured after its retries; `reason` says which step failed."""

    def __init__(self, reason: str) -> None:
        super().__init__(reason)
        self.reason = reason


@dataclass(frozen=True, slots=True)
class FittedView:
    """The fitted models of one view, ready to encode."""

    commanded: ViewAngles
    measured: ViewAngles
    band_names: tuple[str, ...]
    levels: int
    results: dict[tuple[int, int], FittedModel]
    skipped_labels: tuple[int, ...]
    labels: np.ndarray = field(repr=False)
    mask_changed: bool = False
    unchanged: bool = False
    stride: int = 1
    pca: PcaBasis | None = None  # the scene's basis, on the first capture made with it
    dependence: dict[int, Dependence] | None = None  # grain and band correlation, when configured


def feature_spec(cfg: Config) -> FeatureSpec:
    """Only the bands the config asks for are ever computed."""
    return FeatureSpec(FeatureSpace(cfg.features.space), cfg.features.bands or None)


class Pipeline:
    """Per-pose capture on a HAL record (`arm`, `tracker`, `camera`) with retries."""

    def __init__(
        self,
        cfg: Config,
        hal: Hal,
        segmenter: Callable[[FeatureFrame, np.ndarray, ViewAngles], tuple[np.ndarray, bool]],
        pump: Callable[[], None] | None = None,
        sleep: Callable[[float], None] = time.sleep,
    ) -> None:
        self.cfg = cfg
        self.hal = hal
        self.segmenter = segmenter
        self.pump = pump or (lambda: None)  # keeps the link serviced while the arm works
        self._worker = (None if pump is None else
                        concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="pose-step"))
        self.sleep = sleep
        self.spec = feature_spec(cfg)
        self.pca: PcaBasis | None = None
        self.pca_pending = False  # fitted, not yet attached to a capture
        self._fitter: FrameFitter | None = None
        self._previous: dict[tuple[int, int], dict[tuple[int, int], FittedModel]] = {}
        self.faults: list[str] = []  # every retried fault, for STATUS

    # -- device steps ------------------------------------------------------------------

    def pumping(self, step: Callable[[], T], undo: Callable[[T], None] | None = None) -> T:
        """`step()` in the worker while this thread services the link every PUMP_S. When the
        pump raises (an interrupt: the failsafe, ABORT), the step is waited for and its result
        undone, then the interrupt goes on up. Without a pump, `step()` here."""
        if self._worker is None:
            return step()
        future = self._worker.submit(step)
        try:
            while not concurrent.futures.wait([future], timeout=PUMP_S)[0]:
                self.pump()
        except BaseException:
            concurrent.futures.wait([future])
            if undo is not None and future.exception() is None:
                undo(future.result())
            raise
        return future.result()

    def retry(self, step: str, fn: Callable[[], T]) -> T:
        """`fn()`, tried `sweep.retries` more times on a device fault; PoseSkipped with the last one."""
        attempts = self.cfg.sweep.retries + 1
        last = ""
        for attempt in range(attempts):
            try:
                return fn()
            except (HalError, OSError, TimeoutError, ValueError) as exc:
                last = f"{type(exc).__name__}: {exc}"
                self.faults.append(f"{step}: {last}")
                del self.faults[:-32]
                self.pump()
        raise PoseSkipped(f"{step} failed after {attempts} attempts: {last}")

    def move(self, view: ViewAngles) -> None:
        """Send the goals, then poll until settled; each bus call has its own retries."""
        arm, bus = self.hal.arm, self.hal.servo_bus
        try:
            goals = arm.joints_for(view)
        except HalError as exc:  # outside the limits: retrying cannot help
            raise PoseSkipped(f"move: {exc}") from None
        ids = list(goals)
        self.retry("move", lambda: bus.move(goals))
        deadline = time.monotonic() + self.cfg.sweep.settle_timeout_s
        while self.retry("settle", lambda: bus.is_moving(ids)):
            if time.monotonic() > deadline:
                raise PoseSkipped(f"settle failed: servos {ids} still moving after "
                                  f"{self.cfg.sweep.settle_timeout_s:.1f} s")
            self.pump()
            self.sleep(0.005)
        reached = self.retry("positions", lambda: bus.positions(ids))
        tol = arm.joints.tolerance_deg
        for sid, goal in goals.items():
            if abs(reached[sid] - goal) > tol:
                raise PoseSkipped(f"move: servo {sid} stopped at {reached[sid]:.1f}°, short of {goal:.1f}°")

    def measure_view(self) -> ViewAngles:
        v = self.retry("tracker", lambda: view_from_orientation(self.hal.tracker.orientation()))
        # Tracker noise can read a hair past straight down; a view elevation is at most 90°.
        return ViewAngles(min(90.0, max(-90.0, v.elevation)), v.azimuth % 360.0)

    def frame(self) -> np.ndarray:
        def grab() -> np.ndarray:
            frame = self.hal.camera.capture()
            if not isinstance(frame, np.ndarray) or frame.ndim not in (2, 3) or frame.size == 0:
                raise ValueError(f"camera returned an unusable frame {getattr(frame, 'shape', None)}")
            return frame

        return self.retry("camera", lambda: self.pumping(grab))

    # -- the capture -------------------------------------------------------------------

    def fitter(self, n_bands: int, levels: int = 256) -> FrameFitter:
        """One preallocated fitter; 16-bit bands get `features.bins_16bit` bins tiling the
        spread range [-1/2, 65535.5], the range the MODELS codec uses for 65536 levels."""
        n_labels = self.cfg.segment.n_labels
        bins = 256 if levels <= 256 else self.cfg.features.bins_16bit
        span = None if levels <= 256 else (-0.5, levels - 0.5)
        f = self._fitter
        if f is None or f.counts.shape != (n_labels, n_bands, bins) or (f.lo, f.hi) != (span or (0.0, 255.0)):
            self._fitter = FrameFitter(n_labels, n_bands, bins=bins, value_range=span)
        return self._fitter

    def process(self, frame: np.ndarray, commanded: ViewAngles, measured: ViewAngles) -> FittedView:
        """Features, segmentation, skip rules and the fit for one frame (in the worker, the link
        serviced meanwhile)."""
        return self.pumping(lambda: self._process(frame, commanded, measured), undo=self.rollback)

    def _process(self, frame: np.ndarray, commanded: ViewAngles, measured: ViewAngles) -> FittedView:
        cfg = self.cfg  # a SET while this runs applies from the next frame
        try:
            if self.spec.space is FeatureSpace.PCA and self.pca is None:
                self.pca = PcaBasis.fit(frame)  # once per scene; sent with the scene
                self.pca_pending = True
            feats = compute(frame, self.spec, self.pca)
        except ValueError as exc:  # e.g. a band the camera does not have: skip with the reason
            raise PoseSkipped(f"features: {exc}") from None
        labels, changed = self.segmenter(feats, frame, measured)
        n_labels = cfg.segment.n_labels
        counts = skip.label_counts(labels, n_labels)
        keep = skip.kept_labels(counts, cfg.skip.min_pixels)
        data = feats.data
        stride = skip.subsample_stride(counts, keep, cfg.skip.percentile_precision, data.shape[1])
        fitter = self.fitter(data.shape[2], feats.levels)
        fitter.reset()
        if stride > 1:
            # A deterministic lattice: every stride-th pixel in row-major order.
            flat_d = data.reshape(-1, data.shape[2])[::stride]
            flat_l = labels.reshape(-1)[::stride]
            fitter.add(flat_d[:, None, :], flat_l[:, None])
        else:
            fitter.add(data, labels)
        results = fitter.fit(min_count=max(1, cfg.skip.min_pixels // stride))
        results = {k: r for k, r in results.items() if k[0] in keep}
        dropped = tuple(int(i) for i in np.flatnonzero((counts > 0) & (counts < cfg.skip.min_pixels)))
        key = skip.pose_key(commanded)
        same = skip.unchanged(self._previous.get(key), results, cfg.skip.unchanged_tolerance)
        if not same:  # compare with the last models sent, so slow drift is still caught
            remember(self._previous, key, results)
        pca = self.pca if self.pca_pending else None
        self.pca_pending = False
        dep = None
        if cfg.features.dependence and results and not same:  # a bounded second pass
            dep = dependence.measure(data, labels, {k: r.model for k, r in results.items()}, feats.levels)
        return FittedView(commanded, measured, feats.band_names, feats.levels, results, dropped,
                       labels, changed, same, stride, pca, dep)

    def rollback(self, cap: FittedView) -> None:
        """`cap` could not be queued: the next capture carries what it would have sent."""
        if cap.pca is not None:
            self.pca_pending = True
        if cap.mask_changed:
            getattr(self.segmenter, "force_send", lambda: None)()
        self._previous.pop(skip.pose_key(cap.commanded), None)  # next one sends full MODELS

    def capture(self, commanded: ViewAngles, move: bool = True) -> FittedView:
        if move:
            self.move(commanded)
        measured = self.measure_view()
        frame = self.frame()
        return self.process(frame, commanded, measured)


def remember(table: dict, key: Any, value: Any, limit: int = MAX_POSES_REMEMBERED) -> None:
    """Set `table[key]`, forgetting the least recently set key past `limit` (GOTO and
    CAPTURE reach any pose, so a long mission must not grow the table without bound)."""
    table.pop(key, None)
    table[key] = value
    while len(table) > limit:
        del table[next(iter(table))]
