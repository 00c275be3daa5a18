"""A capture carries each region's observed levels, and its grain and band correlation when
`[features] dependence` is on."""
from __future__ import annotations

import numpy as np
import pytest

from hal.interfaces import ViewAngles
from onboard import config
from onboard.capture.pipeline import Pipeline
from onboard.link.bodies import models_body
from radio import packets as pk
from tests.support.robots import robot_toml


def _image(h: int, w: int, seed: int) -> np.ndarray:
    """Three bands sharing a field correlated along rows (r(0, 1) = 0.8)."""
    e = np.random.default_rng(seed).standard_normal((h, w))
    f = np.empty_like(e)
    f[:, 0] = e[:, 0]
    for c in range(1, w):
        f[:, c] = 0.8 * f[:, c - 1] + 0.6 * e[:, c]
    return np.clip(np.rint(120 + 25 * f[..., None] + np.arange(3) * 10), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("on", [True, False])
def test_a_capture_sends_levels_always_and_grain_only_when_configured(tmp_path, on):
    path = tmp_path / "robot.toml"
    path.write_text(robot_toml({"features": {"dependence": on}}))
    img = _image(96, 128, seed=8)
    labels = np.zeros(img.shape[:2], np.uint8)
    labels[:, 64:] = 1
    cap = Pipeline(config.load(path), None, lambda f, fr, m: (labels, False)).process(img, ViewAngles(90), ViewAngles(90))
    _, body = models_body(1, 1, 0.0, "rgb", cap)
    got = pk.decode(body).dependence
    assert set(got) == {0, 1}
    for lab, cols in ((0, slice(0, 64)), (1, slice(64, 128))):
        region = img[:, cols].reshape(-1, 3)
        assert got[lab].lo == tuple(region.min(axis=0).tolist()) and got[lab].hi == tuple(region.max(axis=0).tolist())
        assert got[lab].measured == on
    if on:
        assert got[0].acf[0][0] == pytest.approx(0.8, abs=0.08)  # lag (0, 1)
