"""`[features] space = "auto"`: a scene's feature space, resolved once from its first frame.

The criterion is the host's (btf.fit.space_choice, numpy only): each colour space (rgb, hsv,
pca) is fitted under an ISODATA mask of the frame and judged by its Table-2 error at two seeds
and by how much its bands correlate within regions. The robot judges a lattice of at most
JUDGED_PIXELS pixels of the frame, so the one-off cost is bounded at any frame size. A one-band
frame is gray at its own depth; any other frame but 8-bit colour (16-bit colour, a multi-spectral
camera's bands) is raw: the colour spaces read three 8-bit bands.
"""
from __future__ import annotations

import numpy as np

from btf.fit import space_choice
from btf.fit.features import FeatureSpace, FeatureSpec, PcaBasis, compute
from btf.fit.fitter import FrameFitter
from btf.fit.isodata import IsodataParams, isodata

JUDGED_PIXELS = 1 << 16
COLOUR_SPACES = ("rgb", "hsv", "pca")
MAX_REASON = 500  # characters of the reason a MODELS packet's extras carry (a string holds 512)


def lattice(frame: np.ndarray, pixels: int = JUDGED_PIXELS) -> np.ndarray:
    """Every step-th pixel along both axes, the step the smallest that keeps at most `pixels`."""
    h, w = frame.shape[:2]
    step = 1
    while -(-h // step) * -(-w // step) > pixels:
        step += 1
    return np.ascontiguousarray(frame[::step, ::step])


def resolve(frame: np.ndarray, classes: int, seed: int = 0,
            names: tuple[str, ...] | None = None) -> tuple[FeatureSpec, space_choice.Choice]:
    """The feature spec to fit the scene in, and the criterion's choice with its reason;
    `names`: the camera's band names, should it be raw."""
    if frame.ndim == 2 or frame.shape[2] == 1:
        spec = FeatureSpec(FeatureSpace.GRAY)
        return spec, space_choice.Choice("gray", "gray: the frame has one band", ("gray",))
    if frame.dtype != np.uint8 or frame.shape[2] not in (3, 4):
        depth = 8 * frame.dtype.itemsize
        return FeatureSpec(FeatureSpace.RAW, names=names), space_choice.Choice(
            "raw", f"raw: a frame of {frame.shape[2]} {depth}-bit bands (the colour spaces read three 8-bit bands)",
            ("raw",))
    sub = lattice(frame[..., :3])
    labels = isodata(sub, IsodataParams(k=classes, seed=seed)).labels
    figures = []
    for name in COLOUR_SPACES:
        spec = FeatureSpec(FeatureSpace(name))
        feats = compute(sub, spec, PcaBasis.fit(sub) if name == "pca" else None)
        fitter = FrameFitter(int(labels.max()) + 1, feats.data.shape[2])
        fitter.add(feats.data, labels)
        models = {k: r.model for k, r in fitter.fit().items()}
        figures.append(space_choice.figures(name, feats.data, labels, fitter.counts, models, 256, seed))
    choice = space_choice.choose(figures)
    return FeatureSpec(FeatureSpace(choice.space)), choice
