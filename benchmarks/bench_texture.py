"""Texture synthesis judged beside photographs shipped in public packages, and its cost.

Per photograph (benchmarks.texture_cases: gray, RGB and a 16-bit one), fitted and measured as
`btf-host fit` does and synthesized from those records (tools.analysis.synth), per region of at
least 500 pixels: the share of synthesized pixels outside the region's observed levels, the
plaid index (axis power over the photograph's, tools.analysis.grain_metrics), the worst gap of
the 2-D autocorrelation over |dy|, |dx| <= 8 (mean of SEEDS draws), the worst band-correlation
gap (worst draw), W1 of the marginals to the photograph, and the correlated / independent time;
and the 2-D ACF gap again from the robot's records (fewer anchors, a smaller window).
Then the cost at 1000x1000 RGB, correlated against independent, measured side by side.
"""
from __future__ import annotations

import time
import warnings

import numpy as np

from benchmarks import texture_cases
from benchmarks.common import Context, Section, paired_times, verdict
from benchmarks.texture_cost import cost_lines
from tools.analysis import grain_metrics as gm
from tools.analysis.fields import grain_of
from tools.analysis.synth import ReachWarning, band_maps, synthesize

SEEDS = (0, 1, 2)
SIDE_BY_SIDE = ("brick", "coffee", "grace_hopper", "elevation16")


def _w1(photo: np.ndarray, synth: np.ndarray, inside: np.ndarray) -> float:
    """Worst band's Wasserstein-1 distance between the region's level histograms (levels)."""
    worst = 0.0
    for b in range(photo.shape[2]):
        p, s = photo[..., b][inside].astype(np.int64), synth[..., b][inside].astype(np.int64)
        lo, hi = min(p.min(), s.min()), max(p.max(), s.max())
        cp = np.cumsum(np.bincount(p - lo, minlength=hi - lo + 1)) / p.size
        cs = np.cumsum(np.bincount(s - lo, minlength=hi - lo + 1)) / s.size
        worst = max(worst, float(np.abs(cp - cs).sum()))
    return worst


def _mean_plaid(img: np.ndarray, cors: list[np.ndarray], inside: np.ndarray) -> float | None:
    """The plaid index over the draws: one draw's axis share scatters where a long grain puts
    most of a small square's power in its lowest frequencies."""
    values = [gm.plaid(img, c, inside) for c in cors]
    return None if values[0] is None else float(np.mean(values))


def _or0(v: float | None) -> float:
    return 0.0 if v is None else v


def _judge(photo, cors: list[np.ndarray], ind: np.ndarray, bare: np.ndarray) -> list[dict]:
    rows = []
    for lab in photo.regions:
        inside = photo.labels == lab
        img = photo.pixels
        rows.append({
            "label": lab, "pixels": int(inside.sum()),
            "outside": max(gm.outside(img, c, inside) for c in cors), "outside_ind": gm.outside(img, ind, inside),
            "outside_bare": gm.outside(img, bare, inside),
            "unseen": max(_or0(gm.unseen(img, c, inside, photo.levels)) for c in cors),
            "unseen_ind": gm.unseen(img, ind, inside, photo.levels),
            "plaid": _mean_plaid(img, cors, inside),
            "acf": float(np.mean([gm.acf_gap(img, c, inside) for c in cors])),
            # two draws of one record differ this much: the photograph is one draw too
            "acf_draws": float(np.mean([gm.acf_gap(a, b, inside) for i, a in enumerate(cors) for b in cors[i + 1:]])),
            "acf_ind": gm.acf_gap(img, ind, inside),
            "band": max(gm.band_gap(img, c, inside) for c in cors),
            "w1": _w1(img, cors[0], inside), "w1_bare": _w1(img, bare, inside),
        })
    return rows


def _setup_times(photo) -> list[float]:
    """Seconds per measured record to turn it into what its fields need (the latent band matrix
    and the grain spectra, fields.grain_of, past its cache): synthesis pays it once a record."""
    times = []
    for lab in photo.regions:
        dep = photo.dependence[lab]
        if dep.measured:
            maps = band_maps(photo.models, lab, photo.pixels.shape[2], photo.levels, dep)
            t0 = time.perf_counter()
            grain_of.__wrapped__(dep, maps)
            times.append(time.perf_counter() - t0)
    return times


