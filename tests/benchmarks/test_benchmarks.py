"""Each benchmark module's --quick path runs on tiny inputs and writes well-formed results."""
from __future__ import annotations

import math
import re

import numpy as np
import pytest

from benchmarks.__main__ import discover, main, run_one
from benchmarks.as99_moment_fit import MomentFitError, fit_moments
from benchmarks.common import Context, Saving, Section, paired_rounds
from benchmarks.curve_moments import shape_moments, solve_shape
from benchmarks.stability_grid import SATURATIONS, Point, Saturation, curve, grid
from benchmarks.stability_score import METHODS, Cause, Size, Truth, diagnose, evaluate, fit_and_score, score
from btf.johnson import Family, Johnson

EXPECTED = {"bracketing", "core", "dependence", "hostile", "hostmem", "ingest", "onboard", "page", "peers", "runtime", "sampling", "scene", "stability",
            "startup",
            "subsample", "synth", "texture", "wire", "link", "failsafe"}


def test_every_expected_benchmark_is_discovered():
    assert EXPECTED <= set(discover())


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    """Each module's --quick run, once per test session: (markdown text, plot directory)."""
    runs: dict[str, tuple[str, object]] = {}

    def get(name: str) -> tuple[str, object]:
        if name not in runs:
            out = tmp_path_factory.mktemp(f"bench_{name}")
            sections = run_one(name, Context(quick=True, out=out))
            assert sections and all(isinstance(s, Section) and s.title for s in sections)
            runs[name] = ("\n".join(line for s in sections for line in s.lines), out)
        return runs[name]
    return get


def tables(text: str) -> list[list[str]]:
    """Runs of consecutive markdown table rows."""
    out: list[list[str]] = []
    prev = False
    for line in text.splitlines():
        row = line.startswith("|")
        if row and not prev:
            out.append([])
        if row:
            out[-1].append(line)
        prev = row
    return out


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_quick_run_gives_titled_sections_with_tables_and_existing_plots(name, quick):
    text, out = quick(name)
    # Python prints a NaN or infinite figure as nan/inf; failures are named in words instead
    assert not re.search(r"\b-?(nan|inf)\b", text), text
    for table in tables(text):
        assert len(table) >= 3 and set(table[1]) <= set("|-: ")
        for row in table:
            assert row.endswith("|") and row.count("|") == table[0].count("|"), row
    for image in re.findall(r"!\[[^]]*\]\(([^)]+)\)", text):
        assert (out / image).stat().st_size > 1000


def test_dependence_quick_run_reports_anchor_rows_against_the_fit_and_the_bytes(quick):
    text, _ = quick("dependence")
    assert re.search(r"^\| 2048 \| \d\.\d{3} \| \d\.\d{3} \| \d+\.\d\dx \| \d+\.\d\dx \|$", text, re.M)
    assert re.search(r"\*\*dependence pass / fit at \d+ anchors: \d+\.\d\dx\*\*", text)
    assert re.search(r"\| \d+ B \| \d+ B \| \+\d+ B \|", text)


def test_texture_quick_run_judges_each_photograph_and_times_both_paths(quick):
    text, out = quick("texture")
    rows = [r for r in tables(text)[0][2:]]
    assert [r.split("|")[1].strip() for r in rows] == ["grass", "coffee"]
    assert re.search(r"\*\*correlated / independent = \d+\.\d\dx\*\*", text)
    assert "one region" in text and "four quadrants" in text
    assert re.search(r"outside the observed levels: worst region 0\.000%", text)  # never a level a region lacked
    assert (out / "texture_coffee.png").stat().st_size > 1000


def test_ingest_quick_run_times_every_executor_on_the_same_database(quick):
    text, _ = quick("ingest")
    rows = [r for r in tables(text)[0][2:]]
    assert [r.split("|")[1].strip() for r in rows] == [
        "in-process", "process pool, 1 worker", "process pool, 2 workers", "Dask LocalCluster, 2 worker processes"]
    for r in rows:
        assert float(r.split("|")[3]) > 0  # images/s
    assert "1.00x" in rows[1]  # the pool of one is the unit


def test_ingest_quick_run_times_the_store_with_and_without_a_sync_at_each_commit(quick):
    text, _ = quick("ingest")
    rows = tables(text)[1][2:]
    modes = [(r.split("|")[1].strip(), r.split("|")[3].strip()) for r in rows]
    assert modes == [("NORMAL", "no"), ("FULL", "yes"), ("FULL", "yes"), ("FULL", "yes")]
    assert all(float(r.split("|")[4]) > 0 for r in rows)  # captures/s
    assert re.search(r"radio carries at most \d+ captures/s", text)


