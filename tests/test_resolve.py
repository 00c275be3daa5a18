"""The Section 2 resolution rule: bounds and verdicts."""
import math

import pytest

from tools.resolve import Verdict, bounds


def test_bounds_for_sand_at_700nm():
    b = bounds(0.02, 700)
    assert b.rayleigh_height_nm == pytest.approx(87.5)
    assert b.fraunhofer_height_nm == pytest.approx(21.875)
    assert b.diffraction_limit_nm == pytest.approx(350.0)
    # The widest flat facet: its sagitta on a 20 um sphere equals the Rayleigh height.
    w, r = b.max_flat_facet_nm, 10000.0
    assert r - math.sqrt(r * r - (w / 2) ** 2) == pytest.approx(87.5)
    assert b.nyquist_pixel_mm == pytest.approx(0.01)
    assert b.verdict is None


@pytest.mark.parametrize("pixel, verdict", [(0.005, Verdict.FACET), (0.05, Verdict.MIXED),
                                            (0.125, Verdict.STATISTICAL)])
def test_verdict_follows_pixel_footprint(pixel, verdict):
    assert bounds(0.02, 700, pixel).verdict is verdict


def test_grains_below_the_diffraction_limit_are_never_facets():
    assert bounds(0.0001, 700, 0.00001).verdict is Verdict.UNRESOLVABLE


def test_incidence_relaxes_smoothness():
    assert bounds(0.02, 700, incidence_deg=60).rayleigh_height_nm == pytest.approx(175.0)


@pytest.mark.parametrize("kw", [dict(grain_mm=0), dict(wavelength_nm=float("nan")), dict(pixel_mm=-1),
                                dict(incidence_deg=90)])
def test_bad_numbers_are_refused(kw):
    args = dict(grain_mm=0.02, wavelength_nm=700) | kw
    with pytest.raises(ValueError):
        bounds(**args)


@pytest.mark.parametrize("grain, wavelength, pixel", [(1e308, 1e-308, None), (0.02, 700, 1e300),
                                                       (1e-300, 1e300, 1e300), (1e300, 1e-300, 1e-300)])
def test_sizes_beyond_floating_point_are_refused_not_inf(grain, wavelength, pixel):
    with pytest.raises(ValueError, match="too far apart"):
        bounds(grain, wavelength, pixel)


def test_large_but_representable_grains_give_finite_bounds():
    b = bounds(1e301, 700.0, 1e302)  # D h overflows float64; sqrt(h) sqrt(D - h) does not
    assert math.isfinite(b.max_flat_facet_nm) and b.max_flat_facet_nm > 0
    assert b.grains_per_pixel == pytest.approx(100.0)
