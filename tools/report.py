"""An HTML report of a database: captures per angle, the models, synthetic beside measured
images, histogram overlays and the metric tables; a self-contained directory of PNGs.

Measured images are not in the database (the robot sends models, not pixels); pass
`measured(scene, elevation) -> RGB image` to put them beside the synthetic ones.
"""
from __future__ import annotations

import html
from pathlib import Path
from typing import Any, Callable

import numpy as np

from tools.grid import Grid
from tools.images import stretched_8bit, write_image
from tools.radiometry import adjusted
from tools.radiometry import describe as describe_camera
from tools.receiver import mask_key
from tools.store import Store, StoredCapture
from tools.synth import MissingModels, synthesize

Measured = Callable[[str, float], np.ndarray | None]
_CSS = ("body{font-family:sans-serif;max-width:1100px;margin:auto}table{border-collapse:collapse;"
        "font-size:90%}td,th{border:1px solid #bbb;padding:2px 6px;text-align:right}"
        "img{image-rendering:pixelated;width:240px;margin:2px}figcaption{font-size:80%;text-align:center}.bad{color:#b00}.ok{color:#070}")


def _table(head: list[str], rows: list[list[Any]]) -> str:
    def cell(v: Any) -> str:
        return f"{v:.4f}" if isinstance(v, float) else html.escape(str(v))
    return ("<table><tr>" + "".join(f"<th>{html.escape(h)}</th>" for h in head) + "</tr>"
            + "".join("<tr>" + "".join(f"<td>{cell(v)}</td>" for v in r) + "</tr>" for r in rows)
            + "</table>")


def _figure(src: str, caption: str) -> str:
    return (f"<figure style='display:inline-block;margin:2px'><img src='{src}' title='{caption}'>"
            f"<figcaption>{html.escape(caption)}</figcaption></figure>")


def capture_mask(store: Store, cap: StoredCapture) -> np.ndarray | None:
    """A capture's label map: the robot's MASK for it, the one `fit --mask` or `ingest --mask`
    stored with it, an ingested dataset's common mask, or the robot's latest MASK before it."""
    for key in (mask_key(cap.sequence, cap.incarnation), f"{cap.robot}/{cap.sequence}", cap.robot):
        m = store.mask(key, cap.robot)
        if m is not None:
            return m
    for seq in range(cap.sequence - 1, -1, -1):
        m = store.mask(mask_key(seq, cap.incarnation), cap.robot)
        if m is not None:
            return m
    return None


def _model_curve(model, levels: int) -> tuple[np.ndarray, np.ndarray]:
    """(x, probability per level) for 8-bit models; deep ones per bin of 256 over their bulk."""
    if levels <= 256:
        return np.arange(levels), model.level_probabilities(levels)
    lo, hi = (int(np.clip(model.ppf(q), 0, levels - 1)) for q in (1e-3, 1 - 1e-3))
    grid = Grid.over(lo, hi, levels)
    bounds = np.concatenate(([lo - 0.5], grid.edges(), [hi + 0.5]))
    per_level = model.interval_probabilities(grid.edges()) / np.diff(bounds)  # bins hold 1 or 2 counts of levels
    # the end bins also hold the folded tails: left out of the curve
    return ((bounds[:-1] + bounds[1:]) / 2)[1:-1], per_level[1:-1]


def _hist_plot(path: Path, image: np.ndarray | None, mask: np.ndarray, models: dict, bands: tuple[str, ...],
               title: str, levels: int = 256) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, len(bands), figsize=(3.2 * len(bands), 2.4), squeeze=False)
    edges = np.arange(257) - 0.5
    for b, name in enumerate(bands):
        ax = axes[0][b]
        for lab in sorted({lab for lab, _ in models}):
            if image is not None and levels <= 256 and image.shape[:2] == mask.shape and (mask == lab).any():
                h = np.bincount(image[..., b][mask == lab], minlength=256) / (mask == lab).sum()
                # one filled step artist: 256 bar patches per label made the report slow
                ax.stairs(h, edges, fill=True, alpha=0.4, label=f"measured {lab}")
            ax.plot(*_model_curve(models[(lab, b)], levels), lw=1, label=f"Johnson {lab}")
        ax.set_title(f"{title} {name}", fontsize=8)
        ax.tick_params(labelsize=6)
    axes[0][0].legend(fontsize=5)
    fig.subplots_adjust(left=0.05, right=0.98, bottom=0.12, top=0.88, wspace=0.25)
    fig.savefig(path, dpi=80)
    plt.close(fig)


