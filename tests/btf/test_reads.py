"""The read choice (btf.fit.reads): a handful of percentile fits per region, the nearest kept,
and no rule ever fitting a region worse than the plain percentile fit."""
import dataclasses

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from benchmarks.model_histograms import expected_histogram, histogram_l1, saturating
from btf.codec import Z_LADDER, default_codec, percentile_probs
from btf.fit.fitter import FrameFitter, fit_histogram, histogram_percentiles, plain_fit
from btf.fit.reads import GRID, TEMPLATE, min_count, phi, solve, template
from btf.johnson import Family, Johnson
from btf.percentile import model_from_percentiles
from btf.record import rebuild
from radio.packets import decode, encode_models

SETTINGS = settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
HEADER = dict(robot_id=1, seq=2, time=3.0, commanded=(10.0, 0.0), measured=(10.0, 0.0), feature_space="rgb")


@st.composite
def histograms(draw):
    """Arbitrary 8-bit histograms: noise, several bumps, stray pixels, piles at the limits."""
    kind = draw(st.sampled_from(["noise", "bumps", "pile"]))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    if kind == "noise":
        h = np.array(draw(st.lists(st.integers(0, 300), min_size=256, max_size=256)))
    else:
        h = np.zeros(256, dtype=np.int64)
        for _ in range(draw(st.integers(1, 3))):
            centre, sd = draw(st.floats(0, 255)), draw(st.floats(0.3, 40))
            v = np.clip(np.rint(rng.normal(centre, sd, draw(st.integers(10, 20_000)))), 0, 255)
            h += np.bincount(v.astype(np.int64), minlength=256)
        for level in draw(st.lists(st.integers(0, 255), max_size=3)):
            h[level] += 1
        if kind == "pile":
            h[draw(st.sampled_from([0, 255]))] += draw(st.integers(10, 20_000))
    if not h.any():
        h[7] = 1
    return h


@SETTINGS
@given(histograms())
def test_no_fit_is_worse_than_the_plain_percentile_fit(h):
    r = fit_histogram(h)
    assert histogram_l1(r.model, h) <= histogram_l1(plain_fit(h), h) + 1e-4


def test_the_plain_fit_is_slifker_shapiro_at_the_counts_z():
    truth = Johnson(Family.SU, -0.6, 1.6, 110.0, 22.0)
    h = expected_histogram(truth, 200_000)
    m = plain_fit(h)
    assert m.family is Family.SU
    u = np.linspace(0.02, 0.98, 49)
    assert np.max(np.abs(m.ppf(u) - truth.ppf(u))) < 1.0


