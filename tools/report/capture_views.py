"""What a stored capture looks like: its label map, the view synthesized from its models
(independent pixels, and correlated when it carries dependence; hsv and pca ones turned back
into RGB, pca through the scene's stored basis, raw bands as false colour of those named red,
green and blue, else of their first three), the measured frame where the host has it, and the
histograms with the Johnson curves. The static report and the operator's page both draw
captures with these (`tools.report.look` lays them out).

Measured frames are not in the database (the robot sends models, not pixels): `Frames` finds
them where the host can, a fake robot's render (its config names scene, size and seed) or the
image an ingested dataset's capture was fitted from. A capture without a label map whose models
are all of region 0 (`ingest` or `fit` without a mask) is drawn as one region over the whole image.
"""
from __future__ import annotations

import io
import math
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from btf.fit.features import BAND_NAMES, FeatureSpace, PcaBasis
from hal.fakes.camera import REFERENCE_EXPOSURE_US, REFERENCE_KELVIN, kelvin_gains
from hal.interfaces import ViewAngles
from hal.scene import render
from onboard.config import load
from tools.analysis.level_bins import Grid
from tools.analysis.radiometry import adjusted
from tools.analysis.synth import MissingModels, ReachWarning, synthesize
from tools.data.images import ImageError, read_image, stretched_8bit, to_rgb, view_rgb
from tools.station.receiver import mask_key
from tools.store.database import Store, StoredCapture

Measured = Callable[[StoredCapture], "np.ndarray | None"]
WHOLE_SIZE = (128, 128)  # a whole-image region's size when its frame is not found
HIST_PANEL_PX = (240, 190)  # one band's histogram panel, drawn at the size the report shows it
HIST_DPI = 100


@dataclass
class CaptureViews:
    capture: StoredCapture
    fitted: dict  # (label, band) -> FittedModel, as stored
    images: dict[str, np.ndarray | bytes] = field(default_factory=dict)  # 8-bit views; "histograms": PNG bytes
    no_mask: bool = False  # no label map: nothing synthesized
    problem: str = ""  # why nothing was synthesized (no mask, a label of the mask without models)
    whole: bool = False  # no label map, models of region 0 alone: the whole image is region 0
    space_choice: str | None = None  # why the feature space was chosen automatically (None: configured)


def capture_mask(store: Store, cap: StoredCapture) -> np.ndarray | None:
    """A capture's label map: the robot's MASK for it, the one `fit --mask` or `ingest --mask`
    stored with it, an ingested dataset's common mask, or the robot's latest MASK before it."""
    for key in (mask_key(cap.sequence, cap.incarnation), f"{cap.robot}/{cap.sequence}", cap.robot):
        m = store.mask(key, cap.robot)
        if m is not None:
            return m
    for seq in range(cap.sequence - 1, -1, -1):
        m = store.mask(mask_key(seq, cap.incarnation), cap.robot)
        if m is not None:
            return m
    return None


def label_map(store: Store, cap: StoredCapture, models: dict,
              frame: np.ndarray | None) -> tuple[np.ndarray | None, bool]:
    """(the capture's label map, whether it is the whole frame): a capture of region 0 alone
    with none stored (an ingest without --mask) is its whole frame, or WHOLE_SIZE without one."""
    mask = capture_mask(store, cap)
    if mask is None and models and {label for label, _ in models} == {0}:
        return np.zeros(frame.shape[:2] if frame is not None else WHOLE_SIZE, np.uint8), True
    return mask, False


def shown(cap: StoredCapture, image: np.ndarray) -> bool:
    """Whether an image of this capture's bands can be shown as a picture (rgb, gray, and raw
    bands as false colour)."""
    return ((cap.space == "rgb" and image.shape[2] == 3) or (cap.space == "gray" and image.shape[2] == 1)
            or (cap.space == "raw" and image.shape[2] == len(cap.band_names)))


def picture(cap: StoredCapture, bands: np.ndarray, basis: PcaBasis | None) -> np.ndarray | None:
    """A synthesis of this capture as a picture to set beside the photograph: rgb and gray as
    drawn, hsv and pca turned back into RGB (pca through the scene's `basis`); None where its
    bands make none (some of a space's bands only, pca without its basis)."""
    if shown(cap, bands):
        return bands
    if cap.space == "hsv" and cap.band_names == BAND_NAMES[FeatureSpace.HSV]:
        return to_rgb(bands, "hsv")
    if cap.space == "pca" and basis is not None and cap.band_names == tuple(f"P{k + 1}" for k in range(basis.n)):
        return to_rgb(bands, "pca", basis)
    return None


