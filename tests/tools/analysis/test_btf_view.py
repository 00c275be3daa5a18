"""The BTF view: exact level probabilities of the interpolation synthesis draws from, moments on
the sensor's levels, and leave one out on sweeps whose truth is known."""
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from btf.johnson import Family, Johnson
from tests.support.btf_sweeps import curved_su, linear_normal, write_sweep
from tools.analysis import btf_loo, btf_view
from tools.analysis.synth import blend_pixels
from tools.store.database import Store

ELEVATIONS = (20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0)


def test_blend_probabilities_are_the_distribution_synthesis_draws():
    a, b = Johnson(Family.SU, -1.4, 1.5, 9.5, 3.8), Johnson(Family.SB, 0.3, 0.9, 20.0, 200.0)
    exact = btf_view.blend_probabilities([(0.3, a), (0.7, b)], 256)
    z = np.random.default_rng(1).standard_normal(2_000_000)
    drawn = np.bincount(blend_pixels([(0.3, a), (0.7, b)], 256)(z).astype(int), minlength=256) / z.size
    assert abs(exact.sum() - 1.0) < 1e-12
    assert np.abs(exact - drawn).sum() < 0.012  # the draw's own noise over 256 levels is about 0.009
    # two halves of one model are that model, level by level
    assert np.abs(btf_view.blend_probabilities([(0.5, a), (0.5, a)], 256) - a.level_probabilities(256)).sum() < 1e-12


@given(st.floats(0.0, 1.0), st.floats(-3, 3), st.floats(0.3, 4), st.floats(-50, 300), st.floats(0.5, 80),
       st.sampled_from([Family.SU, Family.SB, Family.SL, Family.SN]))
def test_blend_probabilities_are_finite_non_negative_and_sum_to_one(w, gamma, delta, xi, lam, family):
    if family is Family.SN:
        gamma, delta = 0.0, 1.0
    other = Johnson(family, gamma, delta, xi, lam)
    p = btf_view.blend_probabilities([(w, Johnson.normal(120.0, 15.0)), (1.0 - w, other)], 256)
    assert np.isfinite(p).all() and (p >= 0).all() and abs(p.sum() - 1.0) < 1e-9


def test_moments_of_a_normal_on_the_levels_and_of_a_point_mass():
    m = btf_view.moments(Johnson.normal(100.0, 10.0).level_probabilities(256))
    assert m.mean == pytest.approx(100.0, abs=1e-6)
    assert m.sd == pytest.approx(np.sqrt(100.0 + 1.0 / 12.0), rel=1e-4)  # rounding adds a uniform's variance
    assert abs(m.skewness) < 1e-6 and m.kurtosis == pytest.approx(3.0, abs=0.01)
    point = btf_view.moments(Johnson.constant(42.0).level_probabilities(256))
    assert (point.mean, point.sd, point.skewness, point.kurtosis) == (42.0, 0.0, None, None)


def _load(db, robot="7", scene="plate"):
    with Store.open(db) as store:
        return btf_view.load(store, robot, scene, "rgb")


def test_a_sweep_of_elevations_is_one_dimensional_however_the_tracker_jitters(tmp_path):
    write_sweep(tmp_path / "s.db", linear_normal, ELEVATIONS, jitter=0.8)
    btf = _load(tmp_path / "s.db")
    assert btf.varied == ("elevation",) and btf.one_dimensional
    assert len(btf.directions) == 8 and btf.regions() == [(lab, b) for lab in (1, 2) for b in range(3)]
    assert [len(s) for s in btf.series(1, 0, "elevation").values()] == [8]


def test_leave_one_out_recovers_a_btf_linear_in_angle_exactly_and_the_nearest_angle_does_not(tmp_path):
    write_sweep(tmp_path / "s.db", linear_normal, ELEVATIONS)
    btf = _load(tmp_path / "s.db")
    rows = btf_loo.leave_one_out(btf)
    assert len(rows) == 6 * 6  # 6 interior elevations for each of 2 regions x 3 bands
    assert {btf.directions[r.point].elevation for r in rows} == {d.elevation for d in btf.directions[1:-1]}
    for r in rows:
        # normals with mean and sd linear in angle: the blend of the neighbours is the truth
        assert r.interpolated < 1e-6 and r.nearest > 0.2, r
        assert len(r.neighbours) == 2


def test_leave_one_out_on_a_curved_btf_beats_the_nearest_angle_everywhere(tmp_path):
    write_sweep(tmp_path / "s.db", curved_su, ELEVATIONS)
    btf = _load(tmp_path / "s.db")
    rows = btf_loo.leave_one_out(btf)
    s = btf_loo.summary(rows)
    assert s.interior == 36 and s.better == 36
    assert s.interpolated_mean < 0.3 * s.nearest_mean


def test_curves_pass_through_the_measured_points(tmp_path):
    write_sweep(tmp_path / "s.db", curved_su, ELEVATIONS)
    btf = _load(tmp_path / "s.db")
    (key, pts), = btf.series(1, 2, "elevation").items()
    curve = btf_view.curve(btf, 1, 2, "elevation", pts, key)
    at = {round(c.angle, 9): c.moments for c in curve}
    for i in pts:
        m = btf_view.moments(btf.probabilities(i, 1, 2))
        assert at[round(btf.directions[i].elevation, 9)].mean == pytest.approx(m.mean, abs=1e-9)
    means = [c.moments.mean for c in curve]
    assert all(np.isfinite(means)) and len(curve) >= btf_view.CURVE_POINTS


def test_a_sweep_over_two_azimuths_is_interpolated_over_directions(tmp_path):
    write_sweep(tmp_path / "s.db", curved_su, ELEVATIONS[:-1], azimuths=(0.0, 90.0))
    btf = _load(tmp_path / "s.db")
    assert btf.varied == ("elevation", "azimuth") and not btf.one_dimensional
    assert sorted(btf.series(1, 0, "elevation")) == [(0.0,), (90.0,)]
    rows = btf_loo.leave_one_out(btf, 1, 0)
    # the inner elevations of both azimuths have neighbours on both sides; the ends do not
    assert len(rows) == 10, [btf_loo.angle_text(btf, r.point) for r in rows]
    assert btf_loo.summary(rows).better >= 8
    assert all(btf_loo.why_not(btf, r) for r in rows if not r.better)


def test_a_direction_measured_again_is_said_to_use_its_latest_capture(tmp_path, capsys):
    """The BTF keeps the latest capture at each direction: the table and the report say so where
    more were stored (three photographs at one angle read as one direction, unexplained)."""
    from tools.cli import main

    write_sweep(tmp_path / "s.db", linear_normal, ELEVATIONS)
    write_sweep(tmp_path / "s.db", linear_normal, ELEVATIONS[:2], first_sequence=100)  # two directions again
    btf = _load(tmp_path / "s.db")
    assert (len(btf.directions), btf.stored) == (len(ELEVATIONS), len(ELEVATIONS) + 2)
    assert main(["btf", "--db", str(tmp_path / "s.db")]) == 0
    assert f"{len(ELEVATIONS)} direction(s) (the latest capture at each, of {len(ELEVATIONS) + 2} stored)" in \
        capsys.readouterr().out.splitlines()[0]