def test_a_frame_and_one_histogram_choose_the_same_read():
    rng = np.random.default_rng(3)
    frame = np.stack([np.clip(np.rint(rng.gamma(a, 9, (200, 300)) + 20 * a), 0, 255) for a in (1, 2, 5)],
                     axis=-1).astype(np.uint8)
    labels = (np.arange(300)[None, :] * 3 // 300 + np.zeros((200, 1), dtype=int)).astype(np.uint8)
    fitter = FrameFitter(3, 3)
    fitter.add(frame, labels)
    for (lab, band), r in fitter.fit().items():
        alone = fit_histogram(fitter.counts[lab, band])
        assert alone == r


def test_skewed_and_long_tailed_regions_choose_other_reads_and_fit_better():
    # a skewed bulk with a long tail: the plain read cannot see both; another spread or centre can
    rng = np.random.default_rng(11)
    v = np.concatenate([rng.gamma(1.5, 6, 60_000), 60 + rng.normal(0, 12, 8_000)])
    h = np.bincount(np.clip(np.rint(v + 30), 0, 255).astype(np.int64), minlength=256)
    r = fit_histogram(h)
    assert (r.z, r.shift) != (Z_LADDER[0], 0.0)
    assert histogram_l1(r.model, h) < 0.8 * histogram_l1(plain_fit(h), h)
    assert rebuild(r) == r.model


def test_a_single_stray_pixel_does_not_move_a_bounded_support():
    # A bright region bounded near 221 with one stray pixel at 143 among 18,545: the stray level
    # gets what the model gives it (here nothing), and the bulk keeps its fit.
    truth = Johnson(Family.SB, 0.4, 0.9, 219.0, 37.0)
    h = expected_histogram(truth, 18_544)
    h[143] += 1
    r = fit_histogram(h)
    without = h.copy()
    without[143] = 0
    assert histogram_l1(r.model, h) <= histogram_l1(fit_histogram(without).model, without) + 2.5 / h.sum()
    assert float(r.model.ppf(0.001)) > 200.0
    assert r.model.level_probabilities()[143] < 1e-6


def test_a_stray_level_outside_a_bounded_support_gets_zero_and_sampling_stays_in_range():
    h = np.zeros(256, dtype=np.int64)
    h[98:103] = [10, 3000, 100_000, 3000, 10]
    h[200] = 1
    r = fit_histogram(h)
    p = r.model.level_probabilities()
    assert np.isfinite(p).all() and not np.any(np.signbit(p)) and p.sum() == pytest.approx(1.0)
    assert p[200] < 1e-12
    px = r.model.sample_pixels(100_000, np.random.default_rng(0))
    assert 95 <= px.min() and px.max() <= 105


def test_censored_regions_still_compare_their_placement_and_fallback():
    rng = np.random.default_rng(2)
    shape = Johnson(Family.SU, 0.8, 1.5, 0.0, 20.0)
    h = np.bincount(np.clip(np.rint(saturating(shape, high=0.3).sample(50_000, rng, dtype=np.float64)), 0, 255)
                    .astype(np.int64), minlength=256)
    r = fit_histogram(h)
    assert r.censored_high == pytest.approx(0.3, abs=0.02)
    assert histogram_l1(r.model, h) <= histogram_l1(plain_fit(h), h)
    assert histogram_l1(r.model, h) < 0.06


def test_the_choice_travels_and_the_host_rebuilds_the_same_models():
    rng = np.random.default_rng(5)
    fits = {}
    for lab, tail in enumerate((0, 8_000, 20_000)):  # a skewed bulk, with a tail or without
        v = np.concatenate([rng.gamma(1.5, 6, 60_000), 60 + rng.normal(0, 12, tail)]) + 30 + 10 * lab
        for band in range(3):
            h = np.bincount(np.clip(np.rint(v + 5 * band), 0, 255).astype(np.int64), minlength=256)
            fits[(lab, band)] = fit_histogram(h)
    assert len({(f.z, f.shift) for f in fits.values()}) > 1
    packet = decode(encode_models(fits, bands=("R", "G", "B"), **HEADER))
    for key, fit in fits.items():
        assert packet.models[key] == fit.model


def _read(fit, z: float, shift: float):
    """`fit`'s histogram as if read at (z, shift)."""
    counts = expected_histogram(Johnson.normal(100, 10), fit.count)
    pct = default_codec(0.0, 1.0, 256).snap(histogram_percentiles(counts, percentile_probs(z, shift)))
    return dataclasses.replace(fit, model=model_from_percentiles(pct, z, fit.count, shift=shift), z=z,
                               percentiles=pct, shift=shift, exact_family=False)


def test_a_read_byte_costs_one_byte():
    f = fit_histogram(expected_histogram(Johnson.normal(100, 10), 50_000))
    base = {(0, b): _read(f, Z_LADDER[0], 0.0) for b in range(3)}
    other = {**base, (0, 1): _read(f, 0.3, 0.5)}
    a = encode_models(base, bands=("R", "G", "B"), **HEADER)
    b = encode_models(other, bands=("R", "G", "B"), **HEADER)
    assert len(b) - len(a) == 2  # one byte of 2-bit marks, one read byte
    assert decode(b).models[(0, 1)] == other[(0, 1)].model


def test_reads_that_would_rest_on_too_few_pixels_are_not_tried():
    t = template(Z_LADDER[0])
    for (z, code), need in zip(GRID, t.need[2:TEMPLATE]):
        assert need == min_count(z, code)
        tail = min(phi(np.array([code / 32 - 3 * z], np.float32))[0], phi(np.array([-code / 32 - 3 * z], np.float32))[0])
        assert need * tail == pytest.approx(8, rel=0.02)
    few = np.zeros(256, dtype=np.int64)
    few[100:110] = 10
    r = fit_histogram(few)
    assert few.sum() * phi(np.array([r.shift - 3 * r.z], np.float32))[0] >= 7.9


def test_the_vector_solve_matches_the_scalar_closed_forms():
    rng = np.random.default_rng(9)
    pct = np.sort(rng.uniform(0, 255, (400, 4)), axis=1)
    z = rng.choice([0.3, 0.524, 0.7], 400)
    shift = rng.choice([0.0, -0.5, 0.5], 400)
    band = rng.choice([0.0, 0.05], 400)
    fam, gamma, delta, xi, lam = solve(pct, z, shift, band)
    names = ["SN", "SL", "SU", "SB", "CONST"]
    for i in range(400):
        m = model_from_percentiles(tuple(pct[i]), float(z[i]), 6400, shift=float(shift[i]),
                                   exact_family=band[i] == 0.0)
        assert m.family.value == names[fam[i]]
        got = (gamma[i], delta[i], xi[i], lam[i])
        assert got == pytest.approx((m.gamma, m.delta, m.xi, m.lam), rel=1e-9, abs=1e-9)


def test_the_ranking_cdf_is_accurate_to_3e_7():
    z = np.linspace(-40, 40, 20001)
    exact = np.asarray(Johnson.normal(0.0, 1.0).cdf(z))
    assert np.max(np.abs(phi(z.astype(np.float32)) - exact)) < 3e-7


def test_a_small_region_keeps_the_plain_read_rather_than_chase_counting_noise():
    # 150 pixels of an SU: without the noise margin the other reads fit each draw's noise and
    # the mean quantile error against the true curve grows from 1.66 to 1.88 gray (60 draws)
    truth = Johnson(Family.SU, 0.5, 1.5, 100.0, 20.0)
    u = np.linspace(0.02, 0.98, 49)
    ours, plain = [], []
    for seed in range(60):
        x = truth.sample(150, np.random.default_rng(seed), dtype=np.float64)
        h = np.bincount(np.clip(np.rint(x), 0, 255).astype(int), minlength=256)
        ours.append(np.mean(np.abs(fit_histogram(h).model.ppf(u) - truth.ppf(u))))
        plain.append(np.mean(np.abs(plain_fit(h).ppf(u) - truth.ppf(u))))
    assert np.mean(ours) <= 1.02 * np.mean(plain)