def test_runner_writes_results_headed_by_the_machine(tmp_path, capsys):
    assert main(["wire", "--quick", "--out", str(tmp_path)]) == 0
    text = (tmp_path / "RESULTS.md").read_text()
    assert text.startswith("# Benchmark results")
    assert "- CPU:" in text and "- cores:" in text and "## Wire" in text


def test_a_benchmark_run_alone_replaces_only_its_own_sections(tmp_path, monkeypatch, capsys):
    import benchmarks.__main__ as runner

    old = ["# Benchmark results", "", "- CPU: then", "", "## Core: fit", "", "old core", "",
           "## Wire: bytes", "", "old wire", "", "## Zeta", "", "old zeta", "", "_Whole run: 900 s._", ""]
    (tmp_path / "RESULTS.md").write_text("\n".join(old))
    monkeypatch.setattr(runner, "run_one", lambda name, ctx: [Section("Wire: bytes", ["new wire"]),
                                                              Section("Wire: more", ["added"])])
    assert main(["wire", "--out", str(tmp_path)]) == 0
    text = (tmp_path / "RESULTS.md").read_text()
    assert "old wire" not in text and text.count("## ") == 4
    assert text.index("- CPU: then") < text.index("old core") < text.index("new wire") < text.index("old zeta")
    assert text.index("old zeta") < text.index("## Wire: more") < text.index("_Whole run: 900 s._")
    assert text.count("re-run alone") == 2 and "`python -m benchmarks wire`" in text
    # a smoke test without --out goes to a temporary directory, never over the measured figures
    monkeypatch.setattr(runner.tempfile, "gettempdir", lambda: str(tmp_path / "tmp"))
    assert main(["wire", "--quick"]) == 0
    assert (tmp_path / "tmp" / "btfscout-bench-quick" / "RESULTS.md").is_file()
    assert (tmp_path / "RESULTS.md").read_text() == text


def test_runner_refuses_an_unknown_benchmark(tmp_path, capsys):
    assert main(["nosuch", "--out", str(tmp_path)]) == 2
    assert "no benchmarks/bench_nosuch.py" in capsys.readouterr().err


@pytest.mark.parametrize("family,gamma,delta", [
    (Family.SU, 0.5, 1.3), (Family.SU, -1.0, 2.0), (Family.SU, 0.0, 1.5),
    (Family.SB, 0.5, 1.3), (Family.SB, -1.0, 0.7), (Family.SL, 0.3, 1.5)])
def test_moments_reference_recovers_the_curve_from_its_exact_moments(family, gamma, delta):
    mean, var, skew, b2 = shape_moments(family, gamma, delta)
    model = fit_moments(100.0 + 20.0 * mean, 20.0 * math.sqrt(var), skew, b2)
    assert model.family is family
    u = np.linspace(0.02, 0.98, 25)
    truth = 100.0 + 20.0 * _standard_ppf(family, gamma, delta, u)
    assert np.max(np.abs(model.ppf(u) - truth)) < 1e-4


def _standard_ppf(family, gamma, delta, u):
    from btf.johnson import Johnson
    return Johnson(family, gamma, delta, 0.0, 1.0).ppf(u)


def test_moments_reference_refuses_moments_below_the_impossible_boundary():
    with pytest.raises(MomentFitError, match="beta1 \\+ 1"):
        fit_moments(0.0, 1.0, 1.0, 1.5)


def test_solve_shape_hits_the_requested_betas():
    g, d = solve_shape(Family.SB, 0.7, 3.0)
    _, _, skew, b2 = shape_moments(Family.SB, g, d)
    assert skew == pytest.approx(0.7, abs=1e-6) and b2 == pytest.approx(3.0, abs=1e-5)


def test_saving_is_the_median_of_paired_rounds_with_its_quartiles():
    base = np.full(9, 10.0)
    rule = np.array([5.0, 5.5, 6.0, 4.5, 5.0, 5.2, 4.8, 5.1, 4.9])
    s = Saving.of(rule, base)
    assert s.median == pytest.approx(0.5) and s.q25 < s.median < s.q75 and s.rounds == 9
    assert s.measurable and s.text().startswith("50% (quartiles")


def test_saving_whose_quartiles_straddle_zero_is_no_measurable_difference():
    base = np.full(8, 10.0)
    rule = np.array([8.0, 12.0, 9.5, 10.5, 11.0, 9.0, 10.2, 9.8])
    s = Saving.of(rule, base)
    assert not s.measurable
    assert s.text().startswith("no measurable difference (median")


def test_paired_rounds_time_every_function_every_round_in_alternating_order():
    calls: list[str] = []
    times = paired_rounds({"a": lambda: calls.append("a"), "b": lambda: calls.append("b")}, repeat=4)
    assert calls == ["a", "b"] + ["a", "b", "b", "a"] * 2  # one warm-up each, then alternating rounds
    assert all(t.shape == (4,) and np.all(t >= 0) for t in times.values())


