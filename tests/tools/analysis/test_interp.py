"""Interpolation over view and light directions: barycentric weights and quantile blending."""
from __future__ import annotations

import functools
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from btf.johnson import Johnson
from tools.analysis.interpolation import (
    Direction,
    DirectionInterpolator,
    _plane,
    models_by_direction,
    parse_direction,
    synthesize_at_direction,
    synthesize_blend,
)
from tools.analysis.synth import ExtrapolationWarning, MissingModels, neighbours
from tools.cli import main
from tools.data.datasets import Angles, write_rendered
from tools.data.images import read_image, read_mask
from tools.data.ingest import ingest
from tools.store.database import Store

GRID = [Direction(el, az) for el in (20.0, 50.0, 80.0) for az in range(0, 360, 45)] + [Direction(90.0, 0.0)]
GRID4 = [Direction(el, az, lel, laz) for el in (30.0, 60.0, 90.0) for az in (0.0, 120.0, 240.0)
         for lel in (30.0, 70.0) for laz in (0.0, 180.0)]


@functools.cache
def interpolator(grid: tuple[Direction, ...]) -> DirectionInterpolator:
    """One interpolator per grid, shared by a property's examples (its triangulation is built once)."""
    return DirectionInterpolator(list(grid))


def _position(d: Direction) -> np.ndarray:
    return _plane(np.array([d.angles()]))[0]


@settings(max_examples=60, deadline=None)
@given(el=st.floats(26.0, 90.0), az=st.floats(0.0, 360.0))
def test_view_weights_are_convex_and_reproduce_the_direction(el, az):
    q = Direction(el, az)
    interp = interpolator(tuple(GRID))
    with warnings.catch_warnings():
        warnings.simplefilter("error", ExtrapolationWarning)  # inside the octagon of the 20-degree ring: never warns
        w = interp.weights(q)
    assert all(v > 0 for _, v in w) and sum(v for _, v in w) == pytest.approx(1.0)
    assert len(w) <= 3
    blended = sum(v * _position(GRID[i]) for i, v in w)
    assert np.allclose(blended, _position(q), atol=1e-9)


@settings(max_examples=40, deadline=None)
@given(el=st.floats(30.0, 90.0), az=st.floats(0.0, 360.0), lel=st.floats(30.0, 70.0), laz=st.sampled_from([0.0, 180.0]))
def test_four_angle_weights_reproduce_view_and_light(el, az, lel, laz):
    q = Direction(el, az, lel, laz)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ExtrapolationWarning)  # the triangle of azimuths leaves corners out
        w = interpolator(tuple(GRID4)).weights(q)
    assert all(v > 0 for _, v in w) and sum(v for _, v in w) == pytest.approx(1.0)
    assert len(w) <= 5
    assert all(np.isfinite(v) for _, v in w)


def test_a_measured_direction_gets_all_the_weight():
    interp = DirectionInterpolator(GRID4)
    for k in (0, 7, len(GRID4) - 1):
        w = interp.weights(GRID4[k])
        assert len(w) == 1 and w[0][1] == pytest.approx(1.0) and GRID4[w[0][0]].angles() == GRID4[k].angles()


@pytest.mark.parametrize("angle", [25.0, 40.0, 55.0, 77.0])
def test_elevation_only_data_matches_the_one_angle_interpolation(angle):
    angles = [20.0, 45.0, 60.0, 90.0]
    w = dict(DirectionInterpolator([Direction(a) for a in angles]).weights(Direction(angle)))
    lo, hi, upper = neighbours(angles, angle)
    assert w.get(angles.index(hi), 0.0) == pytest.approx(upper)
    assert w.get(angles.index(lo), 0.0) == pytest.approx(1.0 - upper)


def test_angles_the_data_never_vary_are_skipped_with_a_warning():
    interp = DirectionInterpolator([Direction(a, 0.0, 45.0, 225.0) for a in (30.0, 60.0)])
    assert dict(interp.weights(Direction(45.0))) == pytest.approx({0: 0.5, 1: 0.5})  # no light given: fine
    with pytest.warns(ExtrapolationWarning, match="light elevation 45"):
        assert dict(interp.weights(Direction(45.0, 0.0, 70.0, 225.0))) == pytest.approx({0: 0.5, 1: 0.5})


def test_outside_the_measured_directions_clamps_to_their_hull_and_warns():
    interp = DirectionInterpolator([Direction(el, az) for el in (40.0, 80.0) for az in (0.0, 90.0)])
    with pytest.warns(ExtrapolationWarning, match="outside"):
        w = interp.weights(Direction(10.0, 45.0))
    assert sum(v for _, v in w) == pytest.approx(1.0) and all(v > 0 for _, v in w)


def test_duplicates_at_the_zenith_and_a_single_direction():
    zen = DirectionInterpolator([Direction(90.0, 0.0), Direction(90.0, 90.0), Direction(60.0, 0.0)])
    w = zen.weights(Direction(75.0, 0.0))
    assert sum(v for _, v in w) == pytest.approx(1.0)
    assert DirectionInterpolator([Direction(50.0, 10.0)]).weights(Direction(50.0, 10.0)) == [(0, 1.0)]


