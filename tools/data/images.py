"""Reading and writing images and label masks on the host, with one-line errors.

Images are (H, W, 3) RGB, (H, W, 1) for one-band files (gray, thermal, elevation) or (H, W, N)
for a TIFF of N bands (multi-spectral) in memory, at their sensor depth: uint8 (256 levels) or
uint16 (65536 levels; 16-bit PNG and TIFF, and float images in 0..1 quantized to 16 bits). An
alpha channel is not a band: it is left out. An image keeps its bands: a one-band image is
fitted, synthesized and compared in gray, a colour one in rgb, any other count as its own bands
(raw, B0..Bn-1), written back as TIFF. Masks are label arrays (H, W) uint8, stored as
single-channel PNG so every label value survives a round trip.
"""
from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import cv2
import numpy as np

from btf.dependence import MAX_RADIUS, Dependence
from btf.fit.dependence import measure, observed
from btf.fit.features import FeatureFrame, FeatureSpace, FeatureSpec, PcaBasis, compute
from btf.fit.fitter import FrameFitter
from hal.image_files import TIFF_SUFFIXES, ImageFileError, opencv_bands, tiff_bands
from tools.analysis.pair_sums import every_pair
from tools.analysis.tiles import row_tiles
from tools.data.decoders import complaint, damage_said, native_stderr, png_problem

if TYPE_CHECKING:
    from btf.fit.features import FeatureFrame, PcaBasis


class ImageError(ValueError):
    """A file that cannot be used as an image or mask; the message names the file and why."""


def _imread(p: Path, what: str) -> np.ndarray:
    if not p.is_file():
        raise ImageError(f"{what} {p}: {'not a regular file' if p.exists() else 'no such file'}")
    with native_stderr() as said:  # libpng's and OpenCV's own lines: into ours, or dropped
        raw = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    if raw is None or raw.size == 0:
        damage = png_problem(p)
        why = f" ({damage}; copy or export it again)" if damage else f" ({complaint(said)})" if complaint(said) else ""
        raise ImageError(f"{what} {p}: not a readable image file{why}")
    if damage_said(said):  # pixels returned, but not the file's: part of it filled in
        raise ImageError(f"{what} {p}: damaged image file ({damage_said(said)}); copy or export it again")
    return raw


FLOAT_LEVELS = 65536  # a float image in 0..1 is read as 16-bit levels


def levels_of(image: np.ndarray) -> int:
    """The sensor levels of an image read by read_image: 256 (uint8) or 65536 (uint16)."""
    return 256 if image.dtype == np.uint8 else 65536


def _as_levels(raw: np.ndarray, p: Path) -> np.ndarray:
    """uint8 and uint16 pixels as they are; float in 0..1 as 16-bit levels; anything else refused."""
    if raw.dtype in (np.uint8, np.uint16):
        return raw
    if raw.dtype.kind != "f":
        raise ImageError(f"image {p}: {raw.dtype} pixels; expected 8- or 16-bit unsigned integers "
                         "or floating point in 0..1")
    if not np.isfinite(raw).all():
        raise ImageError(f"image {p}: floating-point pixels that are NaN or infinite")
    lo, hi = float(raw.min()), float(raw.max())
    if lo < 0.0 or hi > 1.0:
        raise ImageError(f"image {p}: floating-point pixels span {lo:g}..{hi:g}; expected 0..1 "
                         "(scale them, or save the image as 16-bit)")
    return np.rint(raw * (FLOAT_LEVELS - 1)).astype(np.uint16)