def _demo_sections(demo: Any) -> list[str]:
    out = ["<h2>Mixed plate reproduction</h2><p>Correlation between the synthetic mixed plate "
           "(black and white models, mixed mask) and its capture, beside the ceiling: two captures "
           "of the same plate with different grain seeds. The paper reports 0.97.</p>"]
    rows = []
    for r in demo.mixed:
        for b in r["synthetic"]:
            ratio = r["synthetic"][b] / r["ceiling"][b] if r["ceiling"][b] else 0.0
            rows.append([f"{r['angle']:.1f}", b, r["synthetic"][b], r["ceiling"][b], ratio, 0.97])
    out.append(_table(["angle", "band", "synthetic", "ceiling", "ratio", "paper"], rows))
    out.append("<h2>Unseen angle (45°)</h2>")
    out.append(_table(["plate", "fitted at 45°", "interpolated", "nearest measured", "neighbours"],
                      [[s, u["fitted"], u["interpolated"], u["nearest"], f"{u['lo']:g}/{u['hi']:g}"]
                       for s, u in demo.unseen.items()]))
    out.append("<h2>Table 2: total histogram error per model</h2>")
    peers = list(next(iter(demo.pdfs.values())).keys()) if demo.pdfs else []
    out.append(_table(["scene", *peers], [[s, *[t[p] for p in peers]] for s, t in demo.pdfs.items()]))
    out.append("<h2>Table 1: correlation per band on the field scene</h2>")
    out.append(_table(["mask", "space", "regions", "band 1", "band 2", "band 3"],
                      [[r["method"], r["space"], r["regions"], *r["correlation"].values()] for r in demo.table1]))
    bars = demo.bars()
    out.append("<h2>Bars</h2><ul>" + "".join(
        f"<li class={'ok' if v else 'bad'}>{html.escape(k)}: {'met' if v else 'MISSED'}</li>"
        for k, v in bars.items()) + "</ul>")
    out.append(f"<p>Link, both ends: {html.escape(', '.join(f'{k} {v}' for k, v in demo.link.items()))}. "
               f"Run time {demo.seconds:.1f} s (sweeps and experiments; this report was written after).</p>")
    return out


def _note(text: str) -> str:
    return f"<p class=note><em>{html.escape(text)}</em></p>"


