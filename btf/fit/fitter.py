"""The fixed-memory fitter: frames and raw values in, fitted models (btf.record) out.

FrameFitter fills preallocated per-(label, band) histograms in bounded row chunks and fits
them in one batch (btf.fit.histogram_fit); fit_values bins raw values and fits them alone.
"""
from __future__ import annotations

import math

import numpy as np

from btf.codec import PercentileCodec, z_for_count
from btf.fit.histogram_fit import fit_counts, fit_histogram, fit_rows, histogram_percentiles, plain_fit
from btf.record import FittedModel

__all__ = ["FrameFitter", "fit_histogram", "fit_values", "histogram_percentiles", "plain_fit"]


def fit_values(values: np.ndarray, value_range: tuple[float, float] | None = None,
               bins: int | None = None) -> FittedModel:
    """Fit raw values. Integer dtypes default to one bin per level over the dtype's range;
    floats to 256 bins over `value_range` (default: the data's own range)."""
    v = np.asarray(values).ravel()
    if v.size == 0:
        raise ValueError("no values to fit")
    if v.dtype.kind not in "iuf":
        raise ValueError(f"values must be numeric, got dtype {v.dtype}")
    if v.dtype.kind == "f" and not np.all(np.isfinite(v)):
        raise ValueError("values contain NaN or inf")
    lo, hi, bins = _value_grid(v, value_range, bins)
    if value_range is not None:  # otherwise the grid is the dtype's or the data's own range
        vmin, vmax = float(v.min()), float(v.max())
        if vmin < lo or vmax > hi:
            raise ValueError(f"values [{vmin}, {vmax}] outside the declared range [{lo}, {hi}]")
    counts, width, centre0 = _bin(v, lo, hi, bins)
    # Counts of v's values: non-negative integers summing to v.size, nothing to re-check.
    return fit_counts(counts, np.flatnonzero(counts), v.size, centre0, width, None, None, True)


def _value_grid(v: np.ndarray, value_range, bins) -> tuple[float, float, int]:
    """(lo, hi, bins) for values v: integers get unit bins centred on each level."""
    dtype = v.dtype
    if dtype.kind in "iu" and value_range is None and bins is None:
        info = np.iinfo(dtype)
        if info.max - info.min + 1 > 65536:
            raise ValueError(f"integer dtype {dtype} is deeper than 16 bits: give value_range and bins")
        return float(info.min), float(info.max), int(info.max - info.min + 1)
    if value_range is None:
        value_range = (float(v.min()), float(v.max()))
    lo, hi = float(value_range[0]), float(value_range[1])
    if not (math.isfinite(lo) and math.isfinite(hi) and hi >= lo):
        raise ValueError(f"value_range must be finite with hi >= lo, got {value_range}")
    if bins is None:
        bins = int(hi - lo + 1) if dtype.kind in "iu" else 256
    if not 2 <= bins <= 65536:
        raise ValueError(f"bins must be in [2, 65536], got {bins}")
    return lo, hi, bins


def _bin_geometry(lo: float, hi: float, bins: int, integer: bool) -> tuple[float, float]:
    """(bin width, centre of bin 0). Integer data whose levels fill the bins one each
    is centred on the levels; otherwise the bins tile [lo, hi]."""
    if hi == lo or (integer and hi - lo + 1 == bins):
        return 1.0, lo
    width = (hi - lo) / bins
    return width, lo + 0.5 * width


def _bin(v: np.ndarray, lo: float, hi: float, bins: int) -> tuple[np.ndarray, float, float]:
    """(counts, bin width, centre of bin 0) of values v on the grid [lo, hi] in `bins` bins."""
    width, centre0 = _bin_geometry(lo, hi, bins, v.dtype.kind in "iu")
    if width == 1.0 and centre0 == lo and v.dtype.kind in "iu":
        idx = (v.astype(np.intp) - int(lo)) if lo != 0 else v.astype(np.intp, copy=False)
    else:
        idx = np.clip(((v - (centre0 - 0.5 * width)) * (1.0 / width)).astype(np.intp), 0, bins - 1)
    return np.bincount(idx, minlength=bins), width, centre0


