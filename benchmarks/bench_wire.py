"""Bytes per capture against quantization error, and packet encode/decode time.

The wire carries 16-bit percentile codes for 8-bit sensors. Rows for 8- and 12-bit codes
show what the same body would cost with codes bit-packed at that width, and what error
that would cost, to justify the choice. Errors are in gray levels against 32-bit codes.
"""
from __future__ import annotations

import math
import time

import numpy as np

from benchmarks.common import Context, Section
from btf.codec import PercentileCodec
from btf.fit.fitter import fit_histogram
from btf.percentile import model_from_percentiles
from radio.packets import decode, encode_models

BANDS = ("R", "G", "B")
LABEL_COUNTS = (1, 2, 4, 8, 16)
CODE_BITS = (8, 12, 16)
U_GRID = np.linspace(0.001, 0.999, 999)


def _histograms(n: int, seed: int = 0, per_label: int = 1) -> list[np.ndarray]:
    """Histograms of 8-bit clutter-like data: skewed, bounded, heavy-tailed, narrow.
    Each run of `per_label` histograms shares a pixel count, as a label's bands do."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        if i % per_label == 0:
            size = int(rng.integers(500, 50_000))
        kind = i % 4
        if kind == 0:
            v = rng.gamma(rng.uniform(1.5, 6), rng.uniform(4, 20), size)
        elif kind == 1:
            v = 255 * rng.beta(rng.uniform(1.5, 5), rng.uniform(1.5, 5), size)
        elif kind == 2:
            v = rng.uniform(60, 190) + rng.standard_t(4, size) * rng.uniform(3, 15)
        else:
            v = rng.normal(rng.uniform(20, 235), rng.uniform(0.7, 4), size)
        out.append(np.bincount(np.clip(np.round(v), 0, 255).astype(np.int64), minlength=256))
    return out


def _fits(n_labels: int, seed: int = 0) -> dict:
    hists = _histograms(n_labels * len(BANDS), seed, per_label=len(BANDS))
    return {(lab, b): fit_histogram(hists[lab * len(BANDS) + b])
            for lab in range(n_labels) for b in range(len(BANDS))}


def _snap(p: tuple, bits: int) -> tuple:
    lo, step = -0.5, 256.0 / (1 << bits)
    top = (1 << bits) - 1
    return tuple(lo + min(max(round((x - lo) / step), 0), top) * step for x in p)


def _errors(bits: int, hists: list[np.ndarray]) -> tuple[float, float, float, float]:
    """Max percentile error; max model ppf error between the outer percentiles;
    median and max model ppf error over u in [0.001, 0.999]."""
    fine = PercentileCodec(-0.5, 255.5, 32)
    p_err, inner, outer = 0.0, 0.0, []
    for h in hists:
        ref = fit_histogram(h, codec=fine)
        snapped = _snap(ref.percentiles, bits)
        p_err = max(p_err, max(abs(a - b) for a, b in zip(snapped, ref.percentiles)))
        model = model_from_percentiles(snapped, ref.z, ref.count)
        diff = np.abs(model.ppf(U_GRID) - ref.model.ppf(U_GRID))
        outer.append(float(np.max(diff)))
        tail = 0.5 * math.erfc(3 * ref.z / math.sqrt(2))  # Phi(-3z)
        inside = (U_GRID >= tail) & (U_GRID <= 1 - tail)
        inner = max(inner, float(np.max(diff[inside])))
    return p_err, inner, float(np.median(outer)), float(np.max(outer))


def _best_time(fn, repeat: int = 5, number: int = 20) -> float:
    best = math.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        for _ in range(number):
            fn()
        best = min(best, (time.perf_counter() - t0) / number)
    return best


def run(ctx: Context | None = None) -> list[str]:
    ctx = ctx or Context()
    header = dict(robot_id=1, seq=123_456, time=1.7e9, commanded=(45.0, 30.0),
                  measured=(44.9, 30.1), feature_space="rgb", bands=BANDS)
    lines = [
             f"MODELS body bytes for {len(BANDS)} bands (16-bit codes on the wire; "
             "8/12-bit: same body with codes bit-packed at that width).", "",
             "| labels | models | " + " | ".join(f"{b}-bit codes" for b in CODE_BITS)
             + " | encode µs | decode µs |",
             "|---:|---:|" + "---:|" * (len(CODE_BITS) + 2)]
    for n in ctx.pick(LABEL_COUNTS, (1, 2)):
        fits = _fits(n)
        body = encode_models(fits, **header)
        models = n * len(BANDS)
        sizes = [len(body) - models * 8 + math.ceil(models * 4 * b / 8) for b in CODE_BITS]
        reps = ctx.pick((5, 20), (1, 1))
        t_enc = _best_time(lambda: encode_models(fits, **header), *reps)
        t_dec = _best_time(lambda: decode(body), *reps)
        lines.append(f"| {n} | {models} | " + " | ".join(str(s) for s in sizes)
                     + f" | {t_enc * 1e6:.0f} | {t_dec * 1e6:.0f} |")
    hists = _histograms(ctx.pick(60, 4), seed=1)
    lines += ["", f"Quantization error in gray levels ({len(hists)} fitted 8-bit histograms, against 32-bit codes):",
              "", "| code bits | step | max percentile error | max model error, fitted range "
              "| median model error | max model error |",
              "|---:|---:|---:|---:|---:|---:|"]
    for bits in CODE_BITS:
        p_err, inner, m_med, m_max = _errors(bits, hists)
        lines.append(f"| {bits} | {256 / (1 << bits):.2e} | {p_err:.2e} | {inner:.2e} "
                     f"| {m_med:.2e} | {m_max:.2e} |")
    lines += ["", "Model error: max of |ppf(u) - ppf_ref(u)| over u in [Phi(-3z), Phi(3z)] "
              "(fitted range) or over u in [0.001, 0.999] (median and max over the histograms).", ""]
    return [Section("Wire: bytes per capture against quantization error", lines)]


if __name__ == "__main__":
    print("\n".join(run()[0].markdown()))
