"""The segmentation step: a label per pixel of each frame, and whether the MASK map changed.

`Segmenter` labels feature frames (a mask file, or ISODATA with scene centres and a palette of
clutter types) and says when the map the MASK packet carries has changed. `Segmentation` is
the pipeline's step for the configured `[segment]` section: it builds the Segmenter, persists
the palette in the state directory, and serves the `scene` method.
"""
from __future__ import annotations

import enum
import json
from typing import Any

import numpy as np

from btf.fit.features import FeatureFrame
from btf.fit.isodata import IsodataParams, Labeller, fit_centres, light_gain, nearest_centres, spread, subsample
from hal.devices import Hal
from hal.interfaces import ViewAngles
from hal.state_file import write_state
from onboard.capture.mask_file import load_mask
from onboard.capture.palette import Palette
from onboard.capture.pipeline import PoseSkipped, Segmented
from onboard.config import Config, ConfigError, SegmentConfig
from radio.packets.base import MAX_LABELS
from radio.packets.mask import MAX_SIDE, pool_labels


# A sample row farther than this many times the spread at fitting from every centre is a
# colour the centres were not fitted on.
REACH = 1.5


class SegmentMethod(enum.Enum):
    MASK = "mask"
    ISODATA = "isodata"


class Segmenter:
    """Labels for each feature frame; `changed` says whether a new MASK is due.

    ISODATA centres belong to the scene, not the frame: they are fitted once, matched to
    the palette, and baked into a `Labeller`; later frames are only looked up. A cheap
    drift check on `drift_sample` pixels refits when the centres no longer fit the view,
    with the view's light level allowed for (one gain over all bands: a sweep over one scene
    sees it brighter or darker by view angle and exposure, and that is what a BTF measures,
    not a new scene): when the mean distance to the nearest centre grows past
    (1 + refit_drift) times its value when they were fitted (refit_drift 0: every frame), or
    when more than `scene_change` of the sample moves from one view to the next between
    centres or out of their reach (a new scene's first view; a sweep's next view of the same
    scene moves a little). The mean distance alone misses a new scene whose colours the old
    centres happen to cover about as well as its own would.
    A map is changed when more than `change_fraction` of the MASK map's cells differ
    from the last one sent (`mask_side`: the longest side of that map).
    """

    def __init__(
        self,
        method: SegmentMethod | str,
        *,
        mask_path: str | None = None,
        n_labels: int | None = None,
        mask_colours: tuple[tuple[int, int, int], ...] | None = None,
        isodata: IsodataParams = IsodataParams(),
        palette: Palette | None = None,
        palette_threshold: float = 30.0,
        palette_size: int = 16,
        mask_side: int = MAX_SIDE,
        change_fraction: float = 0.02,
        refit_drift: float = 0.25,
        drift_sample: int = 2000,
        scene_change: float = 0.35,
    ) -> None:
        method = SegmentMethod(method)
        if method is SegmentMethod.MASK and not mask_path:
            raise ValueError("segmentation: method 'mask' needs mask_path")
        if not 1 <= mask_side <= MAX_SIDE:
            raise ValueError(f"segmentation: mask_side must be in 1..{MAX_SIDE}, got {mask_side}")
        if not 0 <= change_fraction <= 1:
            raise ValueError(f"segmentation: change_fraction must be in 0..1, got {change_fraction}")
        if not (np.isfinite(refit_drift) and refit_drift >= 0) or drift_sample < 1:
            raise ValueError("segmentation: refit_drift must be >= 0 and drift_sample >= 1")
        if not 0 < scene_change <= 1:
            raise ValueError(f"segmentation: scene_change must be in (0, 1], got {scene_change}")
        self.method = method
        self.mask_path = mask_path
        self.isodata = isodata
        self.mask_side = mask_side
        self.change_fraction = change_fraction
        self.refit_drift = refit_drift
        self.drift_sample = drift_sample
        self.scene_change = scene_change
        self.changed = False
        self.small: np.ndarray | None = None  # the last map noted, pooled as the MASK packet pools it
        self.counts: np.ndarray | None = None  # its pixels per label 0..255
        self._sent: np.ndarray | None = None
        self.palette: Palette | None = None
        self._mask: np.ndarray | None = None
        self._labeller: Labeller | None = None
        self._fit_spread = 0.0
        self._gain = 1.0  # the last view's light level against the scene's centres
        self._last_shares: np.ndarray | None = None  # the last view's sample by centre, near and far
        self._frames = 0
        self.refits = 0  # how many times centres were fitted (for STATUS and tests)
        if method is SegmentMethod.MASK:
            # read at start so a bad mask file stops the runtime before the first pose
            self._mask = load_mask(mask_path, n_labels, colours=mask_colours)
        else:
            self.palette = palette or Palette(palette_threshold, palette_size)

    @classmethod
    def from_config(cls, sg: SegmentConfig, seed: int = 0, palette_record: dict | None = None) -> "Segmenter":
        """The Segmenter for a `[segment]` section (`scene` labels like isodata's palette would)."""
        params = IsodataParams(k=sg.k, min_samples=sg.min_samples, split_std=sg.split_std,
                               merge_distance=sg.merge_distance, max_merges=sg.max_merges,
                               iterations=sg.iterations, subsample=sg.subsample, seed=seed)
        method = SegmentMethod.MASK if sg.method == "mask" else SegmentMethod.ISODATA
        return cls(method, mask_path=None if sg.mask is None else str(sg.mask), n_labels=sg.n_labels,
                   isodata=params, palette=Palette.from_record(palette_record) if palette_record else None,
                   palette_size=min(sg.n_labels, MAX_LABELS), refit_drift=sg.refit_drift)

    def labels_for(self, frame: FeatureFrame) -> np.ndarray:
        shape = frame.data.shape[:2]
        if self._mask is not None:
            if self._mask.shape != shape:
                raise ValueError(f"mask: {self.mask_path} is {self._mask.shape[1]}x"
                                 f"{self._mask.shape[0]}, the frame is {shape[1]}x{shape[0]}")
            labels = self._mask
        else:
            labels = self._labels_isodata(frame.data)
        self.note(labels)
        return labels

    def new_scene(self) -> None:
        """Forget the scene's centres: the next frame fits them again."""
        self._labeller = None

    def _labels_isodata(self, data: np.ndarray) -> np.ndarray:
        p = self.isodata
        x = data.reshape(-1, data.shape[-1])
        self._frames += 1
        check = subsample(x, self.drift_sample, p.seed + self._frames)
        lab = self._labeller
        if lab is None or lab.bands != x.shape[1] or self.refit_drift == 0 or self._drifted(check, lab.centres):
            centres = fit_centres(subsample(x, p.subsample, p.seed), p)
            lab = self._labeller = Labeller(centres, self.palette.match(centres))
            # One level of slack keeps a near-perfect fit from refitting on noise.
            self._fit_spread = spread(check, centres) + 1.0
            self._last_shares = self._shares(check, centres)[0]
            self._gain = 1.0
            self.refits += 1
        return lab.assign(data)

    def _shares(self, check: np.ndarray, centres: np.ndarray) -> tuple[np.ndarray, float]:
        """The sample's share at each centre, split into rows within reach of it (REACH times
        the spread at fitting) and beyond, where a new scene's colours show; and its spread."""
        nearest, distance = nearest_centres(check, centres)
        beyond = distance > REACH * self._fit_spread
        shares = np.bincount(2 * nearest + beyond, minlength=2 * len(centres)) / len(check)
        return shares, float(distance.mean())

    def _drifted(self, check: np.ndarray, centres: np.ndarray) -> bool:
        """Whether the scene's centres no longer fit the sample, at its own light level, or the
        sample moved among them from the last view as far as a new scene's does."""
        limit = self._fit_spread * (1 + self.refit_drift)
        # The last view's gain is close to this one's: one round from it is enough.
        self._gain = light_gain(check, centres, rounds=1, start=self._gain)
        shares, scaled_spread = self._shares(check / self._gain, centres)
        last, self._last_shares = self._last_shares, shares
        moved = last is not None and 0.5 * float(np.abs(shares - last).sum()) > self.scene_change
        return moved or (scaled_spread > limit and spread(check, centres) > limit)

    def force_send(self) -> None:
        """The next map counts as changed (the host asked for the mask)."""
        self._sent = None

    def note(self, labels: np.ndarray) -> None:
        """Record this frame's label map (from any source) and set `changed`: the map compared
        is the one the MASK packet carries (radio.packets.mask.downsample_labels), pooled in the
        same count that gives each label's pixels (`counts`)."""
        small, self.counts = pool_labels(labels, self.mask_side)
        sent = self._sent
        self.changed = (
            sent is None or sent.shape != small.shape
            or np.count_nonzero(sent != small) > self.change_fraction * small.size
        )
        if self.changed:
            self._sent = small
        self.small = small

    def segmented(self, labels: np.ndarray) -> Segmented:
        """The pipeline's view of the map just noted: the pooled map only when it is the one a
        MASK packet carries (`mask_side` at its most)."""
        return Segmented(labels, self.changed, self.small if self.mask_side == MAX_SIDE else None, self.counts)


