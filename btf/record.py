"""The fitted-model record: one (label, band) model as the robot fits it, the MODELS packet
carries it and the host stores it.

A model is rebuilt from its four percentiles and its read (z, shift, censored fractions, the
fallback and family rules) by `btf.percentile.model_from_percentiles`, the same call on robot
and host, so both hold the same model bit for bit. `beta1` and `beta2` describe the histogram
the robot fitted; they do not travel, so a record decoded from a packet has None there.
"""
from __future__ import annotations

from dataclasses import dataclass

from btf.codec import fallback_probs
from btf.johnson import Johnson
from btf.percentile import model_from_percentiles


@dataclass(frozen=True, slots=True)
class FittedModel:
    model: Johnson
    count: int  # pixels of the region
    z: float  # the read's spread: percentiles at shift + (-3z, -z, z, 3z) on the normal scale
    percentiles: tuple[float, float, float, float]  # in data units, through the codec's fixed point
    beta1: float | None = None  # squared skewness of the fitted histogram (robot side only)
    beta2: float | None = None  # its kurtosis
    shift: float = 0.0
    # Fractions of the pixels censored at the lowest and highest level (1/65535 fixed point).
    censored_low: float = 0.0
    censored_high: float = 0.0
    fallback: bool = False  # the normal through the censor limits (btf.fit.censor)
    exact_family: bool = False  # the family from the sign of ln d alone (btf.percentile)

    @classmethod
    def solve(cls, percentiles, z: float, count: int, *, shift: float = 0.0, censored_low: float = 0.0,
              censored_high: float = 0.0, fallback: bool = False, exact_family: bool = False,
              beta1: float | None = None, beta2: float | None = None) -> FittedModel:
        """The record of a read, its model solved from the percentiles (what the host does with
        a packet's fields)."""
        pct = tuple(float(v) for v in percentiles)
        model = rebuild_model(pct, z, count, shift, censored_low, censored_high, fallback, exact_family)
        return cls(model, count, z, pct, beta1, beta2, shift, censored_low, censored_high, fallback, exact_family)


def rebuild_model(percentiles, z: float, count: int, shift: float = 0.0, censored_low: float = 0.0,
                  censored_high: float = 0.0, fallback: bool = False, exact_family: bool = False) -> Johnson:
    """The model of a read: model_from_percentiles with the fallback's probabilities."""
    normal_probs = fallback_probs(censored_low, censored_high) if fallback else None
    return model_from_percentiles(percentiles, z, count, shift=shift, normal_probs=normal_probs,
                                  exact_family=exact_family)


def rebuild(record: FittedModel, percentiles=None) -> Johnson:
    """The model from a record's (or the given, e.g. decoded) percentiles and its read."""
    return rebuild_model(record.percentiles if percentiles is None else percentiles, record.z, record.count,
                         record.shift, record.censored_low, record.censored_high, record.fallback,
                         record.exact_family)
