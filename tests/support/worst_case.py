"""The largest capture a robot can make: 256 regions of 16 bands of a 16-bit sensor, every model
read another way than its region's (so each carries its full record), with the observed levels,
grain and band correlation of every region and a camera section with a reference and brackets."""
from __future__ import annotations

import numpy as np

from btf.capture_settings import CaptureSettings
from btf.codec import Z_LADDER
from btf.dependence import RADIUS, Dependence, window_size
from btf.record import FittedModel
from hal.interfaces import ViewAngles
from onboard.capture.pipeline import FittedView
from radio import packets as pk

LABELS, BANDS, LEVELS = 256, 16, 65536


def worst_view() -> FittedView:
    """The worst-case capture, region `label` of 100 + label pixels (the smallest is label 0)."""
    bands = tuple(f"b{i}" for i in range(BANDS))
    results = {}
    for label in range(LABELS):
        for band in range(BANDS):
            base = 100.0 * label + 7 * band
            pct = (base + 1000.0, base + 3000.25, base + 5000.5, base + 9000.75)
            results[(label, band)] = FittedModel.solve(pct, Z_LADDER[(label + band) % len(Z_LADDER)], 100 + label,
                                                       shift=3 / 32, censored_low=0.01, censored_high=0.02)
    corr = tuple([0.1] * (BANDS * (BANDS - 1) // 2))
    acf = (tuple([0.5] * window_size(RADIUS)),)  # the robot's window, one row shared by the bands
    dependence = {label: Dependence(corr, acf, RADIUS, tuple(range(BANDS)), tuple(LEVELS - 1 - b for b in range(BANDS)))
                  for label in range(LABELS)}
    camera = CaptureSettings(exposure_us=8000.0, gain=2.0, white_balance_kelvin=5500.0, sensor_temperature_c=40.0,
                             reference=tuple([300.0] * BANDS), reference_clipped=0.1, brackets=(4000.0, 2000.0),
                             bracketed={label: 1 + label % 2 for label in range(0, LABELS, 3)})
    labels = np.arange(LABELS, dtype=np.uint8).reshape(16, 16)
    return FittedView(ViewAngles(60.0, 10.0), ViewAngles(60.2, 10.1), bands, LEVELS, results, (), labels,
                      dependence=dependence, camera=camera)


def worst_models() -> pk.ModelsPacket:
    """The worst-case capture as one MODELS packet, every region in it (too large to encode)."""
    cap = worst_view()
    return pk.models_packet(cap.results, robot_id=1, seq=1, time=1.7e9, commanded=(60.0, 10.0),
                            measured=(60.2, 10.1), feature_space="raw", bands=cap.band_names, levels=LEVELS,
                            dependence=cap.dependence, camera=cap.camera)