def read_image(path: str | Path) -> np.ndarray:
    """An image file as RGB (H, W, 3), (H, W, 1) for a one-band file or (H, W, N) for a TIFF of
    N bands, uint8 or uint16 (float images in 0..1 become uint16); alpha left out."""
    p = Path(path)
    tiff_said = ""
    if p.suffix.lower() in TIFF_SUFFIXES and p.is_file():
        try:
            bands, tiff_said = tiff_bands(p)
        except ImageFileError as exc:
            raise ImageError(f"image {exc}") from None
        if bands is not None:
            if bands.size == 0:
                raise ImageError(f"image {p}: no pixels")
            bands = _as_levels(bands, p)
            return bands[:, :, None] if bands.ndim == 2 else bands
    try:
        raw = _as_levels(_imread(p, "image"), p)
    except ImageError as exc:
        if tiff_said and str(exc).endswith("not a readable image file"):  # neither reader: say why tifffile could not
            raise ImageError(f"{exc} ({tiff_said}; copy or export it again)") from None
        raise
    return opencv_bands(raw, p)


def stretched_8bit(image: np.ndarray, span: tuple[int, int] | None = None) -> np.ndarray:
    """A 16-bit image as 8 bits over the levels it occupies, or `span` (all channels alike, so
    colours keep their order): what segmentation and viewing need, not the absolute levels."""
    if image.dtype == np.uint8:
        return image

    lo, hi = (int(image.min()), int(image.max())) if span is None else span
    scale = 255.0 / max(1, hi - lo)
    out = np.empty(image.shape, np.uint8)
    for r in row_tiles(image.shape[0], image.shape[1] * (image.shape[2] if image.ndim == 3 else 1)):
        out[r] = np.clip(np.rint((image[r].astype(np.float32) - lo) * np.float32(scale)), 0, 255)
    return out


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
        with native_stderr() as said:
            ok = cv2.imwrite(str(path), array)
    except cv2.error as exc:
        raise ImageError(f"{what} {path}: cannot write ({str(exc).splitlines()[-1]})") from None
    if not ok:
        why = complaint(said)
        raise ImageError(f"{what} {path}: cannot write ({why or 'unknown extension or unwritable place'})")


DEEP_SUFFIXES = (".png", ".tif", ".tiff")  # files that hold 16-bit pixels


def three_bands(image: np.ndarray) -> np.ndarray:
    """A one-band image repeated to RGB (what colour-only steps, segmentation, take); RGB as it is."""
    return np.repeat(image, 3, axis=2) if image.ndim == 3 and image.shape[2] == 1 else image


def band_count(image: np.ndarray) -> int:
    return 1 if image.ndim == 2 else image.shape[2]


COLOUR_NAMES = (("red", "r"), ("green", "g"), ("blue", "b"))  # band names a view draws as R, G and B


def colour_bands(names: tuple[str, ...] | None) -> tuple[int, int, int] | None:
    """The bands named red, green and blue (any case; or R, G, B), None unless all three are."""
    lowered = [n.lower() for n in names or ()]
    picks = [next((i for i, n in enumerate(lowered) if n in colour), None) for colour in COLOUR_NAMES]
    return None if None in picks else (picks[0], picks[1], picks[2])


def view_rgb(image: np.ndarray, reference: np.ndarray | None = None,
             names: tuple[str, ...] | None = None) -> np.ndarray:
    """8-bit RGB for a person to look at, 16-bit stretched over the levels `reference` (the
    photograph; default the image) occupies, so a synthesis and its photograph read alike: one
    band as gray, colour over its bands' common range, other counts as false colour, each band
    over its own range: of the bands `names` calls red, green and blue, else of the first three
    (the first two and the first again for two)."""
    ref = image if reference is None else reference
    if band_count(image) in (1, 3):
        span = None if ref.dtype == np.uint8 else (int(ref.min()), int(ref.max()))
        return three_bands(stretched_8bit(image, span))
    picks = colour_bands(names) or ((0, 1, 2) if image.shape[2] >= 3 else (0, 1, 0))
    return np.dstack([stretched_8bit(image[:, :, b:b + 1], (int(ref[..., b].min()), int(ref[..., b].max())))
                      for b in picks])


def segmentation_view(image: np.ndarray) -> np.ndarray:
    """What `btf-host mask` segments: 8-bit, a one-band image as gray RGB, a colour one over
    its bands' common range (their ratios kept), and other counts (multi-spectral: reflectance
    beside a thermal band in centikelvin) each band over its own range."""
    if band_count(image) in (1, 3):
        return three_bands(stretched_8bit(image))
    return np.dstack([stretched_8bit(image[:, :, b:b + 1]) for b in range(image.shape[2])])