def views(store: Store, cap: StoredCapture, rng: np.random.Generator, measured: Measured | None = None,
          histograms: bool = True) -> CaptureViews:
    """Everything drawn of one capture (images as 8-bit arrays, 16-bit ones stretched over the
    levels they occupy, one span for both syntheses)."""
    fitted = store.models(cap.id)
    out = CaptureViews(cap, fitted, space_choice=store.space_choice(cap.id))
    real = measured(cap) if measured is not None else None
    if real is not None and shown(cap, real):
        out.images["measured"] = view_rgb(real, names=cap.band_names) if cap.space == "raw" else stretched_8bit(real)
    # each region at the capture's exposure (a bracketed region's models scaled back)
    models = dict(adjusted({k: m.model for k, m in fitted.items()}, cap.camera))
    mask, out.whole = label_map(store, cap, models, real)
    if mask is None or not models:
        out.no_mask = mask is None
        out.problem = "No label mask for this capture: nothing to synthesize." if mask is None else ""
        return out
    try:
        deps = store.dependence(cap.id)
        with warnings.catch_warnings():  # the report shows what can be drawn; a missed correlation is no error
            warnings.simplefilter("ignore", ReachWarning)
            syn = synthesize(mask, models, rng, cap.levels, dependence=deps, independent=True)
            grain = any(d.measured for d in deps.values())
            corr = synthesize(mask, models, rng, cap.levels, dependence=deps) if grain else None
    except MissingModels as exc:
        out.problem = str(exc)
        return out
    basis = store.pca_basis(cap.id) if cap.space == "pca" else None
    both = [picture(cap, a, basis) for a in ([syn] if corr is None else [syn, corr])]
    if all(a is not None for a in both) and cap.space == "raw":  # each band over its span in both
        over = np.concatenate(both, axis=0)
        for name, image in zip(("independent", "correlated"), both):
            out.images[name] = view_rgb(image, over, cap.band_names)
    elif all(a is not None for a in both):
        span = (int(min(a.min() for a in both)), int(max(a.max() for a in both)))
        for name, image in zip(("independent", "correlated"), both):
            out.images[name] = stretched_8bit(image, span)
    if histograms:
        out.images["histograms"] = histogram_png(real if real is not None and shown(cap, real) else None, mask, models,
                                                 cap.band_names, cap.levels)
    return out


def model_curve(model, levels: int) -> tuple[np.ndarray, np.ndarray]:
    """(x, probability per level) for 8-bit models; deep ones per bin of 256 over their bulk."""
    if levels <= 256:
        return np.arange(levels), model.level_probabilities(levels)
    lo, hi = (int(np.clip(model.ppf(q), 0, levels - 1)) for q in (1e-3, 1 - 1e-3))
    grid = Grid.over(lo, hi, levels)
    bounds = np.concatenate(([lo - 0.5], grid.edges(), [hi + 0.5]))
    per_level = model.interval_probabilities(grid.edges()) / np.diff(bounds)  # bins hold 1 or 2 counts of levels
    # the end bins also hold the folded tails: left out of the curve
    return ((bounds[:-1] + bounds[1:]) / 2)[1:-1], per_level[1:-1]


def level_span(models: dict, band: int, levels: int) -> tuple[float, float]:
    """The levels a band's models put their bulk on (all regions), with a margin: the x range of its panel."""
    ends = [(float(m.ppf(1e-3)), float(m.ppf(1 - 1e-3))) for (_, b), m in models.items() if b == band]
    if not ends:
        return -0.5, levels - 0.5
    lo, hi = min(e[0] for e in ends), max(e[1] for e in ends)
    pad = max(3.0, 0.08 * (hi - lo))
    return max(lo - pad, -0.5), min(hi + pad, levels - 0.5)


