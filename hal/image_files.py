"""Image files of any number of bands, for the robot's replay camera and the host's readers.

OpenCV reads PNG, JPEG and TIFF of one, three or four channels, and turns a gray-with-alpha PNG
into four. A multi-spectral camera's TIFF has five or six bands (OpenCV refuses it) or four
(OpenCV takes the fourth for alpha and drops it). So a TIFF is read with tifffile, its bands as
stored: contiguous or planar samples, or one band a page, samples marked as alpha left out;
and a PNG's colour type tells gray-with-alpha apart from colour.
"""
from __future__ import annotations

import logging
import math
from pathlib import Path

import cv2
import numpy as np

TIFF_SUFFIXES = (".tif", ".tiff")
MAX_PIXELS = 1 << 30  # OpenCV's own limit (CV_IO_MAX_IMAGE_PIXELS): a header cannot make us allocate more
_BAND_AXES = "SCQI"  # tifffile's names for an axis of samples, channels or pages that are bands
_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_PNG_GRAY_ALPHA = 4  # the IHDR colour type of gray with alpha


class ImageFileError(ValueError):
    """A file that holds an image we will not read; the message starts with its path."""


def tiff_bands(path: Path) -> tuple[np.ndarray | None, str]:
    """(the TIFF's bands as stored, (H, W) or (H, W, N), ""), or (None, why tifffile cannot
    decode it: a damaged file, a compression it lacks) for another reader to try.
    ImageFileError for a TIFF that is not one image of bands, or too large."""
    import tifffile

    # its notes on odd tags would be lines of their own on stderr; what is wrong is said once, by the caller
    logging.getLogger("tifffile").disabled = True
    try:
        with tifffile.TiffFile(path) as tif:
            series = tif.series[0]
            axes = series.axes
            pixels = math.prod(n for a, n in zip(axes, series.shape) if a in "YX")
            if pixels > MAX_PIXELS:
                raise ImageFileError(f"{path}: {pixels} pixels, more than the {MAX_PIXELS} an image may have "
                                     "(OpenCV's limit too); cut it into tiles")
            data = series.asarray()
            extra = [int(v) for v in (tif.pages[0].extrasamples or ())]
    except ImageFileError:
        raise
    except Exception as exc:  # any way tifffile fails to decode: another reader tries
        return None, " ".join(str(exc).split())[:120] or type(exc).__name__
    if data.dtype == np.bool_:  # a bilevel scan: black and white at 8 bits, as OpenCV reads it
        data = data.astype(np.uint8) * np.uint8(255)
    if data.ndim == 2:
        return data, ""
    if data.ndim != 3 or not (axes[-1] in _BAND_AXES or (axes[0] in _BAND_AXES and axes[1:] == "YX")):
        raise ImageFileError(f"{path}: a TIFF of axes {axes} {data.shape}; expected one image of bands "
                             "(height, width and one axis of bands)")
    bands = data if axes[-1] in _BAND_AXES else np.moveaxis(data, 0, -1)
    n = bands.shape[2]  # extra samples are the last ones; 1 and 2 are associated and unassociated alpha
    alpha = {n - len(extra) + k for k, v in enumerate(extra) if v in (1, 2)}
    if alpha and len(alpha) < n:
        bands = bands[:, :, [b for b in range(n) if b not in alpha]]
    return np.ascontiguousarray(bands), ""


def gray_with_alpha(path: Path) -> bool:
    """Whether `path` is a PNG of gray with alpha (which OpenCV reads as four channels)."""
    if path.suffix.lower() != ".png":
        return False
    with open(path, "rb") as f:
        head = f.read(26)
    return len(head) == 26 and head.startswith(_PNG_SIGNATURE) and head[25] == _PNG_GRAY_ALPHA


def opencv_bands(image: np.ndarray, path: Path) -> np.ndarray:
    """The channels OpenCV decoded from `path` (gray, or B, G, R and maybe alpha) as bands: one
    band for gray and for gray with alpha (which OpenCV reads as four), colour as R, G, B."""
    if image.ndim == 2:
        return image[..., None]
    n = image.shape[2]
    if n <= 2 or (n == 4 and gray_with_alpha(path)):
        return np.ascontiguousarray(image[..., :1])
    if n == 4:
        return cv2.cvtColor(image, cv2.COLOR_BGRA2RGB)
    return cv2.cvtColor(image, cv2.COLOR_BGR2RGB, dst=image)  # in place: a copy would double a large image's peak