def test_saturation_moves_the_fraction_beyond_the_top_or_below_the_bottom_level():
    c = curve(0.0, 3.0)
    top, bottom = Saturation(0.25).apply(c), Saturation(0.25, top=False).apply(c)
    assert 1.0 - float(top.cdf(254.5)) == pytest.approx(0.25, abs=1e-9)
    assert float(bottom.cdf(0.5)) == pytest.approx(0.25, abs=1e-9)
    assert Saturation().apply(c) is c and Saturation().label == "none"
    assert (Saturation(0.1).label, Saturation(0.4, top=False).label) == ("10% at 255", "40% at 0")


def test_grid_curves_span_the_8_bit_range_and_the_band_marks_only_points_near_the_boundary():
    pts = grid((0.0, 1.0))
    for p in pts:
        assert np.allclose(p.curve.ppf([0.001, 0.999]), [20.0, 235.0], atol=1e-6)
        assert p.near_boundary == (p.beta2 < p.beta1 + 1.2)
    assert {p.where for p in pts if p.near_boundary} == {"near beta2 = beta1 + 1"}


def test_score_of_the_true_curve_is_zero_and_a_shift_counts_only_inside_the_uncensored_levels():
    truth_curve = Saturation(0.4).apply(curve(0.0, 3.0))
    truth = Truth.of(truth_curve)
    same = score(truth_curve, truth)
    assert same.worst == pytest.approx(0.0, abs=1e-9) and same.w1 == pytest.approx(0.0, abs=1e-9)
    assert same.l1 == pytest.approx(0.0, abs=1e-12)
    moved = score(Johnson.normal(truth_curve.xi + 2.0, truth_curve.lam), truth)
    assert moved.worst == pytest.approx(2.0, abs=1e-6)
    # W1 of the clipped distributions: the 40% piled at 255 in both costs nothing
    assert 1.0 < moved.w1 < 1.5 and moved.l1 > 0.01


def test_fit_and_score_names_a_failed_moment_fit_and_the_percentile_fit_stays_finite():
    counts = np.zeros(256, np.int64)
    counts[[40, 200]] = 500  # a two-point sample: beta2 = beta1 + 1, no Johnson curve has its moments
    truth = Truth.of(curve(0.0, 3.0))
    assert fit_and_score("moments", counts, truth).failure == "no curve (sample at beta2 <= beta1 + 1)"
    pct = fit_and_score("percentile", counts, truth)
    assert not pct.failure and all(math.isfinite(v) for v in (pct.worst, pct.w1, pct.l1))


def test_censoring_recovers_a_saturated_normal_that_the_uncensored_fit_misses():
    p = next(q for q in grid((0.0,)) if q.where == "normal point")
    sizes = [Size(1000), Size(100_000, expected=True)]
    res = evaluate(p, sizes, np.random.default_rng(0))
    assert len(res) == len(METHODS) * len(sizes) * len(SATURATIONS)
    assert not any(s.failure for (m, _, _), s in res.items() if m != "moments")
    for sat in SATURATIONS[1:]:
        cen, unc = res[("percentile", sizes[1], sat)], res[("uncensored", sizes[1], sat)]
        assert cen.worst < 0.5 and cen.l1 < 0.01  # shifted or the (exact) fallback normal
        # up to 25% the off-centre reads keep clear of the pile even without censoring; at 40%
        # only the censored placement or the fallback does
        if sat.fraction >= 0.4:
            assert unc.worst > 5.0 and unc.l1 > 0.1


def test_quick_stability_map_has_the_saturation_axis_and_no_percentile_failure(quick):
    text, out = quick("stability")
    assert re.search(r"Failures \(NaN, exception, no curve\): percentile 0, uncensored 0, moments \d+\.", text)
    header = tables(text)[0][0]
    assert all(label in header for label in ("none", "10% at 255", "40% at 255", "10% at 0", "40% at 0"))
    assert "**What censoring buys**" in text and "**Near the boundary**" in text
    assert (out / "stability_percentile.png").stat().st_size > 1000


def test_quick_stability_cells_give_median_90th_percentile_and_worst_in_order(quick):
    text, _ = quick("stability")
    cell = re.compile(r"^(\d+\.\d) / (\d+\.\d) / (\d+\.\d) \((\d+\.\d|-)\) / \d+\.\d / \d\.\d{3}( \[\d+\])?( \{\d+\})?$")
    for row in tables(text)[0][2:]:
        for c in row.split("|")[2:-1]:
            m = cell.match(c.strip())
            assert m, c
            med, p90, worst = (float(m.group(k)) for k in (1, 2, 3))
            assert med <= p90 <= worst and (m.group(4) == "-" or float(m.group(4)) <= worst)
    assert "**Why the worst points are bad**" in text
    diag = next(t for t in tables(text) if "L1-refined" in t[0])
    assert len(diag) == 2 + 3 and all(re.search(r"\| (a|b|c): |\| open: ", r) for r in diag[2:])


