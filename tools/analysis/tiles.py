"""Row tiles for the host's image work: what `compare`, `synth`, `pdfs` and `mask` hold beyond
their images is a few tiles of temporaries, whatever the image size.

A tile is a block of whole rows of about `TILE_PIXELS` pixels, so pixels keep their row-major
order from tile to tile: a random stream served tile by tile gives every pixel the number it
would get in one whole-image pass, and results do not depend on the tile size.
"""
from __future__ import annotations

import contextlib
import os
import threading
from concurrent.futures import ThreadPoolExecutor, wait
from dataclasses import dataclass
from typing import Callable, ContextManager

import numpy as np
from threadpoolctl import ThreadpoolController

TILE_PIXELS = 1 << 18  # temporaries of a few MB per tile
DRAW_CHUNK = 1 << 18  # random numbers drawn at a time; even (see Draws)
# Work on at least this many pixels is spread over threads (numpy and scipy.fft let go of
# the GIL in their loops). On two cores a 500 x 500 region drew no faster on two threads
# (the hand-overs and the cache traffic ate the gain) and a 1000 x 1000 one 1.2-1.4x faster.
PARALLEL_PIXELS = 1 << 19
MAX_THREADS = 4
_POOL: list[ThreadPoolExecutor] = []
_POOL_LOCK = threading.Lock()
# One BLAS thread: the small solves of the setup and the vector steps of a draw ran 10 to 30
# times slower when OpenBLAS spread them over the cores of a machine other work was using.
_BLAS: list[ThreadpoolController] = []  # made at first use: it inspects the loaded libraries


def _forget_pool() -> None:
    """In a forked child: none of the parent's threads came along, so a pool starts afresh."""
    global _POOL_LOCK
    _POOL.clear()
    _POOL_LOCK = threading.Lock()


os.register_at_fork(after_in_child=_forget_pool)


def _cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)


CORES = _cores()  # the cores this process may run on


def threads() -> int:
    """How many threads `in_parallel` spreads work over."""
    return max(1, min(MAX_THREADS, CORES))


def workers(pixels: int) -> int:
    """scipy.fft's `workers` for a transform of `pixels` pixels: the threads of `in_parallel`."""
    return threads() if pixels >= PARALLEL_PIXELS else 1


def in_pool() -> bool:
    """Whether this is one of `in_parallel`'s threads (work here runs on it alone)."""
    return threading.current_thread().name.startswith("tiles")


def one_blas_thread() -> ContextManager:
    """BLAS held to one thread for the block. In the pool's threads the caller of `in_parallel`
    already holds it: the library's setting is global, and limits set and restored from several
    threads at once could leave it at one for the whole process."""
    if in_pool():
        return contextlib.nullcontext()
    if not _BLAS:
        _BLAS.append(ThreadpoolController())
    return _BLAS[0].limit(limits=1, user_api="blas")


def streams(rng: np.random.Generator, count: int) -> list[np.random.Generator]:
    """`count` independent generators seeded from `rng` (four of its words): work split over
    them gives the same numbers on any number of threads."""
    seeds = np.random.SeedSequence(rng.bit_generator.random_raw(4).tolist()).spawn(count)
    return [np.random.Generator(type(rng.bit_generator)(seed)) for seed in seeds]


