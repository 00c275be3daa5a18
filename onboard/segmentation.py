"""Labels per frame for the configured `segment.method`, with the palette persisted."""
from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

from hal.interfaces import Hal, ViewAngles
from onboard.capture import PoseSkipped
from onboard.config import Config, ConfigError


def _write_json(path: Path, record: dict) -> None:
    tmp = path.with_suffix(".tmp")
    with open(tmp, "w", encoding="utf-8") as f:
        f.write(json.dumps(record))
        f.flush()
        os.fsync(f.fileno())  # a power cut must not leave a torn palette behind the rename
    os.replace(tmp, path)


class Segmentation:
    """Labels per frame for `segment.method`, through `onboard.segment`.

    isodata: a `Segmenter` with centres fitted once per scene and a palette of clutter
    types persisted in `state_dir/palette.json`, so labels mean the same across views and
    restarts; a palette saved for other feature bands is not reused (its entries would be
    colours of another space). mask: the label file, read at start. scene: the fake camera's own mask of
    the frame it rendered (the HAL's `ground_truth` capability; a HAL without it is a config
    error). `changed` comes from the Segmenter in every case.
    """

    def __init__(self, cfg: Config, hal: Hal | None = None) -> None:
        from onboard import segment as sg_mod
        from onboard.isodata import IsodataParams

        self.cfg = cfg
        sg = cfg.segment
        self.truth = None if hal is None else hal.ground_truth
        if sg.method == "scene" and self.truth is None:
            raise ConfigError("segment.method = 'scene' needs ground truth, which only the fake camera has "
                              "(hal.body = 'fake')")
        self.palette_path = cfg.state_dir / "palette.json"
        self.features = f"{cfg.features.space}:{','.join(cfg.features.bands)}"
        try:
            params = IsodataParams(k=sg.k, min_samples=sg.min_samples, split_std=sg.split_std,
                                   merge_distance=sg.merge_distance, max_merges=sg.max_merges,
                                   iterations=sg.iterations, subsample=sg.subsample, seed=cfg.hal.seed)
            method = sg_mod.SegmentMethod.MASK if sg.method == "mask" else sg_mod.SegmentMethod.ISODATA
            scfg = sg_mod.SegmentConfig(method, mask_path=None if sg.mask is None else str(sg.mask),
                                        n_labels=sg.n_labels, isodata=params,
                                        palette_size=min(sg.n_labels, sg_mod.MAX_LABEL + 1),
                                        refit_drift=sg.refit_drift)
            self.segmenter = sg_mod.Segmenter.from_config(scfg, self._read_palette())
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
        _write_json(self.palette_path, rec)
        self._saved = rec

    def force_send(self) -> None:
        """The next capture sends its label map whether or not it changed."""
        self.segmenter.force_send()

    def __call__(self, feats: Any, frame: Any, measured: ViewAngles) -> tuple[Any, bool]:
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
        return labels, self.segmenter.changed