class FrameFitter:
    """Per-(label, band) histograms in preallocated memory, filled in bounded row chunks.

    Without `value_range` the bins are the integer levels 0 .. bins-1 (256 for 8-bit,
    65536 for 16-bit sensors). With it, integer-like ranges (hi - lo + 1 == bins) keep one
    bin per level; otherwise the bins tile [lo, hi]. A chunk holds chunk_rows * 1024 pixels
    (chunk_rows rows of a 1024-wide frame; more rows of narrower, fewer of wider frames), so
    the extra memory of add() does not grow with frame size.
    """

    def __init__(self, n_labels: int, n_bands: int, bins: int = 256,
                 value_range: tuple[float, float] | None = None, chunk_rows: int = 64,
                 subsample: int = 1) -> None:
        if n_labels < 1 or n_bands < 1:
            raise ValueError(f"need at least one label and one band, got {n_labels}, {n_bands}")
        if not 2 <= bins <= 65536:
            raise ValueError(f"bins must be in [2, 65536], got {bins}")
        if chunk_rows < 1 or subsample < 1:
            raise ValueError(f"chunk_rows and subsample must be >= 1, got {chunk_rows}, {subsample}")
        if n_labels * n_bands * bins >= 2**31:
            raise ValueError("labels x bands x bins is too large for one histogram array")
        lo, hi = (0.0, float(bins - 1)) if value_range is None else map(float, value_range)
        if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
            raise ValueError(f"value_range must be finite with hi > lo, got {value_range}")
        self.n_labels, self.n_bands, self.bins = n_labels, n_bands, bins
        self.lo, self.hi = lo, hi
        self.chunk_pixels = chunk_rows * 1024
        self.chunk_rows, self.subsample = chunk_rows, subsample
        self.bin_width, self.centre0 = _bin_geometry(lo, hi, bins, hi - lo + 1 == bins)
        self._unit_levels = self.bin_width == 1.0 and self.centre0 == lo and lo == 0.0
        edge0 = self.centre0 - 0.5 * self.bin_width
        if self._unit_levels:
            self.codec = PercentileCodec.for_levels(bins)
        else:
            self.codec = PercentileCodec(edge0, edge0 + bins * self.bin_width, 16 if bins <= 256 else 32)
        self.counts = np.zeros((n_labels, n_bands, bins), dtype=np.int64)
        self._bases = (np.arange(n_labels, dtype=np.intp)[:, None] * n_bands
                       + np.arange(n_bands, dtype=np.intp)[None, :]) * bins
        self.empty_labels: tuple[int, ...] = ()
        # 8-bit frames: a pixel's label base fits in 16 bits.
        self._fits16 = n_labels * bins <= 65536 and bins == 256

    def reset(self) -> None:
        self.counts[...] = 0
        self.empty_labels = ()

    def add(self, frame: np.ndarray, labels: np.ndarray) -> None:
        """Accumulate one frame (HxWxB, or HxW for one band) under its label image (HxW)."""
        frame, labels = self._checked(frame, labels)
        frame, labels = frame[::self.subsample, ::self.subsample], labels[::self.subsample, ::self.subsample]
        height, width = labels.shape
        if height == 0 or width == 0:
            return
        step = max(1, self.chunk_pixels // width)
        if self._fits16 and self._unit_levels and frame.dtype == np.uint8:
            self._add_8bit(frame, labels, step)
            return
        flat = self.counts.reshape(-1)
        for r0 in range(0, height, step):
            lab, vals = labels[r0:r0 + step], frame[r0:r0 + step]
            self._check_labels(lab)
            # One gather of each pixel's (label, band) base offset, then add the bin index.
            idx = np.take(self._bases, lab, axis=0)
            if self._unit_levels and vals.dtype.kind in "ui":
                self._check_range(vals)
                np.add(idx, vals, out=idx, casting="unsafe")
            else:
                idx += self._value_index(vals)
            flat += np.bincount(idx.reshape(-1), minlength=flat.size)

    def _add_8bit(self, frame: np.ndarray, labels: np.ndarray, step: int) -> None:
        """8-bit frames whose (label, level) indices fit 16 bits: per chunk and band, the index
        label * 256 + value in two buffers reused across chunks, one bincount each into that
        band's labels x levels (no gather, no broadcast over the short band axis, no per-chunk
        copies); the labels checked once, not per chunk."""
        self._check_labels(labels)
        height, width = labels.shape
        cap = min(step, height) * width
        base = np.empty(cap, dtype=np.uint16)
        idx = np.empty(cap, dtype=np.intp)  # bincount's own type: it copies nothing
        size = self.n_labels * self.bins
        for r0 in range(0, height, step):
            lab, vals = labels[r0:r0 + step], frame[r0:r0 + step]
            n = lab.size
            b = base[:n].reshape(lab.shape)
            i = idx[:n].reshape(lab.shape)
            np.multiply(lab, np.uint16(self.bins), out=b, casting="unsafe")
            for band in range(self.n_bands):
                np.add(vals[..., band], b, out=i, casting="unsafe")
                self.counts[:, band, :] += np.bincount(idx[:n], minlength=size).reshape(self.n_labels, self.bins)

    def _check_labels(self, lab: np.ndarray) -> None:
        if lab.dtype == np.uint8 and self.n_labels >= 256:
            return  # every value is a label
        lmin, lmax = (0 if lab.dtype.kind == "u" else int(lab.min())), int(lab.max())
        if lmin < 0 or lmax >= self.n_labels:
            bad = lmin if lmin < 0 else lmax
            raise ValueError(f"label {bad} outside [0, {self.n_labels - 1}]")

    def fit(self, min_count: int = 1, censor: bool = True) -> dict[tuple[int, int], FittedModel]:
        """Fit every (label, band) with at least `min_count` pixels; others go to empty_labels."""
        totals = self.counts[:, 0, :].sum(axis=1)
        keep = [lab for lab in range(self.n_labels) if int(totals[lab]) >= max(min_count, 1)]
        self.empty_labels = tuple(sorted(set(range(self.n_labels)) - set(keep)))
        if not keep:
            return {}
        label_z = {lab: z_for_count(int(totals[lab])) for lab in keep}
        counts = [int(totals[lab]) for lab in keep for _ in range(self.n_bands)]
        zs = [label_z[lab] for lab in keep for _ in range(self.n_bands)]
        rows = self.counts[keep].reshape(-1, self.bins)
        fits = fit_rows(rows, counts, zs, self.centre0, self.bin_width, self.codec, censor)
        keys = [(lab, band) for lab in keep for band in range(self.n_bands)]
        return dict(zip(keys, fits))

    def _checked(self, frame: np.ndarray, labels: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        frame, labels = np.asarray(frame), np.asarray(labels)
        if frame.dtype.kind not in "uif" or frame.dtype.itemsize > 8:
            raise ValueError(f"frame dtype must be unsigned, integer or float, got {frame.dtype}")
        if labels.dtype.kind not in "ui":
            raise ValueError(f"labels must be integers, got dtype {labels.dtype}")
        if frame.ndim == 2:
            frame = frame[..., None]
        if frame.ndim != 3 or frame.shape[2] != self.n_bands:
            raise ValueError(f"frame shape {frame.shape} is not HxWx{self.n_bands}")
        if labels.shape != frame.shape[:2]:
            raise ValueError(f"labels shape {labels.shape} does not match frame {frame.shape[:2]}")
        return frame, labels

    def _check_range(self, vals: np.ndarray) -> None:
        if vals.dtype.kind in "ui":
            info = np.iinfo(vals.dtype)
            if info.min >= self.lo and info.max <= self.hi:
                return  # the dtype cannot leave the range
        vmin, vmax = vals.min(), vals.max()
        if vmin < self.lo or vmax > self.hi:
            raise ValueError(f"frame values [{vmin}, {vmax}] outside the declared range [{self.lo}, {self.hi}]")

    def _value_index(self, vals: np.ndarray) -> np.ndarray:
        """Bin index of every value (new intp array), after range checks."""
        if vals.dtype.kind == "f" and not np.all(np.isfinite(vals)):
            raise ValueError("frame contains NaN or inf")
        self._check_range(vals)
        if self.bin_width == 1.0 and self.centre0 == self.lo:
            # one bin per level: round to the nearest level
            return np.rint(vals - self.lo).astype(np.intp)
        edge0 = self.centre0 - 0.5 * self.bin_width
        idx = ((vals - edge0) * (1.0 / self.bin_width)).astype(np.intp)
        np.clip(idx, 0, self.bins - 1, out=idx)
        return idx