class Segmentation:
    """Labels per frame for `segment.method`, through a `Segmenter`.

    isodata: a `Segmenter` with centres fitted once per scene and a palette of clutter
    types persisted in `state_dir/palette.json`, so labels mean the same across views and
    restarts; a palette saved for other feature bands is not reused (its entries would be
    colours of another space). mask: the label file, read at start. scene: the fake camera's own mask of
    the frame it rendered (the HAL's `ground_truth` capability; a HAL without it is a config
    error). `changed` comes from the Segmenter in every case.
    """

    def __init__(self, cfg: Config, hal: Hal | None = None) -> None:
        self.cfg = cfg
        self.truth = None if hal is None else hal.ground_truth
        if cfg.segment.method == "scene" and self.truth is None:
            raise ConfigError("segment.method = 'scene' needs ground truth, which only the fake camera has "
                              "(hal.body = 'fake')")
        self.palette_path = cfg.state_dir / "palette.json"
        self.features = f"{cfg.features.space}:{','.join(cfg.features.bands)}"
        try:
            self.segmenter = Segmenter.from_config(cfg.segment, cfg.hal.seed, self._read_palette())
        except ValueError as exc:
            raise ConfigError(f"segment: {exc}") from None
        self._saved = self._record()

    def _read_palette(self) -> dict | None:
        if self.cfg.segment.method != "isodata" or not self.palette_path.exists():
            return None
        try:
            rec = json.loads(self.palette_path.read_text())
        except (OSError, ValueError) as exc:
            raise ValueError(f"palette file {self.palette_path} is unreadable ({exc}); "
                             "remove it to start a new palette") from None
        if not isinstance(rec, dict):
            raise ValueError(f"palette file {self.palette_path} does not hold a palette record")
        if rec.get("features", self.features) != self.features:
            return None  # made for other bands: a new palette replaces it at the first save
        return rec

    def _record(self) -> dict | None:
        pal = self.segmenter.palette
        return None if pal is None else {**pal.to_record(), "features": self.features}

    def _save_palette(self) -> None:
        rec = self._record()
        if rec is None or rec == self._saved:
            return
        write_state(self.palette_path, rec)
        self._saved = rec

    def force_send(self) -> None:
        """The next capture sends its label map whether or not it changed."""
        self.segmenter.force_send()

    def __call__(self, feats: Any, frame: Any, measured: ViewAngles) -> Segmented:
        method = self.cfg.segment.method
        if method == "scene":
            labels = self.truth.true_labels()
            if labels is None or labels.shape != feats.data.shape[:2]:
                raise PoseSkipped("segment: the camera has no ground-truth mask for this frame")
            self.segmenter.note(labels)
        else:
            try:
                labels = self.segmenter.labels_for(feats)
            except ValueError as exc:
                raise PoseSkipped(f"segment: {exc}") from None
            self._save_palette()
        return self.segmenter.segmented(labels)