def test_diagnosis_of_a_normal_curve_is_the_8_bit_floor():
    d = diagnose(next(p for p in grid((0.0,)) if p.where == "normal point"), 100_000)
    assert d.cause is Cause.FLOOR and d.floor <= 0.5 and d.exact < 0.01 and d.fit.worst <= d.floor + 1.0
    assert d.outside < 0.002 and not d.at_bound and 20 < d.levels90 < 200


def test_diagnosis_of_a_pile_at_the_bound_finds_a_remedy_that_reaches_the_floor():
    # beta1 4, beta2 5.3: an SB curve with about 65% of its mass in level 20, its lower bound
    d = diagnose(Point(4.0, 5.3, "pile", curve(4.0, 5.3)), 1_000_000)
    assert d.peak[0] == 20 and 0.6 < d.peak[1] < 0.7 and d.at_bound and d.outside == 0.0
    assert d.floor <= 0.5 and d.exact < 0.01  # the counts and the exact quantiles both pin the curve
    assert d.piles <= d.floor + 1.0 and d.refined <= d.floor + 1.0
    assert d.cause in (Cause.FITTER, Cause.FLOOR)  # FLOOR once the fitter reads such piles itself
    if d.cause is Cause.FITTER:
        assert d.why.startswith("the pile at level 20") and d.fit.worst > d.floor + 1.0


def test_diagnosis_calls_a_pile_finer_than_float64_a_grid_artifact():
    d = diagnose(Point(4.0, 5.1, "spike", curve(4.0, 5.1)), 1_000_000)
    assert d.gap < 1e-6 and d.exact > 1.0 and d.floor <= 0.5
    assert d.cause is Cause.GRID and "exact quantiles" in d.why


def test_diagnosis_calls_a_curve_spilling_past_the_8_bit_range_a_grid_artifact():
    d = diagnose(Point(0.0, 3.0, "wide", Johnson.normal(128.0, 100.0)), 100_000)
    below, above = (0.5 * math.erfc(t / 100.0 / math.sqrt(2.0)) for t in (128.5, 127.5))
    assert d.outside == pytest.approx(below + above, rel=1e-9)
    assert d.cause is Cause.GRID and "folds" in d.why


def test_photo_cases_come_from_shipped_photographs_with_at_least_40_cases():
    from benchmarks import photo_cases

    cases = photo_cases.cases()
    assert len(cases) >= 40
    assert {c.mask for c in cases} == {"kmeans3", "whole", "depth3"}
    assert {c.band for c in cases} >= {"Y", "R", "G", "B"}
    assert all(c.counts.shape == (256,) and c.count >= 200 for c in cases)


def test_photos_run_without_r_says_so_and_runs_the_rest(monkeypatch, tmp_path):
    from benchmarks import bench_photos, rpeer

    monkeypatch.setattr(rpeer, "available", lambda: False)
    sections = bench_photos.run(Context(quick=True, out=tmp_path))
    text = "\n".join(line for s in sections for line in s.markdown())
    assert "R SuppDists not run: Rscript or the SuppDists package is missing" in text
    assert re.search(r"ours / Gaussian = 0\.\d+x", text) and "our failures: 0" in text
    assert re.search(r"Worst case against the plain percentile fit: [+-]0\.0\d+ exact L1", text)


def test_r_peer_parses_fits_and_failures():
    from benchmarks.rpeer import _parse

    probs = np.full(256, 1 / 256)
    ok = _parse("SU 0.002 " + " ".join(map(str, (0.1, 1.5, 100.0, 20.0, *probs))))
    assert ok.family == "SU" and ok.params == (0.1, 1.5, 100.0, 20.0) and ok.seconds == 0.002
    assert ok.probs.sum() == pytest.approx(1.0)
    bad = _parse("SL 0.001 " + " ".join(map(str, (0.0, -4.4, 190.0, -81.0, *probs))))
    assert bad.probs is None and "out-of-range" in bad.error
    assert _parse("ERROR Sb_values_out_of_range.").error == "Sb values out of range."


@pytest.mark.skipif(not __import__("benchmarks.rpeer").rpeer.available(), reason="Rscript with SuppDists not installed")
def test_r_peer_fits_a_normal_histogram():
    from benchmarks import rpeer

    h = np.bincount(np.clip(np.rint(np.random.default_rng(0).normal(120, 15, 20_000)), 0, 255).astype(int),
                    minlength=256)
    (fit,) = rpeer.fit_all([h])
    assert fit.probs is not None and fit.probs.sum() == pytest.approx(1.0)
    assert np.abs(fit.probs - h / h.sum()).sum() < 0.1
