"""Reading and writing images and label masks on the host, with one-line errors.

Images are RGB uint8 (H, W, 3) in memory; masks are label arrays (H, W) uint8,
stored as single-channel PNG so every label value survives a round trip.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

if TYPE_CHECKING:
    from onboard.features import FeatureFrame, PcaBasis


class ImageError(ValueError):
    """A file that cannot be used as an image or mask; the message names the file and why."""


def _imread(p: Path, what: str) -> np.ndarray:
    if not p.is_file():
        raise ImageError(f"{what} {p}: {'not a regular file' if p.exists() else 'no such file'}")
    raw = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    if raw is None or raw.size == 0:
        raise ImageError(f"{what} {p}: not a readable image file")
    return raw


def read_image(path: str | Path) -> np.ndarray:
    """An image file as RGB uint8 (H, W, 3); grayscale files are repeated to three channels."""
    p = Path(path)
    raw = _imread(p, "image")
    if raw.dtype != np.uint8:
        raise ImageError(f"image {p}: {raw.dtype} pixels; only 8-bit images are supported")
    if raw.ndim == 2:
        return np.repeat(raw[:, :, None], 3, axis=2)
    if raw.shape[2] == 4:
        return cv2.cvtColor(raw, cv2.COLOR_BGRA2RGB)
    # In place: a copy would double the peak memory of a large image.
    return cv2.cvtColor(raw, cv2.COLOR_BGR2RGB, dst=raw)


def read_mask(path: str | Path, shape: tuple[int, int] | None = None) -> np.ndarray:
    """A label mask (H, W) uint8; `shape` (H, W) is the image it must match."""
    p = Path(path)
    raw = _imread(p, "mask")
    if raw.dtype != np.uint8:
        raise ImageError(f"mask {p}: {raw.dtype} pixels; masks are 8-bit label images")
    if raw.ndim == 3:
        # A colour-saved mask is usable only when its channels agree.
        if not all(np.array_equal(raw[:, :, 0], raw[:, :, c]) for c in range(1, min(3, raw.shape[2]))):
            raise ImageError(f"mask {p}: colour image; a mask holds one label per pixel")
        raw = raw[:, :, 0]
    if shape is not None and tuple(raw.shape) != tuple(shape[:2]):
        raise ImageError(
            f"mask {p}: size {raw.shape[1]}x{raw.shape[0]} differs from the image's "
            f"{shape[1]}x{shape[0]}"
        )
    return np.ascontiguousarray(raw)


def _write(path: Path, array: np.ndarray, what: str) -> None:
    if path.parent and not path.parent.exists():
        raise ImageError(f"{what} {path}: directory {path.parent} does not exist")
    ok = False
    try:
        ok = cv2.imwrite(str(path), array)
    except cv2.error as exc:
        raise ImageError(f"{what} {path}: cannot write ({str(exc).splitlines()[-1]})") from None
    if not ok:
        raise ImageError(f"{what} {path}: cannot write (unknown extension or unwritable place)")


def write_image(path: str | Path, image: np.ndarray) -> None:
    """Writes RGB (H, W, 3) or single-band (H, W) uint8 pixels."""
    img = np.asarray(image)
    if img.dtype != np.uint8:
        raise ImageError(f"image {path}: {img.dtype} pixels; expected uint8")
    if img.ndim == 3 and img.shape[2] == 3:
        img = img[:, :, ::-1]
    elif img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    elif img.ndim != 2:
        raise ImageError(f"image {path}: shape {img.shape}; expected (H, W) or (H, W, 3)")
    _write(Path(path), np.ascontiguousarray(img), "image")


def write_mask(path: str | Path, labels: np.ndarray) -> None:
    """Writes a label mask as a single-channel PNG (labels 0..255)."""
    lab = np.asarray(labels)
    if lab.ndim != 2:
        raise ImageError(f"mask {path}: shape {lab.shape}; expected (H, W)")
    if lab.size and (lab.min() < 0 or lab.max() > 255):
        raise ImageError(f"mask {path}: labels outside 0..255")
    p = Path(path)
    if p.suffix.lower() != ".png":
        raise ImageError(f"mask {p}: masks are written as .png so labels stay exact")
    _write(p, lab.astype(np.uint8, copy=False), "mask")


def encode_png(labels: np.ndarray) -> bytes:
    ok, buf = cv2.imencode(".png", np.ascontiguousarray(labels.astype(np.uint8)))
    if not ok:
        raise ImageError("mask: PNG encoding failed")
    return buf.tobytes()


def decode_png(data: bytes) -> np.ndarray:
    arr = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_UNCHANGED)
    if arr is None:
        raise ImageError("mask: stored PNG bytes are damaged")
    return arr


SPACES = ("rgb", "hsv", "gray", "pca")


def feature_bands(image: np.ndarray, space: str, pca=None):
    """The robot's own feature bands of an RGB image (onboard.features); pca fits a basis if none is given."""
    from onboard.features import FeatureSpace, FeatureSpec, PcaBasis, compute

    if space not in SPACES:
        raise ImageError(f"feature space {space!r}: expected one of {', '.join(SPACES)}")
    if space == "pca" and pca is None:
        pca = PcaBasis.fit(image)
    return compute(image, FeatureSpec(FeatureSpace(space)), pca=pca), pca


@dataclass(frozen=True)
class FittedImage:
    """An image on disk fitted with the robot's own FrameFitter, label by label, band by band."""

    feats: "FeatureFrame"
    pca: "PcaBasis | None"
    labels: np.ndarray  # the mask's labels, or all 0 without a mask
    results: dict


def fit_image(image_path: str | Path, mask_path: str | Path | None, space: str) -> FittedImage:
    """Read, convert and fit one image; ImageError (a ValueError) names what is wrong."""
    from onboard.fit import FrameFitter

    image = read_image(image_path)
    labels = read_mask(mask_path, image.shape[:2]) if mask_path else np.zeros(image.shape[:2], np.uint8)
    feats, pca = feature_bands(image, space)
    fitter = FrameFitter(int(labels.max()) + 1, feats.data.shape[2], bins=feats.levels)
    fitter.add(feats.data, labels)
    return FittedImage(feats, pca, labels, fitter.fit())


def to_rgb(bands: np.ndarray, space: str, pca=None) -> np.ndarray:
    """Synthesized feature bands back to a viewable RGB (or single-band) uint8 image."""
    if space == "rgb" or space == "gray":
        return bands if space == "rgb" else bands[:, :, 0]
    if space == "hsv":
        hsv = bands.copy()
        hsv[:, :, 0] = np.minimum(hsv[:, :, 0], 179)
        return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)
    if space == "pca":
        if pca is None:
            raise ImageError("pca bands need their basis to become an image")
        return np.rint(pca.invert(bands)).astype(np.uint8)
    raise ImageError(f"feature space {space!r}: cannot turn it back into an image")