def measured_per_level(values: np.ndarray, levels: int, span: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """(share of the pixels per level, bin borders) over the panel's `span`, in the bins a deep
    band's histograms are compared in (`Grid`: every level of an 8-bit band, at most 256 bins of
    whole levels of a deeper one), each bin's share spread over its levels as `model_curve` does."""
    grid = Grid.over(max(0, math.floor(span[0])), min(levels - 1, math.ceil(span[1])), levels)
    top = grid.lo + math.ceil(grid.bins * grid.width)  # one past the last level binned
    bounds = np.concatenate(([grid.lo - 0.5], grid.edges(), [top - 0.5]))
    counts = grid.rebin(np.bincount(values.ravel(), minlength=top))
    return counts / (values.size * np.diff(bounds)), bounds


def histogram_png(image: np.ndarray | None, mask: np.ndarray, models: dict, bands: tuple[str, ...],
                  levels: int = 256) -> bytes:
    """One panel per band over the levels its models cover: the measured histogram of each label
    (when the frame is known) and its Johnson curve in the label's colour, as PNG bytes drawn at
    the size the report shows them (`HIST_PANEL_PX` a panel)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    w, h = HIST_PANEL_PX
    width = w * len(bands)
    fig, axes = plt.subplots(1, len(bands), figsize=(width / HIST_DPI, h / HIST_DPI), squeeze=False)
    # margins in pixels (a layout engine would measure every tick label of every figure)
    axis_w = (width - 72 - 40 * (len(bands) - 1)) / len(bands)
    fig.subplots_adjust(left=64 / width, right=1 - 8 / width, bottom=38 / h, top=1 - 22 / h, wspace=40 / axis_w)
    labels = sorted({lab for lab, _ in models})
    for b, name in enumerate(bands):
        ax = axes[0][b]
        span = level_span(models, b, levels)
        for k, lab in enumerate(labels):
            colour = f"C{k % 10}"
            if image is not None and image.shape[:2] == mask.shape and (mask == lab).any():
                # one filled polygon of steps: 256 bar patches per label made the report slow, and a
                # filled `stairs` patch took 25 ms to find its own limits, point by point
                per_level, edges = measured_per_level(image[..., b][mask == lab], levels, span)
                ax.fill_between(edges, np.append(per_level, per_level[-1]), step="post", alpha=0.35, color=colour,
                                linewidth=0, label=f"measured {lab}")
            if (lab, b) in models:
                ax.plot(*model_curve(models[(lab, b)], levels), lw=1.3, color=colour, label=f"Johnson {lab}")
        ax.set_xlim(*span)
        ax.set_ylim(bottom=0)
        ax.set_title(f"band {name}", fontsize=9)
        ax.set_xlabel("level", fontsize=8)
        ax.tick_params(labelsize=8)
    axes[0][0].set_ylabel("probability", fontsize=8)
    axes[0][0].legend(fontsize=7, framealpha=0.7, handlelength=1.2, borderaxespad=0.3)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=HIST_DPI)
    plt.close(fig)
    return buf.getvalue()


def png(image: np.ndarray | bytes) -> bytes:
    """An 8-bit RGB or single-band view as PNG bytes (PNG bytes pass through)."""
    if isinstance(image, bytes):
        return image
    import cv2

    img = image[:, :, ::-1] if image.ndim == 3 and image.shape[2] == 3 else image.reshape(image.shape[:2])
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(img))
    if not ok:
        raise ImageError("PNG encoding failed")
    return buf.tobytes()


class Frames:
    """The camera frames the host can find: a dataset capture's source image, and, given a fake
    robot's config (`[hal]` scene, size, seed, reference), its render at the capture's view and
    camera settings. `frame(capture)` is None where there is none."""

    def __init__(self, fake: Any | None = None) -> None:
        self.fake = fake  # onboard.config.HalConfig of a fake robot, or None

    @classmethod
    def from_robot_config(cls, path: str | Path | None) -> Frames:
        if path is None:
            return cls()
        return cls(load(path).fake_hal)  # ConfigError (one line) for a config the robot would refuse

    def __call__(self, cap: StoredCapture) -> np.ndarray | None:
        if cap.dataset is not None:
            try:
                return read_image(cap.source_file) if cap.source_file else None
            except (ImageError, OSError):
                return None
        if self.fake is not None and cap.space == "rgb":
            return self._render(cap)
        return None

    def _render(self, cap: StoredCapture) -> np.ndarray:
        c, h = cap.camera, self.fake
        exposure = (c.exposure_us if c and c.exposure_us else REFERENCE_EXPOSURE_US) / REFERENCE_EXPOSURE_US
        gain = c.gain if c and c.gain else 1.0
        wb = (c.white_balance_gains if c and c.white_balance_gains
              else kelvin_gains(c.white_balance_kelvin if c and c.white_balance_kelvin else REFERENCE_KELVIN))
        return render(h.scene, ViewAngles(*cap.measured), tuple(h.size), seed=h.seed, exposure=exposure,
                      gain=gain, white_balance=tuple(wb), reference=h.reference).image
