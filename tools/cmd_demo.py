"""`btf-host demo --out DIR`: fit a generated two-region texture and synthesize it back.

Interim: builds a textured test image with numpy, fits every (region, band) with the
onboard FrameFitter, draws each region's pixels from its models and writes both PNGs.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import cv2
import numpy as np

from onboard.fit import FrameFitter
from onboard.johnson import Johnson
from tools.cli import CliError


def add_parser(sub) -> argparse.ArgumentParser:
    p = sub.add_parser("demo", help="fit a generated texture and write a synthetic image beside it")
    p.add_argument("--out", default="demo-out", help="output directory (created if missing)")
    p.add_argument("--size", type=int, default=256, help="image side in pixels (default 256)")
    p.add_argument("--seed", type=int, default=1, help="random seed")
    return p


def texture(size: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """A sand-like upper region and a grass-like lower one, as BGR uint8 plus labels."""
    labels = np.zeros((size, size), dtype=np.uint8)
    yy, xx = np.mgrid[0:size, 0:size]
    labels[yy > size / 2 + 0.15 * size * np.sin(xx / size * 2 * np.pi)] = 1
    grain = cv2.GaussianBlur(rng.standard_normal((size, size)), (0, 0), 1.2)
    sand = np.stack([110 + 18 * grain, 160 + 20 * grain, 190 + 22 * grain], axis=-1)
    blades = rng.gamma(1.5, 18.0, (size, size, 1)) * np.array([0.6, 1.0, 0.5])
    grass = np.array([30, 70, 40]) + blades
    img = np.where(labels[..., None] == 0, sand, grass)
    return np.clip(np.rint(img), 0, 255).astype(np.uint8), labels


def synthesize(models: dict[tuple[int, int], Johnson], labels: np.ndarray, n_bands: int,
               rng: np.random.Generator) -> np.ndarray:
    out = np.zeros(labels.shape + (n_bands,), dtype=np.uint8)
    for (label, band), model in models.items():
        mask = labels == label
        out[..., band][mask] = model.sample_pixels(int(mask.sum()), rng)
    return out


def run(args: argparse.Namespace) -> int:
    if not 16 <= args.size <= 4096:
        raise CliError(f"--size must be between 16 and 4096, got {args.size}")
    out = Path(args.out)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CliError(f"cannot create output directory {out}: {exc.strerror}") from None
    rng = np.random.default_rng(args.seed)
    image, labels = texture(args.size, rng)
    fitter = FrameFitter(n_labels=2, n_bands=3)
    fitter.add(image, labels)
    results = fitter.fit()
    synth = synthesize({k: r.model for k, r in results.items()}, labels, 3, rng)
    for name, img in (("real.png", image), ("synthetic.png", synth)):
        if not cv2.imwrite(str(out / name), img):
            raise CliError(f"cannot write {out / name}")
    print(f"{'region':>6} {'band':>4} {'family':>6} {'gamma':>8} {'delta':>8} {'xi':>9} {'lam':>9} {'hist L1':>8}")
    for (label, band), r in sorted(results.items()):
        m = r.model
        data = np.bincount(image[..., band][labels == label], minlength=256) / r.count
        err = float(np.abs(data - m.level_probabilities()).sum())
        print(f"{label:>6} {'BGR'[band]:>4} {m.family:>6} {m.gamma:>8.3f} {m.delta:>8.3f} "
              f"{m.xi:>9.2f} {m.lam:>9.2f} {err:>8.4f}")
    print(f"wrote {out / 'real.png'} and {out / 'synthetic.png'}")
    return 0
