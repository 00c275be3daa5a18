"""The BTF drawn (matplotlib, host only): for one region against one angle the sweep varied,
the mean, standard deviation, skewness, kurtosis and family of every band's model at the
measured angles (markers) with the interpolated curve between them (lines: the interpolation
`synth --angle` runs, `tools.analysis.btf_view.curve`), and per band a heat map of the level
probabilities over (angle, level) along the series with the most measured angles.
"""
from __future__ import annotations

import io
import math
from dataclasses import dataclass

import numpy as np

from btf.johnson import Family
from tools.analysis.btf_view import AXIS_TITLES, Btf, CurvePoint, Moments, axis_value, curve, moments

FAMILIES = [f.value for f in (Family.CONST, Family.SN, Family.SL, Family.SU, Family.SB)]
STYLES = ("-", "--", ":", "-.")
MARKERS = ("o", "s", "^", "D")
RGB = {"R": "#d62728", "G": "#2ca02c", "B": "#1f77b4"}
PANEL_IN = (3.3, 2.3)  # inches per panel
HEAT_TAIL = 0.01  # a heat map shows the levels between these tails at every angle


def _marker(series: int) -> str:
    """Series k: line style k mod 4 and the next marker every 4, so 16 series look different."""
    return MARKERS[(series // len(STYLES)) % len(MARKERS)]


@dataclass
class Line:
    """One band's series along an axis: its measured points and the curve between them."""

    band: int
    name: str
    points: list[tuple[float, Moments, str]]  # (angle, moments, family)
    curve: list[CurvePoint]


def lines(btf: Btf, label: int, axis: str) -> list[Line]:
    """Every band's series of `label` against `axis`, curves computed."""
    out = []
    for lab, band in btf.regions():
        if lab != label:
            continue
        for key, pts in btf.series(label, band, axis).items():
            measured = [(float(axis_value(btf.directions[i], axis)), moments(btf.probabilities(i, label, band)),
                         btf.models[i][(label, band)].family.value) for i in pts]
            out.append(Line(band, btf.series_name(axis, key), measured, curve(btf, label, band, axis, pts, key)))
    return out


def band_colour(btf: Btf, band: int) -> str:
    import matplotlib

    name = btf.band_name(band)
    return RGB.get(name, matplotlib.colormaps["tab10"](band % 10)) if btf.space in ("rgb", "gray") or name in RGB \
        else matplotlib.colormaps["tab10"](band % 10)


def _moment_panel(ax, btf: Btf, drawn: list[Line], names: list[str], what: str, unit: str) -> None:
    for line in drawn:
        colour, style = band_colour(btf, line.band), STYLES[names.index(line.name) % len(STYLES)]
        xs = [c.angle for c in line.curve if getattr(c.moments, what) is not None]
        ys = [getattr(c.moments, what) for c in line.curve if getattr(c.moments, what) is not None]
        if xs:
            ax.plot(xs, ys, style, color=colour, lw=1.2)
        pts = [(a, getattr(m, what)) for a, m, _ in line.points if getattr(m, what) is not None]
        if pts:
            ax.plot(*zip(*pts), _marker(names.index(line.name)), color=colour, ms=4, ls="none")
    ax.set_ylabel(f"{what} ({unit})")


def _family_panel(ax, btf: Btf, drawn: list[Line], names: list[str]) -> None:
    bands = sorted({line.band for line in drawn})
    for line in drawn:
        offset = 0.12 * (bands.index(line.band) - (len(bands) - 1) / 2)
        xs = [a for a, _, _ in line.points]
        ys = [FAMILIES.index(f) + offset for _, _, f in line.points]
        ax.plot(xs, ys, _marker(names.index(line.name)), color=band_colour(btf, line.band), ms=4)
    ax.set_yticks(range(len(FAMILIES)), FAMILIES)
    ax.set_ylim(-0.6, len(FAMILIES) - 0.4)
    ax.set_ylabel("Johnson family")


def _heat_panel(fig, ax, btf: Btf, line: Line, axis: str) -> None:
    import matplotlib.colors as mcolors

    probs = np.array([c.probabilities for c in line.curve])
    angles = np.array([c.angle for c in line.curve])
    cdf = np.cumsum(probs, axis=1)
    lo = int(np.argmax(cdf >= HEAT_TAIL, axis=1).min())
    hi = int(np.argmax(cdf >= 1.0 - HEAT_TAIL, axis=1).max())
    lo, hi = max(lo - 2, 0), min(hi + 2, btf.levels - 1)
    step = max(1, math.ceil((hi - lo + 1) / 256))  # deep sensors: bins of several levels
    block = probs[:, lo:hi + 1]
    pad = (-block.shape[1]) % step
    binned = np.pad(block, ((0, 0), (0, pad))).reshape(len(angles), -1, step).sum(axis=2) / step
    mids = (angles[1:] + angles[:-1]) / 2
    x_edges = np.concatenate(([angles[0] - (mids[0] - angles[0])], mids, [angles[-1] + (angles[-1] - mids[-1])]))
    y_edges = lo - 0.5 + step * np.arange(binned.shape[1] + 1)
    mesh = ax.pcolormesh(x_edges, y_edges, binned.T, cmap="magma", shading="flat",
                         norm=mcolors.PowerNorm(0.5, vmin=0.0, vmax=max(float(binned.max()), 1e-12)))
    ax.plot([a for a, _, _ in line.points], [y_edges[-1]] * len(line.points), "v", color="#1f2328", ms=4,
            clip_on=False)
    ax.set_ylim(y_edges[0], y_edges[-1])
    ax.set_ylabel("level")
    ax.set_title(f"{btf.band_name(line.band)}: P(level)" + (f", {line.name}" if line.name != "measured" else ""),
                 fontsize=8)
    bar = fig.colorbar(mesh, ax=ax, pad=0.02)
    bar.set_label("probability per level" + (f" (bins of {step})" if step > 1 else ""), fontsize=7)
    bar.ax.tick_params(labelsize=6)


def _legend(ax, btf: Btf, drawn: list[Line], names: list[str], spare: bool) -> None:
    """The bands' colours and the series' styles: in a spare panel, else in the family panel."""
    from matplotlib.lines import Line2D

    handles = [Line2D([], [], color=band_colour(btf, b), lw=2, label=f"band {btf.band_name(b)}")
               for b in sorted({line.band for line in drawn})]
    handles += [Line2D([], [], color="#57606a", ls=STYLES[k % len(STYLES)], marker=_marker(k), ms=4,
                       label=n if n != "measured" else "measured angle")
                for k, n in enumerate(names)]
    handles.append(Line2D([], [], color="#57606a", lw=1.2, label="interpolated (synth --angle)"))
    if spare:
        ax.axis("off")
        ax.legend(handles=handles, loc="center", fontsize=8, frameon=False)
    else:
        ax.legend(handles=handles, loc="best", fontsize=6)


def draw_block(fig, cells, btf: Btf, label: int, axis: str) -> None:
    """One region against one axis into a 3-column grid of subplot specs `cells`."""
    drawn = lines(btf, label, axis)
    names = list(dict.fromkeys(line.name for line in drawn))
    title = f"{AXIS_TITLES[axis]} (°)"
    panels = []
    for what, unit in (("mean", "level"), ("sd", "levels"), ("skewness", "no unit"), ("kurtosis", "beta2, no unit")):
        ax = fig.add_subplot(next(cells))
        _moment_panel(ax, btf, drawn, names, what, unit)
        panels.append(ax)
    ax = fig.add_subplot(next(cells))
    _family_panel(ax, btf, drawn, names)
    panels.append(ax)
    for band in sorted({line.band for line in drawn}):
        longest = max((line for line in drawn if line.band == band), key=lambda line: len(line.points))
        if len(longest.curve) >= 2:
            ax = fig.add_subplot(next(cells))
            _heat_panel(fig, ax, btf, longest, axis)
            panels.append(ax)
    for k, ax in enumerate(panels):
        ax.set_xlabel(title, fontsize=8)
        ax.tick_params(labelsize=7)
        ax.yaxis.label.set_size(8)
        ax.grid(alpha=0.3 if k < 5 else 0.0)
    panels[0].set_title(f"region {label}, {btf.scene or 'robot ' + btf.robot}", fontsize=9, loc="left")
    spare = next(cells, None)
    _legend(fig.add_subplot(spare) if spare is not None else panels[4], btf, drawn, names, spare is not None)


def _panels(btf: Btf, label: int) -> int:
    return 5 + len({b for lab, b in btf.regions() if lab == label})


def figure_png(btf: Btf, blocks: list[tuple[int, str]], dpi: int = 90) -> bytes:
    """PNG bytes of the (region, axis) blocks stacked, three panels to a row."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.gridspec import GridSpec

    rows = [math.ceil(_panels(btf, label) / 3) for label, _ in blocks]
    fig = plt.figure(figsize=(3 * PANEL_IN[0], PANEL_IN[1] * sum(rows) + 0.5 * len(blocks)))
    grid = GridSpec(sum(rows), 3, figure=fig, hspace=0.55, wspace=0.42,
                    top=1 - 0.45 / fig.get_figheight(), bottom=0.35 / fig.get_figheight(), left=0.07, right=0.97)
    first = 0
    for (label, axis), n in zip(blocks, rows):
        cells = iter(grid[first + k // 3, k % 3] for k in range(3 * n))
        draw_block(fig, cells, btf, label, axis)
        first += n
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    plt.close(fig)
    return buf.getvalue()


def region_blocks(btf: Btf) -> list[tuple[int, str]]:
    """(region, axis) for every region against every angle the sweep varied."""
    labels = sorted({lab for lab, _ in btf.regions()})
    return [(label, axis) for label in labels for axis in (btf.varied or ("elevation",))]