def split_rows(rows: slice, parts: int) -> list[slice]:
    """`rows` in up to `parts` blocks, in order: a tile shared by threads holds one tile's
    temporaries in all."""
    step = max(1, -(-(rows.stop - rows.start) // parts))
    return [slice(r, min(r + step, rows.stop)) for r in range(rows.start, rows.stop, step)]


def in_parallel(work: Callable[[int], None], count: int, pixels: int) -> None:
    """work(i) for i in range(count), each on its own memory: over the pool's threads when
    there are several parts of `pixels` pixels in all to share, else one after the other here."""
    if min(threads(), count) < 2 or pixels < PARALLEL_PIXELS or in_pool():
        for i in range(count):
            work(i)
        return
    with _POOL_LOCK:
        if not _POOL:
            _POOL.append(ThreadPoolExecutor(max_workers=threads(), thread_name_prefix="tiles"))
        pool = _POOL[0]
    parts = [pool.submit(work, i) for i in range(count)]
    wait(parts)  # every part ended before any error is raised: none still writes after the call
    for part in parts:
        part.result()


def row_tiles(height: int, width: int, tile_pixels: int | None = None, start: int = 0) -> list[slice]:
    """Row blocks of about `tile_pixels` (default TILE_PIXELS) pixels covering rows
    start..height of a width-wide image."""
    tile_pixels = TILE_PIXELS if tile_pixels is None else tile_pixels
    if tile_pixels < 1:
        raise ValueError(f"tile_pixels must be positive, got {tile_pixels}")
    rows = max(1, tile_pixels // max(width, 1))
    return [slice(r, min(r + rows, height)) for r in range(start, height, rows)]


def label_counts(mask: np.ndarray, tile_pixels: int | None = None) -> dict[int, int]:
    """{label: pixel count} of an integer mask, ascending, found tile by tile."""
    blocks = row_tiles(mask.shape[0], mask.shape[1], tile_pixels)
    if mask.dtype in (np.uint8, np.bool_):
        seen = sum((np.bincount(mask[r].ravel(), minlength=256) for r in blocks), np.zeros(256, np.int64))
        return {int(v): int(seen[v]) for v in np.flatnonzero(seen)}
    counts: dict[int, int] = {}
    for r in blocks:
        values, n = np.unique(mask[r], return_counts=True)
        for v, c in zip(values.tolist(), n.tolist()):
            counts[v] = counts.get(v, 0) + c
    return dict(sorted(counts.items()))


@dataclass(frozen=True)
class Region:
    """Where one label lies: its bounding box, pixel count, and the row tiles of the box."""

    label: int
    rows: slice
    cols: slice
    count: int
    tiles: tuple[slice, ...]


def region(mask: np.ndarray, label: int, tile_pixels: int | None = None) -> Region:
    """The bounding box of `label` in `mask` (empty slices when absent), in one tiled pass."""
    height, width = mask.shape
    row_hit = np.zeros(height, bool)
    col_hit = np.zeros(width, bool)
    count = 0
    for r in row_tiles(height, width, tile_pixels):
        sel = mask[r] == label
        row_hit[r] = sel.any(axis=1)
        col_hit |= sel.any(axis=0)
        count += int(np.count_nonzero(sel))
    if not count:
        return Region(label, slice(0, 0), slice(0, 0), 0, ())
    rows, cols = np.flatnonzero(row_hit), np.flatnonzero(col_hit)
    r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    return Region(label, slice(r0, r1), slice(c0, c1), count, tuple(row_tiles(r1, c1 - c0, tile_pixels, r0)))


class Draws:
    """One random stream served in pieces of any size: the numbers `draw(n)` would give at once.

    `draw(k)` is called with DRAW_CHUNK, ..., then the remainder. numpy's Generator continues
    its stream across calls except that `bytes` rounds each call up to 4-byte words, so every
    chunk but the last must be even for 2-byte draws (DRAW_CHUNK is)."""

    def __init__(self, draw, n: int) -> None:
        self.draw, self.left = draw, n
        self.buffer: np.ndarray | None = None

    def take(self, k: int) -> np.ndarray:
        parts: list[np.ndarray] = []
        if k <= 0:
            return self.draw(0)
        while k:
            if self.buffer is None or not len(self.buffer):
                size = min(DRAW_CHUNK, self.left)
                if size <= 0:
                    raise ValueError("random stream exhausted")
                self.buffer, self.left = self.draw(size), self.left - size
            part, self.buffer = self.buffer[:k], self.buffer[k:]
            parts.append(part)
            k -= len(part)
        return parts[0] if len(parts) == 1 else np.concatenate(parts)


def region_histograms(stack: np.ndarray, mask: np.ndarray | None, ids: np.ndarray, levels: list[int],
                      tile_pixels: int | None = None) -> list[np.ndarray]:
    """Per band k of an H x W x B stack of integer levels, the (len(ids), levels[k]) counts of
    each region (label ids[i] of `mask`; one region without a mask), tile by tile."""
    height, width = stack.shape[:2]
    counts = [np.zeros(len(ids) * n, np.int64) for n in levels]
    for r in row_tiles(height, width, tile_pixels):
        index = (np.zeros((r.stop - r.start) * width, np.intp) if mask is None
                 else np.searchsorted(ids, mask[r].ravel()).astype(np.intp, copy=False))
        for k, n in enumerate(levels):
            v = stack[r, :, k].ravel()
            if v.size and (v.min() < 0 or v.max() >= n):
                raise ValueError(f"values outside 0..{n - 1}")
            counts[k] += np.bincount(index * n + v.astype(np.intp), minlength=len(ids) * n)
    return [c.reshape(len(ids), n) for c, n in zip(counts, levels)]
