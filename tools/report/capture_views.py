"""What a stored capture looks like: its label map, the view synthesized from its models
(independent pixels, and correlated when it carries dependence), the measured frame where the
host has it, and the histograms with the Johnson curves. The static report and the operator's
page both draw captures with these (`tools.report.look` lays them out).

Measured frames are not in the database (the robot sends models, not pixels): `Frames` finds
them where the host can, a fake robot's render (its config names scene, size and seed) or the
image an ingested dataset's capture was fitted from.
"""
from __future__ import annotations

import io
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from hal.fakes.camera import REFERENCE_EXPOSURE_US, REFERENCE_KELVIN, kelvin_gains
from hal.interfaces import ViewAngles
from hal.scene import render
from onboard.config import load
from tools.analysis.level_bins import Grid
from tools.analysis.radiometry import adjusted
from tools.analysis.synth import MissingModels, synthesize
from tools.data.images import ImageError, read_image, stretched_8bit
from tools.station.receiver import mask_key
from tools.store.database import Store, StoredCapture

Measured = Callable[[StoredCapture], "np.ndarray | None"]
DATASET = "dataset:"  # the robot id `ingest` files a dataset's captures under, before its folder


@dataclass
class CaptureViews:
    capture: StoredCapture
    fitted: dict  # (label, band) -> FittedModel, as stored
    images: dict[str, np.ndarray | bytes] = field(default_factory=dict)  # 8-bit views; "histograms": PNG bytes
    no_mask: bool = False  # no label map: nothing synthesized
    problem: str = ""  # why nothing was synthesized (no mask, a label of the mask without models)


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


def shown(cap: StoredCapture, image: np.ndarray) -> bool:
    """Whether a synthesized image of this capture can be shown as a picture (rgb, gray)."""
    return (cap.space == "rgb" and image.shape[2] == 3) or (cap.space == "gray" and image.shape[2] == 1)


def views(store: Store, cap: StoredCapture, rng: np.random.Generator, measured: Measured | None = None,
          histograms: bool = True) -> CaptureViews:
    """Everything drawn of one capture (images as 8-bit arrays, 16-bit ones stretched over the
    levels they occupy, one span for both syntheses)."""
    fitted = store.models(cap.id)
    out = CaptureViews(cap, fitted)
    real = measured(cap) if measured is not None else None
    if real is not None and cap.space == "rgb":
        out.images["measured"] = stretched_8bit(real)
    mask = capture_mask(store, cap)
    # each region at the capture's exposure (a bracketed region's models scaled back)
    models = dict(adjusted({k: m.model for k, m in fitted.items()}, cap.camera))
    if mask is None or not models:
        out.no_mask = mask is None
        out.problem = "No label mask for this capture: nothing to synthesize." if mask is None else ""
        return out
    try:
        syn = synthesize(mask, models, rng, cap.levels)
        deps = store.dependence(cap.id)
        corr = synthesize(mask, models, rng, cap.levels, dependence=deps) if deps else None
    except MissingModels as exc:
        out.problem = str(exc)
        return out
    if shown(cap, syn):
        both = [syn] if corr is None else [syn, corr]
        span = (int(min(a.min() for a in both)), int(max(a.max() for a in both)))
        out.images["independent"] = stretched_8bit(syn, span)
        if corr is not None:
            out.images["correlated"] = stretched_8bit(corr, span)
    if histograms:
        out.images["histograms"] = histogram_png(real if cap.space == "rgb" else None, mask, models,
                                                 cap.band_names, f"{cap.scene} {cap.elevation:.0f}°", cap.levels)
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


def histogram_png(image: np.ndarray | None, mask: np.ndarray, models: dict, bands: tuple[str, ...],
                  title: str, levels: int = 256) -> bytes:
    """One panel per band: the measured histogram of each label (when the frame is known) and
    its Johnson curve, as PNG bytes."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(bands), figsize=(3.2 * len(bands), 2.4), squeeze=False)
    edges = np.arange(257) - 0.5
    for b, name in enumerate(bands):
        ax = axes[0][b]
        for lab in sorted({lab for lab, _ in models}):
            if image is not None and levels <= 256 and image.shape[:2] == mask.shape and (mask == lab).any():
                h = np.bincount(image[..., b][mask == lab], minlength=256) / (mask == lab).sum()
                # one filled step artist: 256 bar patches per label made the report slow
                ax.stairs(h, edges, fill=True, alpha=0.4, label=f"measured {lab}")
            if (lab, b) in models:
                ax.plot(*model_curve(models[(lab, b)], levels), lw=1, label=f"Johnson {lab}")
        ax.set_title(f"{title} {name}", fontsize=8)
        ax.tick_params(labelsize=6)
    axes[0][0].legend(fontsize=5)
    fig.subplots_adjust(left=0.05, right=0.98, bottom=0.12, top=0.88, wspace=0.25)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=80)
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

        hal = load(path).hal  # ConfigError (one line) for a config the robot would refuse
        return cls(hal if hal.body == "fake" else None)

    def __call__(self, cap: StoredCapture) -> np.ndarray | None:
        if cap.robot.startswith(DATASET) and cap.source:
            try:
                return read_image(Path(cap.robot[len(DATASET):]) / cap.source)
            except (ImageError, OSError):
                return None
        if self.fake is not None and cap.space == "rgb" and not cap.robot.startswith(DATASET):
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