def _photo_row(name: str, ctx: Context) -> tuple[str, list[dict], dict]:
    photo = texture_cases.load(name, side=ctx.pick(None, 96))
    deps, models, levels = photo.dependence, photo.models, photo.levels
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ReachWarning)
        setup = _setup_times(photo)
        cors = [synthesize(photo.labels, models, np.random.default_rng(s), levels, deps) for s in SEEDS]
    ind = synthesize(photo.labels, models, np.random.default_rng(9), levels, deps, independent=True)
    bare = synthesize(photo.labels, models, np.random.default_rng(9), levels)  # no levels: the clipped curves
    rng = np.random.default_rng(0)
    t = paired_times({"ind": lambda: synthesize(photo.labels, models, rng, levels, deps, independent=True),
                      "cor": lambda: synthesize(photo.labels, models, rng, levels, deps)}, ctx.pick(5, 1))
    rows = _judge(photo, cors, ind, bare)
    robot = texture_cases.load(name, side=ctx.pick(None, 96), robot=True)
    for row, lab in zip(rows, photo.regions):
        inside = photo.labels == lab
        row["acf_robot"] = float(np.mean([gm.acf_gap(photo.pixels, synthesize(
            robot.labels, robot.models, np.random.default_rng(s), levels, robot.dependence), inside) for s in SEEDS]))
    h, w, b = photo.pixels.shape
    reach = [issubclass(c.category, ReachWarning) for c in caught]
    info = {"size": f"{w}x{h}", "bands": f"{b} x {'8' if levels == 256 else '16'}-bit", "ratio": t["cor"] / t["ind"],
            "setup": setup, "warned": [str(c.message) for c, r in zip(caught, reach) if r],
            "faults": [f"{c.category.__name__}: {c.message}" for c, r in zip(caught, reach) if not r],
            "photo": photo, "synth": cors[0], "ind": ind}
    return name, rows, info


def _fmt(v: float | None, pattern: str) -> str:
    return "-" if v is None else pattern.format(v)


def _table(results) -> list[str]:
    lines = ["| photograph | size | bands | regions | outside, ind / cor (worst region) | outside without levels "
             "| colours never seen, ind / cor (worst region) | plaid (worst) | 2-D ACF gap: ind / cor (worst region) "
             "| band gap (worst) | W1 to photo: without levels / cor (mean) | cor / ind time |",
             "|---|---|---|---:|---|---|---|---|---|---|---|---:|"]
    for name, rows, info in results:
        plaids = [r["plaid"] for r in rows if r["plaid"] is not None]
        colour = [r for r in rows if r["unseen_ind"] is not None]
        lines.append(
            f"| {name} | {info['size']} | {info['bands']} | {len(rows)} | "
            f"{max(r['outside_ind'] for r in rows):.3%} / {max(r['outside'] for r in rows):.3%} | "
            f"{max(r['outside_bare'] for r in rows):.2%} | "
            + (f"{max(r['unseen_ind'] for r in colour):.1%} / {max(r['unseen'] for r in colour):.2%} | " if colour
               else "- | ")
            + f"{_fmt(max(plaids) if plaids else None, '{:.2f}')} | "
            f"{max(r['acf_ind'] for r in rows):.2f} / {max(r['acf'] for r in rows):.3f} | "
            f"{max(r['band'] for r in rows):.3f} | {np.mean([r['w1_bare'] for r in rows]):.2f} / "
            f"{np.mean([r['w1'] for r in rows]):.2f} | {info['ratio']:.2f}x |")
    return lines


def _unseen_line(rows: list[dict]) -> list[str]:
    if not rows:
        return []
    cor = [r["unseen"] for r in rows]
    return [f"- colours a region never had (its pixels in bins of 1/32 of the depth, every band at once, with one "
            f"bin of slack, where none of the photograph's pixels there fall): worst region {max(cor):.2%} "
            f"correlated (median {np.median(cor):.2%}), {max(r['unseen_ind'] for r in rows):.1%} independent. The "
            "Gaussian copula keeps each band's levels and the bands' correlation, not the shape of their joint "
            "spread: a class of several materials draws some of their levels in pairs none of them has"]


