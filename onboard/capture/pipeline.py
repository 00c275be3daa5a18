"""One pose, end to end: move, settle, read the tracker, capture, features, segment, fit.

The result is a `FittedView`; `onboard.link.bodies` turns it into the bodies sent.

The measured view (from the tracker) is what a capture is filed under. Each device
step gets bounded retries; when they run out the pose is skipped with a reason
(`PoseSkipped`) and the caller records it. The fitter is preallocated once and reset
per capture, so memory does not grow with the mission.

Given a `pump` (the runtime's link service), the pipeline keeps the link serviced while the
arm works: between polls of a moving arm, and while a camera frame or its processing, which
take longer the larger the frame, runs in a worker thread. So the failsafe holds the arm
within `link.failsafe_s` of the base falling silent at any frame size. Only the calling thread
touches the link, the arm and the runtime's state; the worker touches the camera and numbers
(a step the worker runs calls the pump not at all, and runs its own frames inline).
"""
from __future__ import annotations

import concurrent.futures
import dataclasses
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, ClassVar, NamedTuple, TypeVar

import numpy as np

from btf.capture_settings import CaptureSettings
from btf.dependence import Dependence
from btf.fit import bracketing, dependence
from btf.fit.features import FeatureFrame, FeatureSpace, FeatureSpec, PcaBasis, compute
from btf.fit.fitter import FrameFitter
from btf.record import FittedModel
from hal.devices import Hal
from hal.interfaces import CameraSettings, DeviceGone, DeviceSpent, HalError, ViewAngles, view_from_orientation
from onboard.capture import skip, space_auto
from onboard.capture.camera_lock import CameraLock, reference_level
from onboard.config import Config
from radio.packets.schema import Recent

T = TypeVar("T")
MAX_POSES_REMEMBERED = 512  # previous models kept per pose for the UNCHANGED rule
PUMP_S = 0.01  # how often the link is serviced while a step runs in the worker


@dataclass(frozen=True, slots=True)
class PoseTiming:
    """One pose's compute by step, seconds: features, segmentation, fit (the skip rules, the
    fit, the camera record and any brackets), dependence, encode (its packet bodies)."""

    features: float = 0.0
    segmentation: float = 0.0
    fit: float = 0.0
    dependence: float = 0.0
    encode: float = 0.0

    STEPS: ClassVar[tuple[str, ...]] = ("features", "segmentation", "fit", "dependence", "encode")

    @property
    def total(self) -> float:
        return self.features + self.segmentation + self.fit + self.dependence + self.encode

    def milliseconds(self) -> dict[str, float]:
        """Each step and the total in ms, to 0.1 ms (the robot's log line)."""
        return {**{f"{k}_ms": round(getattr(self, k) * 1e3, 1) for k in self.STEPS},
                "total_ms": round(self.total * 1e3, 1)}


class Segmented(NamedTuple):
    """A frame's labels as the segmentation step gives them (a plain (labels, changed) pair
    also does): `small` the MASK packet's map of them and `counts` each label's pixels, when
    the step already counted them (else the pipeline does)."""

    labels: np.ndarray
    changed: bool
    small: np.ndarray | None = None
    counts: np.ndarray | None = None


class PoseSkipped(Exception):
    """A pose could not be measured after its retries; `reason` says which step failed, `fault`
    whether a device did (then the sweep tries the pose again after its plan)."""

    def __init__(self, reason: str, fault: bool = False) -> None:
        super().__init__(reason)
        self.reason, self.fault = reason, fault


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
    # each region's observed levels, and its grain and band correlation when configured
    dependence: dict[int, Dependence] | None = None
    camera: CaptureSettings | None = None  # what it was taken with (None: a frame from elsewhere)
    small: np.ndarray | None = field(default=None, repr=False)  # `labels` as MASK pools them, when known
    timing: PoseTiming = PoseTiming()  # its compute by step (encode: filled where it is encoded)
    space: str = ""  # the feature space fitted ("": the configured one)
    space_choice: str | None = None  # why, on the first capture of a scene that chose it automatically


def feature_spec(cfg: Config) -> FeatureSpec | None:
    """Only the bands the config asks for are ever computed; None for `auto` (resolved from the
    scene's first frame)."""
    if cfg.features.space == "auto":
        return None
    return FeatureSpec(FeatureSpace(cfg.features.space), cfg.features.bands or None, raw_names(cfg))


