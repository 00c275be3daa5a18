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

# The driver prints VmHWM (kB) on its last stderr line, whatever the command printed before.
_DRIVER = """
import sys
from tools.cli import main
try:
    rc = main(sys.argv[1:])
finally:
    with open("/proc/self/status") as f:
        hwm = next(line.split()[1] for line in f if line.startswith("VmHWM:"))
    sys.stderr.write(f"\\nVmHWM {hwm}\\n")
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
    models = directory / "models.json"
    out = subprocess.run([sys.executable, "-m", "tools.cli", "fit", str(paths[0]), "--mask",
                          str(directory / "mask.png"), "--json"], capture_output=True, text=True, check=True)
    doc = json.loads(out.stdout)
    doc["angle"] = None
    models.write_text(json.dumps(doc))
    return Scene(paths[0], paths[1], directory / "mask.png", models, height, width)


def commands(scene: Scene, out: Path) -> dict[str, list[str]]:
    """The host commands whose memory is bounded, on a scene."""
    im, mask = str(scene.image), str(scene.mask)
    return {
        "compare": ["compare", im, str(scene.other), "--mask", mask, "--json"],
        "compare hsv": ["compare", im, str(scene.other), "--mask", mask, "--space", "hsv", "--json"],
        "synth": ["synth", "--model", str(scene.models), "--mask", mask, "--angle", "0", "--out",
                  str(out / "synth.png")],
        "pdfs": ["pdfs", im, "--mask", mask, "--json"],
        "mask isodata": ["mask", im, "--method", "isodata", "--k", "5", "--out", str(out / "iso.png")],
        "mask kmeans": ["mask", im, "--method", "kmeans", "--k", "5", "--out", str(out / "km.png")],
        "mask felzenszwalb": ["mask", im, "--method", "felzenszwalb", "--k", "5", "--out", str(out / "fz.png")],
        "mask slic": ["mask", im, "--method", "slic", "--k", "5", "--out", str(out / "slic.png")],
    }


def peak_rss(argv: list[str], timeout: float = 3600) -> tuple[int, int, str]:
    """(exit status, peak RSS in bytes, stderr without the measurement line) of `btf-host argv`."""
    env = dict(os.environ, OMP_NUM_THREADS=os.environ.get("OMP_NUM_THREADS", "2"))
    p = subprocess.run([sys.executable, "-c", _DRIVER, *argv], capture_output=True, text=True,
                       timeout=timeout, env=env)
    err, _, last = p.stderr.rstrip().rpartition("\n")
    if not last.startswith("VmHWM "):
        raise RuntimeError(f"btf-host {' '.join(argv)} ended without a measurement: {p.stderr[-500:]}")
    return p.returncode, int(last.split()[1]) * 1024, err


def per_pixel(big: Scene, tiny: Scene, out: Path, names: list[str]) -> dict[str, tuple[float, float]]:
    """For each command: (peak RSS / pixel, (peak - the tiny scene's peak) / extra pixel)."""
    result = {}
    for name in names:
        rc_small, small, err_small = peak_rss(commands(tiny, out)[name])
        rc, peak, err = peak_rss(commands(big, out)[name])
        if rc or rc_small:
            raise RuntimeError(f"{name} failed: {err or err_small}")
        result[name] = (peak / big.pixels, (peak - small) / (big.pixels - tiny.pixels))
    return result
