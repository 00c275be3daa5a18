"""Peak memory of `btf-host` commands on large images: scene files and a measuring subprocess.

`peak_rss(argv)` runs `btf-host argv` in a fresh interpreter and returns its exit status and
peak resident set (VmHWM). `per_pixel` subtracts the same command's peak on a tiny image (the
interpreter and its libraries), so what remains is what grows with the image.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

# Runs `btf-host` on a warm-up argv (libraries loaded), restarts VmHWM from the resident set
# (/proc/self/clear_refs), runs the measured argv and prints "before peak" in bytes last.
_DRIVER = """
import json, sys
from tools.cli import main

def status(key):
    with open("/proc/self/status") as f:
        return int(next(line.split()[1] for line in f if line.startswith(key + ":"))) * 1024

warm, argv = json.loads(sys.argv[1]), json.loads(sys.argv[2])
if warm and main(warm):
    sys.exit("warm-up run failed")
with open("/proc/self/clear_refs", "w") as f:
    f.write("5")
before = status("VmRSS")
try:
    rc = main(argv)
finally:
    sys.stderr.write(f"\\nPEAK {before} {status('VmHWM')}\\n")
sys.exit(rc)
"""


@dataclass(frozen=True)
class Scene:
    """Files of one synthetic scene: two RGB images of the same clutter, its mask, its models."""

    image: Path
    other: Path
    mask: Path
    models: Path
    height: int
    width: int

    @property
    def pixels(self) -> int:
        return self.height * self.width


def make_scene(directory: Path, height: int, width: int, labels: int = 6, seed: int = 0) -> Scene:
    """Irregular regions (nearest of `labels` seeds on a coarse grid, upscaled) of distinct
    colours with pixel noise; `other` is the same clutter with other noise. Built in row
    blocks, so making a 20000 x 20000 scene needs little more than its images."""
    directory.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    ch, cw = max(1, height // 64), max(1, width // 64)
    pts = rng.uniform((0, 0), (ch, cw), (labels, 2))
    yy, xx = np.mgrid[0:ch, 0:cw]
    coarse = np.argmin((yy[..., None] - pts[:, 0]) ** 2 + (xx[..., None] - pts[:, 1]) ** 2, axis=2)
    mask = cv2.resize(coarse.astype(np.uint8), (width, height), interpolation=cv2.INTER_NEAREST)
    base = rng.integers(40, 200, (labels, 3)).astype(np.int16)
    paths = []
    for k, name in enumerate(("image.png", "other.png")):
        img = np.empty((height, width, 3), np.uint8)
        noise = np.random.default_rng(seed + 1 + k)
        for r in range(0, height, 512):
            m = mask[r:r + 512]
            block = base[m] + noise.integers(-24, 25, m.shape + (3,), dtype=np.int16)
            img[r:r + 512] = np.clip(block, 0, 255)
        cv2.imwrite(str(directory / name), img[:, :, ::-1], [cv2.IMWRITE_PNG_COMPRESSION, 1])
        paths.append(directory / name)
        del img
    cv2.imwrite(str(directory / "mask.png"), mask)
    from tools.analysis.synth import models_document
    from tools.data.images import fit_image

    fitted = fit_image(paths[0], directory / "mask.png", "rgb")
    models = directory / "models.json"
    models.write_text(json.dumps(models_document("rgb", fitted.feats.band_names, fitted.feats.levels,
                                                 None, fitted.results)))
    return Scene(paths[0], paths[1], directory / "mask.png", models, height, width)


def commands(scene: Scene, out: Path) -> dict[str, list[str]]:
    """The host commands whose memory is bounded, on a scene."""
    im, mask = str(scene.image), str(scene.mask)
    tag = f"{scene.width}x{scene.height}"  # outputs named per scene: commands refuse to overwrite
    return {
        "compare": ["compare", im, str(scene.other), "--mask", mask, "--json"],
        "compare hsv": ["compare", im, str(scene.other), "--mask", mask, "--space", "hsv", "--json"],
        "synth": ["synth", "--model", str(scene.models), "--mask", mask, "--angle", "0", "--out",
                  str(out / f"synth-{tag}.png")],
        "pdfs": ["pdfs", im, "--mask", mask, "--json"],
        **{f"mask {m}": ["mask", im, "--method", m, "--k", "5", "--out", str(out / f"{m}-{tag}.png")]
           for m in ("isodata", "kmeans", "felzenszwalb", "slic")},
    }


def measuring_env() -> dict[str, str]:
    """The environment of a measured process: glibc's malloc with a fixed mmap threshold, so
    every array of 128 kB or more is returned to the system when freed and the resident set
    follows what the program holds (by default the threshold grows to 32 MB after the first
    large free, and freed blocks below it stay resident, blurring small measurements)."""
    return dict(os.environ, MALLOC_MMAP_THRESHOLD_="131072", MALLOC_TRIM_THRESHOLD_="131072")


def peak_rss(argv: list[str], warm: list[str] | None = None, timeout: float = 3600) -> tuple[int, int, int, str]:
    """(exit status, resident set before, peak resident set, stderr without the measurement
    line) of `btf-host argv` in a fresh interpreter, after a `warm` run in the same process."""
    p = subprocess.run([sys.executable, "-c", _DRIVER, json.dumps(warm or []), json.dumps(argv)],
                       capture_output=True, text=True, timeout=timeout, env=measuring_env())
    err, _, last = p.stderr.rstrip().rpartition("\n")
    if not last.startswith("PEAK "):
        raise RuntimeError(f"btf-host {' '.join(argv)} ended without a measurement: {p.stderr[-500:]}")
    _, before, peak = last.split()
    return p.returncode, int(before), int(peak), err


def per_pixel(big: Scene, tiny: Scene, out: Path, names: list[str]) -> dict[str, tuple[float, float]]:
    """For each command: (peak RSS / pixel, (peak - the resident set after the same command
    on the tiny scene) / pixel): the whole process, and what grew with the image."""
    result = {}
    for name in names:
        rc, before, peak, err = peak_rss(commands(big, out)[name], warm=commands(tiny, out)[name])
        if rc:
            raise RuntimeError(f"{name} failed: {err}")
        result[name] = (peak / big.pixels, (peak - before) / big.pixels)
    return result
