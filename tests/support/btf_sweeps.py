"""Databases of sweeps whose BTF is known: each region's model is a given smooth function of the
angles, stored as a robot would (jittered measured angles, commanded ones, camera settings,
dependence), for the BTF view, its leave-one-out and the export's tests."""
from __future__ import annotations

import math
from pathlib import Path
from typing import Callable

from btf.capture_settings import CaptureSettings
from btf.dependence import Dependence
from btf.johnson import Family, Johnson
from btf.record import FittedModel
from tools.store.database import Store

BANDS = ("R", "G", "B")


def linear_normal(el: float, az: float, band: int) -> Johnson:
    """Mean and sd linear in elevation: the quantile blend of two of them is the one between."""
    return Johnson.normal(60.0 + 1.2 * el + 10.0 * band, 6.0 + 0.1 * el)


def curved_su(el: float, az: float, band: int) -> Johnson:
    """A skewed SU whose location, scale and shape bend with elevation and azimuth."""
    t = math.radians(el)
    return Johnson(Family.SU, -1.0 + 0.8 * math.sin(t) + 0.002 * az, 1.2 + 0.6 * math.cos(t),
                   70.0 + 60.0 * math.sin(t) + 8.0 * band + 0.05 * az, 12.0 + 6.0 * math.cos(2 * t))


def write_sweep(db: Path, truth: Callable[[float, float, int], Johnson], elevations, azimuths=(0.0,),
                robot: str = "7", scene: str = "plate", labels=(1, 2), jitter: float = 0.3,
                first_sequence: int = 1) -> list[tuple[float, float]]:
    """One capture per (elevation, azimuth), models of every label and band from `truth` at the
    measured angles (label 2 a brighter copy); returns the measured angles."""
    measured = []
    with Store.open(db) as store:
        seq = first_sequence
        for az in azimuths:
            for k, el in enumerate(elevations):
                m_el, m_az = el + jitter * math.sin(3 * k + az), (az + jitter * (1 + math.cos(5 * k))) % 360
                m_el = min(m_el, 90.0)
                results = {}
                for label in labels:
                    for b in range(len(BANDS)):
                        model = truth(m_el, m_az, b)
                        if label == 2:
                            model = Johnson(model.family, model.gamma, model.delta, model.xi + 40.0, model.lam)
                        results[(label, b)] = FittedModel(model, 1000 + label, 0.5, (1.0, 2.0, 3.0, 4.0))
                store.add_capture(robot, seq, 1000.0 + seq, (el, az), (m_el, m_az), "rgb", BANDS, results,
                                  scene=scene, camera=CaptureSettings(exposure_us=5000.0, gain=2.0),
                                  dependence={1: Dependence((0.5, 0.4, 0.3), (0.9, 0.8, 0.6, 0.3), (0.9, 0.7, 0.5, 0.2))})
                measured.append((m_el, m_az))
                seq += 1
    return measured
