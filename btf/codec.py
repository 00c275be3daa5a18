"""The z ladder and the percentile codec: what the robot's fit and the receiver share.

The packet sends a fit's z as its ladder index and its four percentiles as fixed-point codes;
the receiver decodes them with the same codec and solves the same model.
"""
from __future__ import annotations

import functools
import math

import numpy as np

# Wire scales: censored fractions travel as 1/65535 fixed point, read shifts as int8 multiples
# of 1/32 (btf.fit.censor places them).
CENSOR_SCALE = 65535
SHIFT_SCALE = 32
MAX_SHIFT_CODE = 127
# z values; the packet sends the index of the one used. z_for_count tries the first ten from
# the top; 0.7, after them, is a wider read the fitter may choose (btf.fit.reads).
Z_LADDER: tuple[float, ...] = (0.524, 0.5, 0.45, 0.4, 0.35, 0.3, 0.25, 0.2, 0.15, 0.1, 0.7)
COUNT_LADDER = Z_LADDER[:10]
# The tail percentile x(3z) should rest on at least this many pixels.
MIN_TAIL_PIXELS = 8


def _phi(x: float) -> float:
    return 0.5 * math.erfc(-x / math.sqrt(2.0))


# Lower-tail probabilities Phi(-3z), Phi(-z), Phi(z), Phi(3z) for each ladder step.
_PROBS: dict[float, tuple[float, float, float, float]] = {
    z: (_phi(-3 * z), _phi(-z), _phi(z), _phi(3 * z)) for z in Z_LADDER
}


def z_for_count(count: int) -> float:
    """The largest ladder step whose outer tail holds MIN_TAIL_PIXELS of `count` pixels."""
    for z in COUNT_LADDER:
        if count * _PROBS[z][0] >= MIN_TAIL_PIXELS:
            return z
    return COUNT_LADDER[-1]


def percentile_probs(z: float, shift: float = 0.0) -> tuple[float, float, float, float]:
    """Lower-tail probabilities of the four percentiles read at shift + (-3z, -z, z, 3z)."""
    if shift == 0.0 and z in _PROBS:
        return _PROBS[z]
    return (_phi(shift - 3 * z), _phi(shift - z), _phi(shift + z), _phi(shift + 3 * z))


class PercentileCodec:
    """Fixed-point codes for percentiles across a sensor range [lo, hi]."""

    def __init__(self, lo: float, hi: float, bits: int = 16) -> None:
        if not (math.isfinite(lo) and math.isfinite(hi) and hi > lo):
            raise ValueError(f"codec range must be finite with hi > lo, got [{lo}, {hi}]")
        if bits not in (8, 16, 32):
            raise ValueError(f"codec bits must be 8, 16 or 32, got {bits}")
        self.lo, self.hi, self.bits = float(lo), float(hi), bits
        self.step = (self.hi - self.lo) / (1 << bits)
        self._top = (1 << bits) - 1

    @classmethod
    def for_levels(cls, levels: int) -> PercentileCodec:
        """Integer sensors: the spread range [-1/2, levels - 1/2]; 16-bit codes up to 8 bits."""
        if not 2 <= levels <= 65536:
            raise ValueError(f"levels must be in [2, 65536], got {levels}")
        return cls(-0.5, levels - 0.5, 16 if levels <= 256 else 32)

    def encode(self, percentiles) -> tuple[int, int, int, int]:
        codes = []
        for x in percentiles:
            x = float(x)
            if not math.isfinite(x):
                raise ValueError(f"cannot encode non-finite percentile {x}")
            codes.append(min(max(round((x - self.lo) / self.step), 0), self._top))
        return tuple(codes)  # type: ignore[return-value]

    def decode(self, codes) -> tuple[float, float, float, float]:
        out = []
        for c in codes:
            c = int(c)
            if not 0 <= c <= self._top:
                raise ValueError(f"percentile code {c} outside [0, {self._top}]")
            out.append(self.lo + c * self.step)
        return tuple(out)  # type: ignore[return-value]

    def snap(self, percentiles) -> tuple[float, float, float, float]:
        return self.decode(self.encode(percentiles))

    def snap_array(self, x: np.ndarray) -> np.ndarray:
        """`snap` of every element of a finite float array (the same steps, element-wise)."""
        codes = np.minimum(np.maximum(np.rint((x - self.lo) / self.step), 0), self._top)
        return self.lo + codes * self.step

    def snap_one(self, x: float) -> float:
        """One value through the fixed point (as `snap` does each of four)."""
        x = float(x)
        if not math.isfinite(x):
            raise ValueError(f"cannot encode non-finite percentile {x}")
        return self.lo + min(max(round((x - self.lo) / self.step), 0), self._top) * self.step

    def __repr__(self) -> str:
        return f"PercentileCodec(lo={self.lo}, hi={self.hi}, bits={self.bits})"

    def __eq__(self, other: object) -> bool:
        return isinstance(other, PercentileCodec) and (self.lo, self.hi, self.bits) == (
            other.lo, other.hi, other.bits)

    def __hash__(self) -> int:
        return hash((self.lo, self.hi, self.bits))


@functools.lru_cache(maxsize=16)
def default_codec(lo: float, bin_width: float, bins: int) -> PercentileCodec:
    """The range of bins centred on lo + k * bin_width, at 16 bits (32 above 256 bins)."""
    return PercentileCodec(lo - 0.5 * bin_width, lo + (bins - 0.5) * bin_width, 16 if bins <= 256 else 32)


def quantize(fraction: float) -> float:
    """A censored fraction as it travels (1/65535 fixed point)."""
    if not (math.isfinite(fraction) and 0.0 <= fraction <= 1.0):
        raise ValueError(f"censored fraction {fraction} outside [0, 1]")
    return round(fraction * CENSOR_SCALE) / CENSOR_SCALE


def fallback_probs(low: float, high: float) -> tuple[float, float]:
    """(pa, pe): the probabilities below the fallback normal's two points. A censored end uses
    its limit; an uncensored end the middle of the uncensored mass."""
    pa = low if low > 0.0 else 0.5 * (1.0 - high)
    pe = 1.0 - high if high > 0.0 else 1.0 - 0.5 * (1.0 - low)
    return pa, pe
