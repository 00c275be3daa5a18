"""The Section 2 resolution rule: bounds and verdicts."""
import math

import pytest

from tools.analysis.resolve import Verdict, bounds


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


# --- the paper's Section 2 view -----------------------------------------------------------
PAPER_INPUTS = ("--grain-mm", "0.02", "--wavelength-nm", "700", "--pixel-per-facet", "1000",
                "--facet-per-wavelength2", "1000", "--rays-per-facet", "100")


def _resolve(capsys, *argv):
    from tools.cli import main

    code = main(["resolve", *argv])
    out, err = capsys.readouterr()
    return code, out, err


def test_paper_section_2_numbers_from_its_inputs(capsys):
    """Sand: 0.02 mm grains at 700 nm, factors 1000 (pixel/facet), 1000 (facet/lambda^2), 100 rays."""
    import json

    code, out, _ = _resolve(capsys, *PAPER_INPUTS, "--json")
    assert code == 0
    doc = json.loads(out)
    paper = {b["name"]: b for b in doc["paper"]["bounds"]}
    assert doc["paper"]["pixel_area_nm2"] == pytest.approx(4e8)
    assert paper["facet_diameter"]["value"] == pytest.approx(356.82, abs=0.005)
    assert paper["facet_diameter"]["unit"] == "nm" and paper["facet_diameter"]["limit"] == "upper"
    assert paper["wavelength_from_pixel"]["value"] == pytest.approx(2.0)
    assert paper["grain_size"]["value"] == pytest.approx(124888.688, abs=5e-4)
    assert paper["grain_size"]["limit"] == "lower"
    assert paper["wavelength_from_grain"]["value"] == pytest.approx(112.1, abs=0.05)
    assert all(b["rules_out_facets"] for b in paper.values())
    assert doc["paper"]["verdict"] == "statistical"
    # each bound names its formula and the inputs that went into it
    assert paper["grain_size"]["inputs"] == {"wavelength_nm": 700.0, "pixel_per_facet": 1000.0,
                                             "facet_per_wavelength2": 1000.0, "rays_per_facet": 100.0}
    assert "lambda" in paper["wavelength_from_grain"]["formula"]
    # the diffraction and smoothness bounds stay, as the physical view
    assert doc["physical"]["rayleigh_height_nm"] == pytest.approx(87.5)

    code, text, _ = _resolve(capsys, *PAPER_INPUTS)
    assert code == 0
    for number in ("356.82 nm", "2.00 nm", "0.125 mm", "124888.688 nm", "112.10 nm"):
        assert number in text, number
    paper_part, physical_part = text.split("\nphysical view")
    assert "paper view" in paper_part and "356.82" in paper_part and "Rayleigh" in physical_part
    assert "verdict (paper view): statistical" in paper_part


def test_paper_inputs_are_the_default_worked_example(capsys):
    explicit = _resolve(capsys, *PAPER_INPUTS, "--json")[1]
    assert _resolve(capsys, "--json")[1] == explicit


def test_paper_view_allows_facets_for_centimetre_pebbles_in_visible_light():
    from tools.analysis.resolve import paper_bounds

    p = paper_bounds(10.0, 500.0)  # 10 mm pebbles at 500 nm: dA = 1e14 nm^2
    assert p.verdict is Verdict.FACET
    assert not any(b.rules_out_facets for b in p.bounds)
    assert {b.name: b.value for b in p.bounds}["wavelength_from_pixel"] == pytest.approx(1000.0)


def test_paper_bounds_follow_the_factors():
    from tools.analysis.resolve import paper_bounds

    base = {b.name: b.value for b in paper_bounds(0.02, 700.0).bounds}
    fewer = {b.name: b.value for b in paper_bounds(0.02, 700.0, rays_per_facet=1.0).bounds}
    assert fewer["wavelength_from_pixel"] == pytest.approx(10 * base["wavelength_from_pixel"])
    assert fewer["grain_size"] == pytest.approx(base["grain_size"] / 10)
    assert fewer["facet_diameter"] == pytest.approx(base["facet_diameter"])  # dA / pixel-per-facet only


@pytest.mark.parametrize("kw", [dict(pixel_per_facet=0), dict(facet_per_wavelength2=float("inf")),
                                dict(rays_per_facet=-1), dict(grain_mm=float("nan"))])
def test_paper_factors_must_be_positive_numbers(kw):
    from tools.analysis.resolve import paper_bounds

    with pytest.raises(ValueError, match="positive"):
        paper_bounds(**(dict(grain_mm=0.02, wavelength_nm=700.0) | kw))


def test_paper_bounds_beyond_floating_point_are_refused():
    from tools.analysis.resolve import paper_bounds

    with pytest.raises(ValueError, match="too far apart"):
        paper_bounds(1e300, 700.0, pixel_per_facet=1e300)