def _summary(results) -> list[str]:
    rows = [r for _, rs, _ in results for r in rs]
    plaids = [r["plaid"] for r in rows if r["plaid"] is not None]
    acf_ok = sum(r["acf"] <= 0.10 for r in rows)
    colour = [r["band"] for name, rs, info in results for r in rs if info["photo"].pixels.shape[2] > 1]
    colour_rows = [r for r in rows if r["unseen_ind"] is not None]
    worst = lambda key: max(r[key] for r in rows)  # noqa: E731
    setup = [t for _, _, info in results for t in info["setup"]]
    out = [f"{len(results)} photographs, {len(rows)} regions of at least {texture_cases.MIN_REGION} pixels; "
           f"each drawn {len(SEEDS)} times (ACF gap: their mean; outside and band gap: the worst draw).", "",
           f"- **outside the observed levels: worst region {worst('outside'):.3%}** correlated, "
           f"{worst('outside_ind'):.3%} independent (target < 0.2%: {verdict(worst('outside'), 0.002)}); "
           f"without the levels {worst('outside_bare'):.2%}",
           *_unseen_line(colour_rows),
           f"- **plaid index: worst {max(plaids):.2f}** over {len(plaids)} regions with a square of 32 pixels "
           f"(target <= 1.2: {verdict(max(plaids), 1.2)})",
           f"- **2-D ACF gap: {acf_ok} of {len(rows)} regions within 0.10**, median "
           f"{np.median([r['acf'] for r in rows]):.3f}, worst {worst('acf'):.3f} (independent pixels: worst "
           f"{worst('acf_ind'):.2f}); from the robot's records (6,144 anchors, lags within 6): "
           f"{sum(r['acf_robot'] <= 0.10 for r in rows)} of {len(rows)}, median "
           f"{np.median([r['acf_robot'] for r in rows]):.3f}; two draws of one record differ by "
           f"{np.median([r['acf_draws'] for r in rows]):.3f} (median), and "
           f"{sum(r['acf'] <= max(0.10, r['acf_draws']) for r in rows)} of {len(rows)} regions are within 0.10 "
           f"or their own draw-to-draw gap",
           f"- **band-correlation gap: worst {max(colour):.3f}** over {len(colour)} colour regions "
           f"(target <= 0.05: {verdict(max(colour), 0.05)})",
           "- a record's setup (latent band matrix and grain spectra, cached per record): " + (
               f"{min(setup):.2f}-{max(setup):.2f} s, median {np.median(setup):.2f} s over {len(setup)} records"
               if setup else "no record measured its grain"),
           f"- W1 to the photograph, mean over regions: {np.mean([r['w1_bare'] for r in rows]):.2f} levels without the "
           f"observed levels, {np.mean([r['w1'] for r in rows]):.2f} with them (correlated)"]
    warned = [(name, w) for name, _, info in results for w in info["warned"]]
    if warned:
        out += ["", "Warned (a band correlation the marginals cannot reach):"]
        out += [f"- {name}: {w}" for name, w in warned]
    faults = [(name, w) for name, _, info in results for w in info["faults"]]
    if faults:  # a numerical warning from synthesis is a defect to find, not a reach to name
        out += ["", "Other warnings, raised while synthesizing (each one a defect to look into):"]
        out += [f"- {name}: {w}" for name, w in faults]
    return out


def _pictures(results, ctx: Context) -> list[str]:
    from benchmarks.common import save
    from benchmarks.texture_cost import side_by_side

    lines = []
    for name, _, info in results:
        if name in SIDE_BY_SIDE:
            fig = side_by_side(info["photo"].pixels, info["ind"], info["synth"], name)
            lines += [save(fig, ctx, f"texture_{name}.png", tight=False), ""]
    return lines


def run(ctx: Context = Context()) -> list[Section]:
    names = ctx.pick(texture_cases.ALL, ("grass", "coffee"))
    results = [_photo_row(n, ctx) for n in names]
    photos = _summary(results) + ["", *_table(results), "", "Photograph | independent | correlated, each "
                                  "within the region's observed levels (16-bit shown stretched):", "",
                                  *_pictures(results, ctx)]
    return [Section("Texture synthesis on photographs", photos),
            Section("Texture synthesis: cost at 1000x1000 RGB", cost_lines(ctx))]
