"""The paper's Table 1 on any photograph: every mask x feature space fitted, synthesized and judged.

For each mask and space the photograph is fitted with the robot's own fitter (as `btf-host fit`),
synthesized independently and with its grain and band correlation (as `btf-host synth`), and
judged by
- Table 1: the correlation per band of each synthesis with the photograph's bands;
- the Table-2 error and the band decorrelation of btf.fit.space_choice (the criterion);
- the exact L1 of the fit: the mean over regions and bands of sum_k |h_k - p_k| between the
  region's histogram and the model's probability of each level (for 8-bit bands the Johnson
  column of `btf-host pdfs`, per level for 16-bit ones);
- the synthesis's texture figures (tools.analysis.grain_metrics) over its regions: the share of
  pixels outside the observed levels, the plaid index (mean), the worst 2-D autocorrelation gap
  and the worst band-correlation gap;
- the MODELS packet's bytes on the wire and the fit's time.
The mask is chosen in the photograph's own space (rgb, or gray for one band) by Table 1, the
space on that mask by btf.fit.space_choice.
"""
from __future__ import annotations

import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from btf.fit import dependence, space_choice
from radio import packets
from tools.analysis import grain_metrics
from tools.analysis.metrics import compare_bands
from tools.analysis.synth import synthesize
from tools.data.images import DEEP_SPACES, default_space, feature_bands, fit_bands

MASK_MARGIN = 0.02  # a mask within this Table-1 correlation of the best and cheaper on the wire wins
MIN_REGION = space_choice.MIN_PIXELS  # regions smaller than this are left out of the texture figures


@dataclass
class SpaceRow:
    mask: str
    space: str
    regions: int
    bands: tuple[str, ...]
    correlation: dict[str, dict[str, float]]  # "independent" / "correlated" -> band -> Table 1
    figures: space_choice.SpaceFigures
    l1: float
    texture: dict[str, float | None]
    wire_bytes: int | None
    fit_seconds: float
    synthesis: np.ndarray = field(repr=False)  # the correlated synthesis, in the feature space
    pca: object = field(default=None, repr=False)
    notes: tuple[str, ...] = ()

    def mean_correlation(self, kind: str = "correlated") -> float:
        values = list(self.correlation[kind].values())
        return float(np.mean(values)) if values else 0.0

    def to_json(self) -> dict:
        f = self.figures
        return {"mask": self.mask, "space": self.space, "regions": self.regions, "bands": list(self.bands),
                "table1": self.correlation, "table2": f.error, "table2_seeds": list(f.table2),
                "table2_noise": f.noise, "exact_l1": self.l1, "decorrelation": f.decorrelation,
                "texture": dict(self.texture), "wire_bytes": self.wire_bytes,
                "fit_ms": round(self.fit_seconds * 1e3, 1), "notes": list(self.notes)}


@dataclass
class Judgement:
    rows: list[SpaceRow]
    mask: str
    space: str
    reason: str

    @property
    def chosen(self) -> SpaceRow:
        return next(r for r in self.rows if r.mask == self.mask and r.space == self.space)

    @property
    def worst(self) -> SpaceRow:
        """The row whose synthesis misses the photograph most: largest Table-2 error."""
        return max(self.rows, key=lambda r: (r.figures.error, -r.mean_correlation()))

    def to_json(self) -> dict:
        return {"rows": [r.to_json() for r in self.rows],
                "choice": {"mask": self.mask, "space": self.space, "reason": self.reason}}


def spaces_of(image: np.ndarray) -> tuple[str, ...]:
    """The feature spaces a photograph offers: gray alone for one band, its own bands alone for
    other than one or three, rgb and gray at 16 bits."""
    if default_space(image) != "rgb":
        return (default_space(image),)
    if image.dtype == np.uint16:
        return tuple(s for s in DEEP_SPACES if s != "raw")  # raw would repeat rgb
    return ("rgb", "hsv", "gray", "pca")


def exact_l1(counts: np.ndarray, models: dict, levels: int) -> float:
    """Mean over the fitted (label, band) of sum_k |h_k - p_k| over every level."""
    errors = []
    for lab, band in sorted(models):
        c = counts[lab, band]
        n = c.sum()
        if n:
            errors.append(float(np.abs(c / n - models[(lab, band)].level_probabilities(levels)).sum()))
    return float(np.mean(errors)) if errors else 0.0


def texture(photo: np.ndarray, synth: np.ndarray, labels: np.ndarray) -> dict[str, float | None]:
    """The synthesis's texture figures over the regions of at least MIN_REGION pixels."""
    outside = total = 0.0
    plaids, acf, band = [], 0.0, 0.0
    for lab in np.unique(labels):
        inside = labels == lab
        n = int(np.count_nonzero(inside))
        if n < MIN_REGION:
            continue
        outside += grain_metrics.outside(photo, synth, inside) * n
        total += n
        p = grain_metrics.plaid(photo, synth, inside)
        if p is not None:
            plaids.append(p)
        acf = max(acf, grain_metrics.acf_gap(photo, synth, inside))
        band = max(band, grain_metrics.band_gap(photo, synth, inside))
    return {"outside": outside / total if total else 0.0, "plaid": float(np.mean(plaids)) if plaids else None,
            "acf_gap": acf, "band_gap": band}


