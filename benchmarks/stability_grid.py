"""The stability map's grid: Johnson curves at points of the (beta1, beta2) plane, scaled to
the 8-bit range, and the saturations applied to them.

Each point's curve has that (beta1, beta2) (SB and SU shapes solved numerically, SL on the
lognormal line, SN at the normal point) and is scaled so its 0.1%..99.9% range spans gray
levels 20..235; a saturation then translates it (benchmarks.model_histograms.saturating) until the given
fraction lies beyond level 254.5 (at 255) or below 0.5 (at 0).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

from benchmarks.curve_moments import lognormal_beta2, lognormal_omega, solve_shape
from benchmarks.model_histograms import saturating
from btf.johnson import Family, Johnson

# Below beta2 = beta1 + 1 + NEAR_BOUNDARY the curves are U- or J-shaped, close to two-point
# distributions: the quantile function is nearly a step, and any shift of the step's u shows
# up as the whole gap. The map reports its worst error with and without this band.
NEAR_BOUNDARY = 0.2


@dataclass(frozen=True)
class Point:
    beta1: float
    beta2: float
    where: str  # region name
    curve: Johnson  # scaled to the 8-bit range

    @property
    def near_boundary(self) -> bool:
        return self.beta2 < self.beta1 + 1.0 + NEAR_BOUNDARY


@dataclass(frozen=True)
class Saturation:
    """`fraction` of the mass at the top level (255) or the bottom level (0); none at 0."""
    fraction: float = 0.0
    top: bool = True

    @property
    def label(self) -> str:
        return "none" if self.fraction == 0 else f"{self.fraction:.0%} at {255 if self.top else 0}"

    def apply(self, curve: Johnson) -> Johnson:
        if self.fraction == 0:
            return curve
        return saturating(curve, high=self.fraction) if self.top else saturating(curve, low=self.fraction)


FRACTIONS = (0.10, 0.25, 0.40)
SATURATIONS = (Saturation(), *(Saturation(f) for f in FRACTIONS), *(Saturation(f, top=False) for f in FRACTIONS))


def grid(beta1s: tuple[float, ...]) -> list[Point]:
    pts = []
    for b1 in beta1s:
        ln = lognormal_beta2(b1) if b1 > 0 else 3.0
        cands = [(b1 + 1.1, "near beta2 = beta1 + 1"), (b1 + 1.3, "beside the near-boundary band"),
                 (b1 + 1 + 0.5 * (ln - b1 - 1), "SB region"), (ln + 1.0, "SU region"),
                 (ln + 6.0, "SU region, heavy tails")]
        if b1 > 0:
            cands.append((ln, "lognormal line"))
        else:
            cands += [(3.0, "normal point"), (3.05, "near the normal point")]
        pts += [Point(b1, b2, where, curve(b1, b2)) for b2, where in cands]
    return pts


def curve(b1: float, b2: float) -> Johnson:
    """The Johnson curve with these (beta1, beta2), positive skew, 0.1%..99.9% at 20..235."""
    skew = math.sqrt(b1)
    if b1 == 0.0 and b2 == 3.0:
        std = Johnson.normal(0.0, 1.0)
    elif b1 > 0 and abs(b2 - lognormal_beta2(b1)) < 1e-9:
        std = Johnson(Family.SL, 0.0, 1.0 / math.sqrt(math.log(lognormal_omega(b1))), 0.0, 1.0)
    else:
        family = Family.SU if b2 > (lognormal_beta2(b1) if b1 > 0 else 3.0) else Family.SB
        g, d = solve_shape(family, skew, b2)
        std = Johnson(family, g, d, 0.0, 1.0)
    a, b = (float(v) for v in std.ppf([0.001, 0.999]))
    scale = 215.0 / (b - a)
    return Johnson(std.family, std.gamma, std.delta, 20.0 - a * scale, std.lam * scale)