def test_light_must_match_what_was_measured():
    with pytest.raises(ValueError, match="vary in illumination"):
        DirectionInterpolator(GRID4).weights(Direction(45.0, 0.0))
    with pytest.raises(ValueError, match="no illumination"):
        DirectionInterpolator(GRID).weights(Direction(45.0, 0.0, 30.0, 0.0))
    with pytest.raises(ValueError, match="some measured directions"):
        DirectionInterpolator([Direction(40.0), Direction(50.0, 0.0, 30.0, 0.0)])


@pytest.mark.parametrize("text, problem", [("x", "expected"), ("1,2,3", "1, 2 or 4"), ("95", "outside"),
                                           ("45,0,30", "1, 2 or 4"), ("45,nan", "not finite")])
def test_bad_directions_are_named(text, problem):
    with pytest.raises(ValueError, match=problem):
        parse_direction(text)


def test_blend_moves_the_distribution_rather_than_mixing_it():
    mask = np.zeros((200, 200), np.uint8)
    lo, hi = {(0, 0): Johnson.normal(60.0, 6.0)}, {(0, 0): Johnson.normal(160.0, 6.0)}
    img = synthesize_blend(mask, [(0.25, lo), (0.75, hi)], np.random.default_rng(1))[..., 0].astype(float)
    assert img.mean() == pytest.approx(135.0, abs=0.5)
    assert img.std() == pytest.approx(6.0, abs=0.3)  # a mixture would have sd ~ 43
    with pytest.raises(MissingModels, match=r"label\(s\) \[1\]"):
        synthesize_blend(np.ones((4, 4), np.uint8), [(1.0, lo)], np.random.default_rng(1))


def test_held_out_light_is_predicted_better_than_by_either_neighbour(tmp_path):
    views = [Angles(el, 0.0, lel, 0.0) for el in (60.0, 90.0) for lel in (30.0, 80.0)]
    write_rendered(tmp_path / "d", "utia", views, size=(48, 48), seed=2)
    truth = Angles(75.0, 0.0, 55.0, 0.0)
    write_rendered(tmp_path / "t", "utia", [truth], size=(48, 48), seed=2)
    ingest(tmp_path / "d", "utia", tmp_path / "x.db", mask=tmp_path / "d" / "masks", workers=0)
    with Store.open(tmp_path / "x.db") as store:
        by_dir = models_by_direction(store)
    assert len(by_dir) == 4
    real_path = next((tmp_path / "t").glob("*.png"))
    real = read_image(real_path).astype(float)
    mask = read_mask(tmp_path / "t" / "masks" / real_path.name)
    synth = synthesize_at_direction(by_dir, mask, Direction(75.0, 0.0, 55.0, 0.0),
                                    np.random.default_rng(0)).astype(float)
    err = abs(synth.mean() - real.mean())
    for lel in (30.0, 80.0):  # nearest neighbours in light elevation
        near = synthesize_at_direction(by_dir, mask, Direction(60.0, 0.0, lel, 0.0), np.random.default_rng(0))
        assert err < abs(near.astype(float).mean() - real.mean())


def test_cli_synth_with_several_angles(tmp_path, capsys):
    views = [Angles(el, az, lel, 0.0) for el in (40.0, 90.0) for az in (0.0, 90.0) for lel in (30.0, 70.0)]
    write_rendered(tmp_path / "d", "utia", views, size=(24, 24))
    db = str(tmp_path / "x.db")
    ingest(tmp_path / "d", "utia", db, workers=0)
    mask = tmp_path / "m.png"
    from tools.data.images import write_mask
    write_mask(mask, np.zeros((24, 24), np.uint8))
    base = ["synth", "--db", db, "--mask", str(mask)]
    assert main(base + ["--angle", "60,45,50,0", "--out", str(tmp_path / "a.png")]) == 0
    assert main(base + ["--angle", "60", "--azimuth", "45", "--light-elevation", "50", "--light-azimuth", "0",
                        "--out", str(tmp_path / "b.png")]) == 0
    assert np.array_equal(read_image(tmp_path / "a.png"), read_image(tmp_path / "b.png"))
    capsys.readouterr()
    for extra, problem in [(["--angle", "60,45"], "vary in illumination"), (["--angle", "60,45,50"], "1, 2 or 4"),
                           (["--angle", "60,0,50,0", "--azimuth", "3"], "either"),
                           (["--angle", "60", "--light-elevation", "50"], "both")]:
        assert main(base + extra + ["--out", str(tmp_path / "c.png")]) == 2
        err = capsys.readouterr().err.strip()
        assert problem in err and len(err.splitlines()) == 1
    assert main(["synth", "--model", str(mask), "--mask", str(mask), "--angle", "60,0",
                 "--out", str(tmp_path / "c.png")]) == 2
    assert "need --db" in capsys.readouterr().err