def raw_names(cfg: Config) -> tuple[str, ...] | None:
    """The camera's band names for space raw (None: B0..Bn-1)."""
    return cfg.features.band_names or None


class Pipeline:
    """Per-pose capture on a HAL record (`arm`, `tracker`, `camera`) with retries."""

    def __init__(
        self,
        cfg: Config | Callable[[], Config],
        hal: Hal,
        segmenter: Callable[[FeatureFrame, np.ndarray, ViewAngles], tuple],
        pump: Callable[[], None] | None = None,
        sleep: Callable[[float], None] = time.sleep,
        resend_mask: Callable[[], None] = lambda: None,
    ) -> None:
        # The configuration in force is the runtime's (a SET replaces it): read, never copied.
        self._config = cfg if callable(cfg) else (lambda: cfg)
        cfg = self._config()
        self.hal = hal
        self.segmenter = segmenter
        self.resend_mask = resend_mask  # the next capture sends its label map (after a rollback)
        self._service = pump  # keeps the link serviced while the arm works
        self._worker = (None if pump is None else
                        concurrent.futures.ThreadPoolExecutor(1, thread_name_prefix="pose-step"))
        self._here = threading.local()  # `in_worker`: this thread is the worker
        self.sleep = sleep
        self.spec = feature_spec(cfg)
        self.pca: PcaBasis | None = None
        self.pca_pending = False  # fitted, not yet attached to a capture
        self.space_choice: str | None = None  # features.space auto: why the scene's space was chosen
        self.choice_pending = False  # resolved, not yet attached to a capture
        self._fitter: FrameFitter | None = None
        self._previous: dict[tuple[int, int], dict[tuple[int, int], FittedModel]] = {}
        self.faults: Recent = Recent(32)  # every retried fault, for STATUS
        self.lock = CameraLock(hal.camera, cfg.camera) if hal is not None else None

    def keep_space(self, chosen: tuple[str, str] | None) -> None:
        """The scene's automatic space, as chosen before a restart (None: choose from the next frame)."""
        if chosen is not None:
            space = FeatureSpace(chosen[0])
            names = raw_names(self.cfg) if space is FeatureSpace.RAW else None
            self.spec, self.space_choice = FeatureSpec(space, names=names), chosen[1]

    @property
    def cfg(self) -> Config:
        return self._config()

    # -- device steps ------------------------------------------------------------------

    def pump(self) -> None:
        """Service the link, from the calling thread only (the worker leaves it alone)."""
        if self._service is not None and not getattr(self._here, "in_worker", False):
            self._service()

    def pumping(self, step: Callable[[], T], undo: Callable[[T], None] | None = None) -> T:
        """`step()` in the worker while this thread services the link every PUMP_S. When the
        pump raises (an interrupt: the failsafe, ABORT), the step is waited for and its result
        undone, then the interrupt goes on up. Without a pump, or in the worker, `step()` here."""
        if self._worker is None or getattr(self._here, "in_worker", False):
            return step()

        def in_worker() -> T:
            self._here.in_worker = True
            try:
                return step()
            finally:
                self._here.in_worker = False

        future = self._worker.submit(in_worker)
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
        last, spent = "", False
        for attempt in range(attempts):
            try:
                return fn()
            except DeviceGone as exc:  # not there: no retry helps now (the sweep waits for it)
                raise DeviceGone(f"{step}: {exc}") from exc
            except (HalError, OSError, TimeoutError, ValueError) as exc:
                last, spent = f"{type(exc).__name__}: {exc}", isinstance(exc, DeviceSpent)
                self.faults.append(f"{step}: {last}")
                self.pump()
        raise PoseSkipped(f"{step} failed after {attempts} attempts: {last}", fault=not spent)

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
                                  f"{self.cfg.sweep.settle_timeout_s:.1f} s", fault=True)
            self.pump()
            self.sleep(0.005)
        reached = self.retry("positions", lambda: bus.positions(ids))
        tol = arm.joints.tolerance_deg
        for sid, goal in goals.items():
            if abs(reached[sid] - goal) > tol:
                raise PoseSkipped(f"move: servo {sid} stopped at {reached[sid]:.1f}°, short of {goal:.1f}°",
                                  fault=True)

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

    def lock_camera(self) -> CameraSettings:
        """Apply `[camera]` to the camera (at start, and when SET changes it); what it granted."""
        assert self.lock is not None
        return self.retry("camera controls", lambda: self.lock.apply(self.cfg.camera))

    def exposed_frame(self) -> tuple[np.ndarray, CameraSettings]:
        """A frame and the settings the camera reports for it; PoseSkipped when the camera does
        not hold its lock and `[camera] allow_auto` is false."""
        assert self.lock is not None
        if self.lock.asked is None or self.lock.applied != self.cfg.camera:
            self.lock_camera()
        why = self.lock.refusal()  # known before the frame: do not take it
        if why:
            raise PoseSkipped(why)
        frame = self.frame()
        now = self.retry("camera settings", self.hal.camera.settings)
        why = self.lock.refusal(now)  # the camera let go of the lock while taking it
        if why:
            raise PoseSkipped(why)
        return frame, now

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

    def fit_frame(self, data: np.ndarray, labels: np.ndarray, levels: int,
                  stride: int) -> dict[tuple[int, int], FittedModel]:
        """Every region of one frame's feature bands fitted, on the subsample lattice `stride`."""
        fitter = self.fitter(data.shape[2], levels)
        fitter.reset()
        if stride > 1:
            # A deterministic lattice: every stride-th pixel in row-major order.
            flat_d = data.reshape(-1, data.shape[2])[::stride]
            flat_l = labels.reshape(-1)[::stride]
            fitter.add(flat_d[:, None, :], flat_l[:, None])
        else:
            fitter.add(data, labels)
        return fitter.fit(min_count=max(1, self.cfg.skip.min_pixels // stride))

    def shoot(self, commanded: ViewAngles, measured: ViewAngles) -> FittedView:
        """Capture at the pose the arm holds and process it, with the camera's settings, the
        reference's level and, where a region clips past `[camera] bracket_limit`, brackets."""
        frame, now = self.exposed_frame()
        return self.process(frame, commanded, measured, now)

    def process(self, frame: np.ndarray, commanded: ViewAngles, measured: ViewAngles,
                settings: CameraSettings | None = None) -> FittedView:
        """Features, segmentation, skip rules and the fit for one frame (taken with `settings`),
        in the worker, the link serviced meanwhile."""
        return self.pumping(lambda: self._process(frame, commanded, measured, settings), undo=self.rollback)

    def _process(self, frame: np.ndarray, commanded: ViewAngles, measured: ViewAngles,
                 settings: CameraSettings | None) -> FittedView:
        cfg = self.cfg  # a SET while this runs applies from the next frame
        clock = time.perf_counter
        t0 = clock()
        try:
            if self.spec is None:  # features.space auto: once per scene, from its first frame
                self.spec, choice = space_auto.resolve(frame, cfg.segment.k, names=raw_names(cfg))
                self.space_choice, self.choice_pending = choice.reason[:space_auto.MAX_REASON], True
            if self.spec.space is FeatureSpace.PCA and self.pca is None:
                self.pca = PcaBasis.fit(frame)  # once per scene; sent with the scene
                self.pca_pending = True
            feats = compute(frame, self.spec, self.pca)
        except ValueError as exc:  # e.g. a band the camera does not have: skip with the reason
            raise PoseSkipped(f"features: {exc}") from None
        t1 = clock()
        seg = Segmented(*self.segmenter(feats, frame, measured))
        labels, changed = seg.labels, seg.changed
        t2 = clock()
        n_labels = cfg.segment.n_labels
        counts = skip.label_counts(labels, n_labels) if seg.counts is None else seg.counts[:n_labels]
        keep = skip.kept_labels(counts, cfg.skip.min_pixels)
        data = feats.data
        stride = skip.subsample_stride(counts, keep, cfg.skip.percentile_precision, data.shape[1])
        results = {k: r for k, r in self.fit_frame(data, labels, feats.levels, stride).items() if k[0] in keep}
        fitter = self.fitter(data.shape[2], feats.levels)  # its histograms give each region's levels
        seen = dependence.observed(fitter.counts, fitter.centre0, fitter.bin_width, feats.levels)
        primary, camera = results, None  # `primary`: the models of this frame's own pixels
        if settings is not None and self.lock is not None:
            camera = self.settings_record(settings, data, labels, feats.levels)
            if cfg.camera.bracket_limit and settings.locked:
                results, camera = self.bracket(results, camera, labels, stride, feats.levels)
        dropped = tuple(int(i) for i in np.flatnonzero((counts > 0) & (counts < cfg.skip.min_pixels)))
        key = skip.pose_key(commanded)
        same = skip.unchanged(self._previous.get(key), results, cfg.skip.unchanged_tolerance)
        if not same:  # compare with the last models sent, so slow drift is still caught
            remember(self._previous, key, results)
        pca = self.pca if self.pca_pending else None
        self.pca_pending = False
        chosen = self.space_choice if self.choice_pending else None
        self.choice_pending = False
        t3 = clock()
        dep = None
        if cfg.features.dependence and results and not same:  # a bounded second pass
            dep = dependence.measure(data, labels, {k: r.model for k, r in primary.items()}, feats.levels,
                                     levels_seen=seen)
        elif results and not same:  # the levels each region took: free, and what synthesis keeps to
            dep = {lab: Dependence.observed(*seen[lab]) for lab in {lab for lab, _ in results} if lab in seen}
        timing = PoseTiming(t1 - t0, t2 - t1, t3 - t2, clock() - t3)
        return FittedView(commanded, measured, feats.band_names, feats.levels, results, dropped,
                          labels, changed, same, stride, pca, dep, camera, seg.small, timing,
                          self.spec.space.value, chosen)

    def bracket(self, results: dict[tuple[int, int], FittedModel], camera: CaptureSettings, labels: np.ndarray,
                stride: int, levels: int) -> tuple[dict[tuple[int, int], FittedModel], CaptureSettings]:
        """`btf.fit.bracketing` at this pose: shorter frames fitted with this frame's labels."""
        assert self.lock is not None
        lock, c = self.lock, self.cfg.camera

        def take(exposure_us: float) -> tuple[dict[tuple[int, int], FittedModel], float] | None:
            try:
                granted = self.retry("camera controls", lambda: lock.set_exposure(exposure_us))
                frame = self.frame()
                now = self.retry("camera settings", self.hal.camera.settings)
            except PoseSkipped:
                return None  # a bracket frame that failed: the first frame's fits stand
            if not (granted.locked and now.locked) or now.exposure_us is None:
                return None  # a camera that will not hold a shorter exposure
            feats = compute(frame, self.spec, self.pca)
            return self.fit_frame(feats.data, labels, feats.levels, stride), now.exposure_us

        try:
            return bracketing.bracket(results, camera, levels, c.bracket_limit, c.bracket_max, c.bracket_min_ratio, take)
        finally:
            lock.restore()

    def settings_record(self, settings: CameraSettings, data: np.ndarray, labels: np.ndarray,
                        levels: int) -> CaptureSettings:
        """The capture's settings, with the reference region's level when one is declared."""
        assert self.lock is not None
        record = self.lock.record(settings)
        ref = self.cfg.camera.reference_label
        found = reference_level(data, labels, ref, levels) if ref >= 0 else None
        if found is None:
            return record
        return dataclasses.replace(record, reference=found[0], reference_clipped=found[1])

    def rollback(self, cap: FittedView) -> None:
        """`cap` could not be queued: the next capture carries what it would have sent."""
        if cap.pca is not None:
            self.pca_pending = True
        if cap.space_choice is not None:
            self.choice_pending = True
        if cap.mask_changed:
            self.resend_mask()
        self._previous.pop(skip.pose_key(cap.commanded), None)  # next one sends full MODELS

    def capture(self, commanded: ViewAngles, move: bool = True) -> FittedView:
        if move:
            self.move(commanded)
        return self.shoot(commanded, self.measure_view())


def remember(table: dict, key: Any, value: Any, limit: int = MAX_POSES_REMEMBERED) -> None:
    """Set `table[key]`, forgetting the least recently set key past `limit` (GOTO and
    CAPTURE reach any pose, so a long mission must not grow the table without bound)."""
    table.pop(key, None)
    table[key] = value
    while len(table) > limit:
        del table[next(iter(table))]