def default_space(image: np.ndarray) -> str:
    """The feature space an image is fitted and compared in unless asked otherwise: its own
    bands, gray for a one-band image, rgb for a colour one and raw for any other count."""
    return {1: "gray", 3: "rgb"}.get(band_count(image), "raw")


def write_image(path: str | Path, image: np.ndarray) -> None:
    """Writes RGB (H, W, 3) or single-band (H, W) uint8 pixels, or uint16 as 16-bit PNG or TIFF;
    any other number of bands (H, W, N) as a TIFF of N bands."""
    img = np.asarray(image)
    if img.dtype not in (np.uint8, np.uint16):
        raise ImageError(f"image {path}: {img.dtype} pixels; expected uint8 or uint16")
    if img.dtype == np.uint16 and Path(path).suffix.lower() not in DEEP_SUFFIXES:
        raise ImageError(f"image {path}: 16-bit pixels need a .png or .tif file")
    if img.ndim == 3 and img.shape[2] not in (1, 3):
        _write_bands(Path(path), img)
        return
    if img.ndim == 3 and img.shape[2] == 3:
        img = img[:, :, ::-1]
    elif img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    elif img.ndim != 2:
        raise ImageError(f"image {path}: shape {img.shape}; expected (H, W) or (H, W, 3)")
    _write(Path(path), np.ascontiguousarray(img), "image")


def _write_bands(p: Path, img: np.ndarray) -> None:
    """N bands as one TIFF image of N samples (no colour, no alpha), which read_image reads back."""
    import tifffile

    if p.suffix.lower() not in TIFF_SUFFIXES:
        raise ImageError(f"image {p}: {img.shape[2]} bands need a .tif file (PNG holds one or three)")
    if p.parent and not p.parent.exists():
        raise ImageError(f"image {p}: directory {p.parent} does not exist")
    try:
        tifffile.imwrite(p, np.ascontiguousarray(img), photometric="minisblack", planarconfig="contig")
    except OSError as exc:
        raise ImageError(f"image {p}: cannot write ({exc.strerror or exc})") from None


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


SPACES = ("rgb", "hsv", "gray", "pca", "raw")
DEEP_SPACES = ("rgb", "gray", "raw")  # the spaces of 16-bit images


def feature_bands(image: np.ndarray, space: str | None = None, pca=None):
    """The robot's own feature bands of an image (btf.fit.features); `space` None follows the
    image (`default_space`); pca fits a basis if none is given. A one-band image in gray is its
    own band at its own depth; a 16-bit image keeps its depth: rgb and raw as they are, gray by
    OpenCV's weights. A one-band image has no colour space (its R, G and B would be one band three
    times, its hue and saturation 0); raw is any image's own bands."""
    space = default_space(image) if space is None else space
    if space not in SPACES:
        raise ImageError(f"feature space {space!r}: expected one of {', '.join(SPACES)}")
    if space == "raw":  # the bands as they are, at their depth
        return compute(image, FeatureSpec(FeatureSpace.RAW)), None
    if band_count(image) == 1 and space != "gray":
        raise ImageError(f"feature space {space}: the image is one band, which has no colours; "
                         "use gray (its own band, the default)")
    if band_count(image) not in (1, 3):
        raise ImageError(f"feature space {space}: the image has {band_count(image)} bands, and {space} is "
                         "made from one or three; fit its own bands with the raw space")
    if image.ndim == 3 and image.shape[2] == 1 and space == "gray":
        return FeatureFrame(np.ascontiguousarray(image), ("Y",), levels_of(image), FeatureSpace.GRAY), None
    image = three_bands(image)
    if image.dtype == np.uint16:
        if space not in DEEP_SPACES:
            raise ImageError(f"feature space {space}: 16-bit images are fitted in "
                             f"{' or '.join(DEEP_SPACES)} ({space} is defined for 8-bit pixels)")
        data = image if space == "rgb" else cv2.cvtColor(image, cv2.COLOR_RGB2GRAY)[:, :, None]
        names = ("R", "G", "B") if space == "rgb" else ("Y",)
        return FeatureFrame(data, names, 65536, FeatureSpace(space)), None
    if space == "pca" and pca is None:
        pca = PcaBasis.fit(image)
    return compute(image, FeatureSpec(FeatureSpace(space)), pca=pca), pca


