"""Hypothesis profiles: "default" sized for CI, "stress" for `make stress` (--hypothesis-profile=stress)."""
from __future__ import annotations

from hypothesis import HealthCheck, settings

settings.register_profile("default", max_examples=100, deadline=None)
settings.register_profile("stress", max_examples=5000, deadline=None,
                          suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
settings.load_profile("default")
