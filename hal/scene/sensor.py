"""What the sensor makes of the light: read noise, rounding and clipping to its range.

Noise is 16 random bits a value looked up in a table of normal quantiles (several times
cheaper than `Generator.normal`; beyond 4.3 sigma is nothing a sensor shows). Large tables
are read in blocks of indices, so numpy converts each block's indices to its own index type
without a temporary the size of the frame.
"""
from __future__ import annotations

import math
from functools import lru_cache
from statistics import NormalDist

import numpy as np

BLOCK = 1 << 16  # indices per gather


def gather(table: np.ndarray, index: np.ndarray) -> np.ndarray:
    """`table` (rows along the first axis) at each `index`: shape index.shape + a row's shape."""
    flat = index.reshape(-1)
    out = np.empty((flat.size, *table.shape[1:]), table.dtype)
    for start in range(0, flat.size, BLOCK):
        np.take(table, flat[start:start + BLOCK], axis=0, out=out[start:start + BLOCK])
    return out.reshape(*index.shape, *table.shape[1:])


@lru_cache(maxsize=1)
def _normal_quantiles() -> np.ndarray:
    """N(0, 1) at the middle of each of 2^16 equally likely intervals."""
    unit = NormalDist()
    return np.array([unit.inv_cdf((i + 0.5) / 65536) for i in range(65536)], np.float32)


def unit_normal(rng: np.random.Generator, shape: tuple[int, ...], sigma: float = 1.0,
                mean: float = 0.0) -> np.ndarray:
    """Normal noise of `mean` and `sigma`, float32, drawn from `rng`."""
    count = math.prod(shape)
    bits = rng.bit_generator.random_raw(-(-count // 4)).view(np.uint16)[:count]
    return gather(_normal_quantiles() * np.float32(sigma) + np.float32(mean), bits).reshape(shape)


def digitise(signal: np.ndarray, factors: np.ndarray, noise_sigma: float, full: int,
             rng: np.random.Generator, dtype: type) -> np.ndarray:
    """signal (H x W x B) times each band's factor plus Gaussian noise, rounded to whole
    numbers and clipped to 0..full."""
    # a half added with the noise makes truncation the rounding (an exact tie has probability 0)
    out = unit_normal(rng, signal.shape, noise_sigma, 0.5)
    for band, factor in enumerate(factors):
        out[..., band] += signal[..., band] * np.float32(factor)
    np.clip(out, 0.0, full + 0.5, out=out)
    return out.astype(dtype)


def clipped_mean(signal: np.ndarray, factors: np.ndarray, full: float) -> np.ndarray:
    """Mean per band of signal (H x W x B) times each band's factor, clipped at `full` (float64)."""
    return np.array([np.minimum(signal[..., band] * np.float32(factor), np.float32(full)).mean(dtype=np.float64)
                     for band, factor in enumerate(factors)])