# The host is not held to the robot's time per pose: it reads the grain over every pixel pair
# (tools.analysis.pair_sums; the robot's anchors missed the photograph's own autocorrelation by
# up to 0.20) on the widest window, so the lags out to 8 that a comparison reads are measured,
# not extended (benchmarks: "Texture synthesis on photographs").
HOST_RADIUS = MAX_RADIUS
# The band correlations from every pixel up to 16 MP: a lattice's few thousand points of a
# region with a long grain missed grace_hopper's background by 0.05.
HOST_CORR_POINTS = 1 << 24


@dataclass(frozen=True)
class FittedImage:
    """An image on disk fitted with the robot's own FrameFitter, label by label, band by band,
    with each region's grain and band dependence measured by the robot's own pass (over every
    pixel pair, on the window of HOST_RADIUS)."""

    feats: "FeatureFrame"
    pca: "PcaBasis | None"
    labels: np.ndarray  # the mask's labels, or all 0 without a mask
    results: dict
    dependence: dict  # {label: btf.dependence.Dependence}: observed levels, and grain when measured
    counts: np.ndarray | None = None  # the fitter's histograms, labels x bands x levels


def fit_image(image_path: str | Path, mask_path: str | Path | None, space: str | None = None,
              dependence: bool = True) -> FittedImage:
    """Read, convert and fit one image, keep each region's observed levels and measure its grain
    and band correlation (btf.fit.dependence) unless `dependence` is False; ImageError (a
    ValueError) names what is wrong."""
    image = read_image(image_path)
    labels = read_mask(mask_path, image.shape[:2]) if mask_path else np.zeros(image.shape[:2], np.uint8)
    feats, pca = feature_bands(image, space)
    del image
    return fit_bands(feats, pca, labels, dependence)


def fit_bands(feats: "FeatureFrame", pca: "PcaBasis | None", labels: np.ndarray,
              dependence: bool = True) -> FittedImage:
    """`fit_image` on feature bands in memory."""
    fitter = FrameFitter(int(labels.max()) + 1, feats.data.shape[2], bins=feats.levels)
    fitter.add(feats.data, labels)
    results = fitter.fit()
    seen = observed(fitter.counts, fitter.centre0, fitter.bin_width, feats.levels)
    fitted = {lab for lab, _ in results}
    if dependence and results:
        deps = measure(feats.data, labels, {k: r.model for k, r in results.items()}, feats.levels,
                       radius=HOST_RADIUS, levels_seen=seen, corr_points=HOST_CORR_POINTS, pair_sums=every_pair)
    else:
        deps = {lab: Dependence.observed(*seen[lab]) for lab in fitted if lab in seen}
    return FittedImage(feats, pca, labels, results, deps, fitter.counts)


def to_rgb(bands: np.ndarray, space: str, pca=None) -> np.ndarray:
    """Synthesized feature bands back to an image at their depth: RGB, one band, or raw bands."""
    if space in ("rgb", "gray", "raw"):  # raw: the bands as they are (a TIFF for other than one or three)
        return bands[:, :, 0] if bands.shape[2] == 1 else bands
    if space == "hsv":
        hsv = bands.copy()
        hsv[:, :, 0] = np.minimum(hsv[:, :, 0], 179)
        return cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB)
    if space == "pca":
        if pca is None:
            raise ImageError("pca bands need their basis to become an image")
        return np.rint(pca.invert(bands)).astype(np.uint8)
    raise ImageError(f"feature space {space!r}: cannot turn it back into an image")
