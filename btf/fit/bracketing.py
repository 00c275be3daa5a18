"""Bracketing: a region clipped past `[camera] bracket_limit` is fitted again from shorter exposures.

Censoring fits a saturated region, but it extrapolates the clipped part from the rest. Where
that part is large, the pose takes up to `bracket_max` shorter exposures (the skip principle
in reverse: the extra frame only where the scene needs it) and fits each such region from
the exposure that clips it least, recording which (`CaptureSettings.bracketed`). The next
exposure is read off the region's censored model: the one that brings its top (the 99.9th
percentile) to 90% of full scale, at most half the last one and no shorter than
`bracket_min_ratio` of the capture's own. The label map stays the first frame's: the arm has
not moved.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Callable

from btf.capture_settings import CaptureSettings
from btf.record import FittedModel

TOP_PROBABILITY = 0.999
TOP_TARGET = 0.9  # share of full scale the region's top is brought to

Fits = dict[tuple[int, int], FittedModel]
# One more frame at the pose: its fits and the exposure the camera reports, or None when the
# camera would not take or hold it.
Take = Callable[[float], "tuple[Fits, float] | None"]


def clipped(fits: Fits, label: int) -> float:
    """The largest share of `label`'s pixels censored at the top, over its bands."""
    return max((r.censored_high for (lab, _), r in fits.items() if lab == label), default=0.0)


def over_limit(fits: Fits, limit: float) -> list[int]:
    return [lab for lab in sorted({lab for lab, _ in fits}) if clipped(fits, lab) > limit]


def wanted_exposure(fits: Fits, label: int, exposure: float, levels: int) -> float:
    """The exposure that brings `label`'s top to TOP_TARGET of full scale, from its models
    fitted at `exposure` (censored models extrapolate past the limit)."""
    tops = [float(r.model.ppf(TOP_PROBABILITY)) for (lab, _), r in fits.items() if lab == label]
    top = max(tops, default=math.inf)
    if not (math.isfinite(top) and top > 0):
        return 0.0
    return exposure * TOP_TARGET * (levels - 1) / top


def bracket(fits: Fits, camera: CaptureSettings, levels: int, limit: float, max_brackets: int,
            min_ratio: float, take: Take) -> tuple[Fits, CaptureSettings]:
    """`fits` with each region over `limit` taken from the exposure that clips it least, and
    `camera` with the brackets taken and which region each serves."""
    todo = over_limit(fits, limit)
    if not todo or camera.exposure_us is None:
        return fits, camera
    out = dict(fits)
    best = {lab: clipped(fits, lab) for lab in todo}
    fitted_at = dict.fromkeys(todo, camera.exposure_us)
    shortest = camera.exposure_us * min_ratio
    brackets: list[float] = []
    chosen: dict[int, int] = {}
    last = camera.exposure_us
    for _ in range(max_brackets):
        guess = min(wanted_exposure(out, lab, fitted_at[lab], levels) for lab in todo)
        asked = max(shortest, min(0.5 * last, guess))
        taken = take(asked)
        if taken is None:
            break  # keep what censoring gave
        frame_fits, got = taken
        brackets.append(got)
        last = asked
        for lab in todo:
            share = clipped(frame_fits, lab)
            keys = [k for k in out if k[0] == lab]
            if share < best[lab] and all(k in frame_fits for k in keys):
                best[lab], fitted_at[lab], chosen[lab] = share, got, len(brackets)
                out.update({k: frame_fits[k] for k in keys})
        todo = [lab for lab in todo if best[lab] > limit]
        if not todo or asked <= shortest:
            break
    return out, dataclasses.replace(camera, brackets=tuple(brackets), bracketed=chosen)