def wire_bytes(fitted, levels: int) -> int | None:
    """The MODELS body's length as the robot would send it (None when it exceeds a link message):
    with the robot's own dependence record (its window and row rule), not the host's larger one."""
    extras = fitted.pca.to_extras() if fitted.pca is not None else None
    robots = None
    if fitted.results:
        seen = {lab: (dep.lo, dep.hi) for lab, dep in fitted.dependence.items() if dep.lo}
        robots = dependence.measure(fitted.feats.data, fitted.labels, {k: r.model for k, r in fitted.results.items()},
                                    fitted.feats.levels, levels_seen=seen)
    try:
        return len(packets.encode_models(fitted.results, robot_id=0, seq=0, time=0.0, commanded=(0.0, 0.0),
                                         measured=(0.0, 0.0), feature_space=fitted.feats.space.value,
                                         bands=fitted.feats.band_names, levels=levels, extras=extras,
                                         dependence=robots))
    except ValueError:
        return None


def _synth(labels: np.ndarray, fitted, levels: int, seed: int, independent: bool) -> tuple[np.ndarray, int]:
    """A synthesis in the feature space, and how many band-correlation warnings it raised."""
    models = {k: r.model for k, r in fitted.results.items()}
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        out = synthesize(labels, models, np.random.default_rng(seed), levels, fitted.dependence, independent)
    if fitted.feats.space.value == "hsv":
        out[..., 0] = np.minimum(out[..., 0], 179)  # hue is 0..179 in OpenCV's 8-bit HSV
    return out, len(said)


def judge_one(image: np.ndarray, mask: str, labels: np.ndarray, space: str, seed: int = 0) -> SpaceRow:
    """One row: fit, synthesize both ways and judge."""
    feats, pca = feature_bands(image, space)
    levels = feats.levels
    t0 = time.perf_counter()
    fitted = fit_bands(feats, pca, labels)
    seconds = time.perf_counter() - t0
    models = {k: r.model for k, r in fitted.results.items()}
    circular = ("H",) if space == "hsv" else ()
    corr, notes = {}, []
    synth = None
    for kind, independent in (("independent", True), ("correlated", False)):
        synth, warned = _synth(labels, fitted, levels, seed, independent)
        if warned:
            notes.append(f"{kind}: a band correlation beyond what the models can reach")
        corr[kind] = dict(compare_bands(feats.data, synth, feats.band_names, levels, labels,
                                        circular=circular).correlation)
    figs = space_choice.figures(space, feats.data, labels, fitted.counts, models, levels, seed)
    wire = wire_bytes(fitted, levels)
    if wire is None:
        notes.append("the models exceed the link's largest message")
    return SpaceRow(mask, space, len(np.unique(labels)), feats.band_names, corr, figs,
                    exact_l1(fitted.counts, models, levels), texture(feats.data, synth, labels), wire,
                    seconds, synth, pca, tuple(notes))


def choose_mask(rows: list[SpaceRow], space: str) -> tuple[str, str]:
    """(mask, reason): the highest Table-1 correlation of the correlated synthesis in `space`;
    a mask within MASK_MARGIN of it that costs fewer bytes on the wire is preferred (no reason
    where only one was judged)."""
    own = [r for r in rows if r.space == space]
    best = max(r.mean_correlation() for r in own)
    near = [r for r in own if r.mean_correlation() >= best - MASK_MARGIN]
    pick = min(near, key=lambda r: (r.wire_bytes if r.wire_bytes is not None else 1 << 30, -r.mean_correlation()))
    if len(own) == 1:
        return pick.mask, ""
    others = ", ".join(f"{r.mask} {r.mean_correlation():.3f}" for r in own if r is not pick)
    return pick.mask, (f"{pick.mask}: its {space} synthesis correlates {pick.mean_correlation():.3f} with the "
                       f"photograph (Table 1, band mean; {others}) at {pick.wire_bytes} bytes")


def judge(image: np.ndarray, masks: dict[str, np.ndarray], spaces: tuple[str, ...], seed: int = 0,
          progress=None) -> Judgement:
    """Every mask x space, and the choice of mask and space with its reason."""
    rows = []
    for name, labels in masks.items():
        for space in spaces:
            if progress is not None:
                progress(f"{name} {space}")
            rows.append(judge_one(image, name, labels, space, seed))
    own = default_space(image) if default_space(image) in spaces else spaces[0]
    mask, mask_reason = choose_mask(rows, own)
    choice = space_choice.choose([r.figures for r in rows if r.mask == mask])
    said = f"mask {mask_reason}" if mask_reason else "one mask judged"
    return Judgement(rows, mask, choice.space, f"{choice.reason}; {said}")


def auto_space(image: np.ndarray, labels: np.ndarray, seed: int = 0) -> space_choice.Choice:
    """The space `fit --space auto` fits in: the criterion over the photograph's colour spaces
    (gray only for a one-band photograph), fitted without the dependence pass."""
    figs = []
    for space in spaces_of(image):
        if space == "gray" and default_space(image) != "gray":
            continue  # never chosen for a colour photograph
        feats, pca = feature_bands(image, space)
        fitted = fit_bands(feats, pca, labels, dependence=False)
        models = {k: r.model for k, r in fitted.results.items()}
        figs.append(space_choice.figures(space, feats.data, labels, fitted.counts, models, feats.levels, seed))
    return space_choice.choose(figs)
