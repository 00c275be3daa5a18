"""Where the dependence pass (btf.fit.dependence) puts its anchors.

The lattice: deterministic, over the whole frame, at most `max_anchors`, inside the frame by R
so every partner exists. A region small or scattered enough to meet few of its anchors gets a
second pass on its own pixels (`sparse_anchors`), at most a set budget in all, so that the pass
stays bounded however many such regions a frame holds.
"""
from __future__ import annotations

import math

import numpy as np

OVERSAMPLE = 8  # pixels read per anchor a region takes (from a random share of its rows)


def lattice(h: int, w: int, radius: int, max_anchors: int) -> list[tuple[np.ndarray, int, int]]:
    """Anchor blocks: (window top rows, first window column, windows per row) per phase. A
    row's windows lie side by side (2R + 1 columns each), so its partners are one run of the
    frame's row."""
    width = 2 * radius + 1
    hv, nx = h - radius, w // width
    if hv < 1 or nx < 1:
        return []
    # Phases: several runs of windows per row, shifted, so the lattice is about as fine across
    # as down (13 x 10 pixels for 8192 anchors of a 1 MP frame; finer phases for small frames).
    phases = min(width, max(1, round(width / math.sqrt(hv * w / max_anchors))))
    step = max(1, math.ceil(hv * nx * phases / max_anchors))
    out = []
    for p in range(phases):
        off = p * width // phases
        if (w - off) // width >= 1:
            out.append((np.arange(p * step // phases, hv, step), off, (w - off) // width))
    return out


def sparse_anchors(labels: np.ndarray, index: np.ndarray, sparse: np.ndarray, met: np.ndarray, radius: int,
                   budget: int, grid: list) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """The second pass's anchors, or None: (index with only the regions it measures, rows,
    columns). `sparse`: the regions the lattice `grid` left with few pairs (positions that
    `index` maps labels to); `met`: the lattice's anchors in each region, which estimate its
    pixels. A sparse region is measured when its share of `budget` would at least match the
    lattice's anchors in it: where the budget is thin over many large regions a second pass
    gains little. Its anchors are its own pixels off the lattice (no pair counted twice, which
    would understate the sampling noise) and inside the frame by R, drawn at random: from every
    row for a region whose share is an OVERSAMPLE-th of its pixels or more, else from a random
    share of the rows holding OVERSAMPLE times its share, so the reading follows the budget, not
    the frame (a scattered region's bounding box is the frame). The draw is seeded, so a frame
    always gets the same anchors; a regular thinning, every k-th pixel, aliased with the column
    pattern of upsampled photographs."""
    h, w = labels.shape
    area, points = (h - radius) * (w - 2 * radius), sum(len(rows) * nx for rows, _, nx in grid)
    if not len(sparse) or budget < 1 or area < 1 or not points:
        return None
    pixels = np.maximum(met, 1.0) * (area / points)  # a region the lattice missed: one lattice cell
    sparse = sparse[_worth(pixels[sparse], met[sparse], budget)]
    if not len(sparse):
        return None
    rng = np.random.default_rng(0)
    rate = np.minimum(1.0, OVERSAMPLE * shares(pixels[sparse], budget) / pixels[sparse])
    found = _candidates(labels, index, sparse, rate, radius, OVERSAMPLE * budget, rng)
    found = [f[~on_lattice(f // w, f % w, grid, radius)] for f in found]
    take = shares(np.array([len(f) for f in found]), budget).astype(np.int64)
    flat = np.sort(np.concatenate([f if len(f) <= t else rng.choice(f, t, replace=False)
                                   for f, t in zip(found, take)]))
    return np.where(np.isin(index, sparse), index, -1), flat // w, flat % w


def _candidates(labels: np.ndarray, index: np.ndarray, sparse: np.ndarray, rate: np.ndarray, radius: int,
                cap: int, rng: np.random.Generator) -> list[np.ndarray]:
    """Per region of `sparse`, the flat positions of its pixels inside the frame by R on a random
    `rate` of the rows (one reading of every row for the regions at rate 1), at most about `cap`
    of them: past it, those found and those to come are halved at random. Memory: a block of
    rows and the positions kept."""
    h, w = labels.shape
    every, per = np.arange(h - radius), max(1, 65536 // max(1, w - 2 * radius))  # rows: about 64k pixels a block
    groups = [(np.flatnonzero(rate >= 1.0), every)] + [
        (np.array([i]), every[rng.random(len(every)) < r]) for i, r in enumerate(rate) if r < 1.0]
    found: list[list[np.ndarray]] = [[] for _ in sparse]
    kept, keep = np.zeros(len(sparse), np.int64), np.ones(len(sparse))
    for members, rows in groups:
        if not len(members) or not len(rows):
            continue
        only = np.full(len(index), -1, np.int16 if len(sparse) < 2 ** 15 else np.int32)
        for i in members:
            only[np.flatnonzero(index == sparse[i])] = i
        wanted = np.flatnonzero(only >= 0)  # their labels
        for start in range(0, len(rows), per):
            block = rows[start:start + per]
            reg = _which(labels[block, radius:w - radius], only, wanted).ravel()
            hit = np.flatnonzero(reg >= 0)
            y, x = np.divmod(hit, w - 2 * radius)  # a 2-D nonzero ran ten times slower
            flat, which = block[y] * w + radius + x, reg[hit]
            for i in members:
                mine = flat[which == i] if len(members) > 1 else flat
                if keep[i] < 1.0:
                    mine = mine[rng.random(len(mine)) < keep[i]]
                found[i].append(mine)
                kept[i] += len(mine)
                while kept[i] > cap:  # halve what was found and what will be
                    found[i] = [np.concatenate(found[i])[rng.random(kept[i]) < 0.5]]
                    kept[i], keep[i] = len(found[i][0]), keep[i] / 2
    return [np.concatenate(f) if f else np.zeros(0, np.int64) for f in found]


def _worth(pixels: np.ndarray, met: np.ndarray, budget: int) -> np.ndarray:
    """Which regions a share of `budget` would give at least the anchors `met` they have,
    the budget shared among those alone (dropping a region raises the others' shares)."""
    keep = np.ones(len(pixels), dtype=bool)
    while keep.any():
        low = keep & (shares(np.where(keep, pixels, 0.0), budget) < met)
        if not low.any():
            break
        keep &= ~low
    return keep


def _which(lab: np.ndarray, only: np.ndarray, wanted: np.ndarray) -> np.ndarray:
    """Per pixel of a block, the region `only` maps its label to (-1 for most): a comparison
    per label for one or two labels (a quarter of a table lookup's time), else the table."""
    if len(wanted) <= 2:
        out = np.full(lab.shape, -1, only.dtype)
        for label in wanted:
            out[lab == label] = only[label]
        return out
    return np.take(only, np.where(lab < 0, -1, lab) if lab.dtype.kind == "i" else lab)


def on_lattice(ys: np.ndarray, xs: np.ndarray, grid: list, radius: int) -> np.ndarray:
    """Whether each pixel (ys, xs) is an anchor of the lattice `grid` (`lattice`)."""
    width = 2 * radius + 1
    out = np.zeros(len(ys), dtype=bool)
    for rows, col, nx in grid:
        if not len(rows):
            continue
        step = int(rows[1] - rows[0]) if len(rows) > 1 else 1
        c = xs - col - radius
        out |= ((ys >= rows[0]) & (ys <= rows[-1]) & ((ys - rows[0]) % step == 0)
                & (c >= 0) & (c % width == 0) & (c < nx * width))
    return out


def shares(counts: np.ndarray, budget: int) -> np.ndarray:
    """Anchors per region of `counts` pixels: the budget shared out from the smallest region
    up, each taking at most an equal share of what is left (so the smallest regions keep all
    their pixels)."""
    out = np.zeros(len(counts))
    order = [j for j in np.argsort(counts, kind="stable") if counts[j] > 0]
    left = float(budget)
    for i, j in enumerate(order):
        out[j] = min(float(counts[j]), left / (len(order) - i))
        left -= out[j]
    return out