def write_report(store: Store, out: Path, measured: Measured | None = None, demo: Any = None,
                 seed: int = 0, robot: str | None = None,
                 scene: str | None = None, progress: bool = False) -> Path:
    """Writes out/index.html and its PNGs for the captures of `robot` and `scene` (all when None);
    returns the HTML path. `progress` shows a tqdm bar over the captures on stderr."""
    from tqdm import tqdm

    out.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    caps = store.captures(robot=robot, scene=scene)
    chosen = " ".join(f"{k} {v}" for k, v in (("robot", robot), ("scene", scene)) if v is not None)
    parts = [f"<!doctype html><meta charset=utf-8><title>btfscout report</title><style>{_CSS}</style>",
             f"<h1>btfscout report: {html.escape(store.path.name)}"
             + (f" ({html.escape(chosen)})" if chosen else "") + "</h1>",
             "<h2>Captures per angle</h2>",
             _table(["scene", "robot", "seq", "commanded", "measured", "space", "models", "camera"],
                    [[c.scene, c.robot, c.sequence, "" if c.commanded[0] is None else f"{c.commanded[0]:.1f}",
                      f"{c.measured[0]:.2f}", c.space, len(store.models(c.id)), describe_camera(c.camera)]
                     for c in caps])]
    rows = []
    for c in caps:
        for (label, band), m in store.models(c.id).items():
            j = m.model
            fitted_at = c.camera.exposure_of(label) if c.camera is not None else None
            rows.append([c.scene, f"{c.elevation:.1f}", label, c.band_names[band] if band < len(c.band_names)
                         else band, j.family.value, j.gamma, j.delta, j.xi, j.lam, m.count,
                         "" if fitted_at is None else f"{fitted_at:g}"])
    parts += ["<h2>Models</h2>", _table(["scene", "angle", "label", "band", "family", "gamma", "delta",
                                         "xi", "lambda", "pixels", "fitted at (us)"], rows)
              if rows else _note("No models stored.")]
    parts.append("<h2>Synthetic beside measured</h2>")
    shown, unmasked = len(parts), 0
    for c in tqdm(caps, desc="report", unit="capture", disable=not progress):
        mask = capture_mask(store, c)
        # each region at the capture's exposure (a bracketed region's models scaled back)
        models = dict(adjusted({k: m.model for k, m in store.models(c.id).items()}, c.camera))
        unmasked += mask is None
        if mask is None or not models:
            continue
        name = f"{c.scene or 'robot' + c.robot}_{c.elevation:05.1f}_{c.sequence}"
        deps = store.dependence(c.id)
        try:
            syn = synthesize(mask, models, rng, c.levels)
            # With stored grain and band correlation, the correlated synthesis goes beside it.
            corr = synthesize(mask, models, rng, c.levels, dependence=deps) if deps else None
        except MissingModels as exc:
            parts.append(f"<p>{html.escape(name)}: {html.escape(str(exc))}</p>")
            continue
        real = measured(c.scene, c.elevation) if measured else None
        imgs = []
        if real is not None and c.space == "rgb":
            write_image(out / f"{name}_measured.png", real)
            imgs.append(_figure(f"{name}_measured.png", "measured"))
        if (c.space == "rgb" and syn.shape[2] == 3) or (c.space == "gray" and syn.shape[2] == 1):
            # 16-bit pixels are shown stretched over the levels they occupy (one span for both)
            span = (int(syn.min()), int(syn.max())) if corr is None else (
                int(min(syn.min(), corr.min())), int(max(syn.max(), corr.max())))
            write_image(out / f"{name}_synthetic.png", stretched_8bit(syn, span))
            imgs.append(_figure(f"{name}_synthetic.png", "independent pixels" if corr is not None else "synthetic"))
            if corr is not None:
                write_image(out / f"{name}_correlated.png", stretched_8bit(corr, span))
                imgs.append(_figure(f"{name}_correlated.png", "grain and band correlation"))
        _hist_plot(out / f"{name}_hist.png", real if c.space == "rgb" else None, mask, models,
                   c.band_names, f"{c.scene} {c.elevation:.0f}°", c.levels)
        imgs.append(f"<img src='{name}_hist.png' style='width:480px' title='histograms'>")
        parts.append(f"<h3>{html.escape(c.scene)} at {c.elevation:.1f}° (seq {c.sequence})</h3>"
                     "<div>" + "".join(imgs) + "</div>")
    if unmasked == len(caps):
        parts.append(_note("None: no capture has a label mask (the robot sends one with its captures; "
                           "`fit --mask` and `ingest --mask` store one), so nothing can be synthesized."))
    elif len(parts) == shown:
        parts.append(_note("None: no capture with a label mask has models for it."))
    elif unmasked:
        parts.append(_note(f"{unmasked} capture(s) without a label mask are not shown."))
    if demo is not None:
        parts += _demo_sections(demo)
    path = out / "index.html"
    path.write_text("\n".join(parts), encoding="utf-8")
    return path
