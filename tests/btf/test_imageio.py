"""PNG reading and writing against OpenCV and Pillow, every filter type, and bad files."""
import struct
import zlib

import cv2
import numpy as np
import pytest
from PIL import Image

from btf.fit.png import decode_png, encode_png, read_png, write_png


def _smooth_rgb(h=40, w=57, seed=0):
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w]
    base = (xx * 3 + yy * 2) % 256
    return np.stack([base, (base * 7) % 256, rng.integers(0, 256, (h, w))], -1).astype(np.uint8)


def _png_with_filter(img: np.ndarray, filt: int) -> bytes:
    """A PNG whose every row uses filter `filt` (0..4), encoded independently of the reader."""
    a = img[..., None] if img.ndim == 2 else img
    h, w, ch = a.shape
    x = a.reshape(h, w * ch).astype(np.int32)
    bpp = ch
    left = np.zeros_like(x)
    left[:, bpp:] = x[:, :-bpp]
    up = np.zeros_like(x)
    up[1:] = x[:-1]
    ul = np.zeros_like(x)
    ul[1:, bpp:] = x[:-1, :-bpp]
    if filt == 0:
        pred = 0
    elif filt == 1:
        pred = left
    elif filt == 2:
        pred = up
    elif filt == 3:
        pred = (left + up) // 2
    else:
        p = left + up - ul
        pa, pb, pc = abs(p - left), abs(p - up), abs(p - ul)
        pred = np.where((pa <= pb) & (pa <= pc), left, np.where(pb <= pc, up, ul))
    rows = np.column_stack([np.full(h, filt), (x - pred) % 256]).astype(np.uint8)
    ctype = {1: 0, 3: 2, 4: 6}[ch]

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, ctype, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(rows.tobytes())) + chunk(b"IEND", b""))


@pytest.mark.parametrize("filt", range(5))
@pytest.mark.parametrize("channels", [1, 3, 4])
def test_every_filter_type_decodes_exactly(filt, channels):
    img = _smooth_rgb(seed=filt)
    img = img[..., 0] if channels == 1 else (img if channels == 3 else np.dstack([img, img[..., 1]]))
    np.testing.assert_array_equal(decode_png(_png_with_filter(img, filt)).pixels, img)


def test_reads_what_opencv_writes(tmp_path):
    img = _smooth_rgb(seed=1)
    cv2.imwrite(str(tmp_path / "rgb.png"), img[..., ::-1])
    np.testing.assert_array_equal(read_png(tmp_path / "rgb.png").pixels, img)
    g16 = (img[..., 0].astype(np.uint16) * 257 + img[..., 2]).astype(np.uint16)
    cv2.imwrite(str(tmp_path / "g16.png"), g16)
    got = read_png(tmp_path / "g16.png")
    assert got.bit_depth == 16 and got.pixels.dtype == np.uint16
    np.testing.assert_array_equal(got.pixels, g16)


@pytest.mark.parametrize("mode", ["1", "L", "LA", "P", "RGBA"])
def test_reads_what_pillow_writes(tmp_path, mode):
    Image.fromarray(_smooth_rgb(seed=2)).convert(mode).save(tmp_path / "x.png")
    ref = np.array(Image.open(tmp_path / "x.png")).astype(np.uint8)
    got = read_png(tmp_path / "x.png")
    np.testing.assert_array_equal(got.pixels, ref)
    assert (got.palette is not None) == (mode == "P")


@pytest.mark.parametrize("bits", [2, 4])
def test_reads_low_bit_depth_indexed_images(tmp_path, bits):
    labels = (np.add.outer(np.arange(13), np.arange(29)) % (1 << bits)).astype(np.uint8)
    im = Image.fromarray(labels, "P")
    im.putpalette(list(range(3 * (1 << bits))))
    im.save(tmp_path / "p.png", bits=bits)
    got = read_png(tmp_path / "p.png")
    assert got.bit_depth == bits
    np.testing.assert_array_equal(got.pixels, labels)


@pytest.mark.parametrize("shape, dtype", [((9, 11), np.uint8), ((9, 11), np.uint16),
                                          ((9, 11, 3), np.uint8), ((9, 11, 4), np.uint16)])
def test_writes_what_opencv_reads(tmp_path, shape, dtype):
    img = np.random.default_rng(3).integers(0, np.iinfo(dtype).max + 1, shape).astype(dtype)
    write_png(tmp_path / "w.png", img)
    back = cv2.imread(str(tmp_path / "w.png"), cv2.IMREAD_UNCHANGED)
    if img.ndim == 3:
        back = cv2.cvtColor(back, cv2.COLOR_BGR2RGB if shape[2] == 3 else cv2.COLOR_BGRA2RGBA)
    np.testing.assert_array_equal(back, img)
    np.testing.assert_array_equal(read_png(tmp_path / "w.png").pixels, img)


def test_bad_files_name_the_problem(tmp_path):
    good = encode_png(np.zeros((4, 5), np.uint8))
    with pytest.raises(ValueError, match="signature"):
        decode_png(b"GIF89a" + good)
    with pytest.raises(ValueError, match="CRC"):
        decode_png(good[:20] + bytes([good[20] ^ 1]) + good[21:])
    with pytest.raises(ValueError, match="truncated|IEND"):
        decode_png(good[:-12])
    with pytest.raises(ValueError, match="no such file"):
        read_png(tmp_path / "missing.png")
    ihdr = good[16:29]
    laced = ihdr[:12] + b"\x01"
    crc = struct.pack(">I", zlib.crc32(b"IHDR" + laced))
    with pytest.raises(ValueError, match="interlaced"):
        decode_png(good[:16] + laced + crc + good[33:])
    with pytest.raises(ValueError, match="uint8 or uint16"):
        encode_png(np.zeros((3, 3), np.float32))
    with pytest.raises(ValueError, match="shape"):
        encode_png(np.zeros((3, 3, 2), np.uint8))


def test_short_image_data_is_rejected():
    body = struct.pack(">IIBBBBB", 10, 10, 8, 0, 0, 0, 0)

    def chunk(kind, b):
        return struct.pack(">I", len(b)) + kind + b + struct.pack(">I", zlib.crc32(kind + b))

    png = b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", body) + chunk(b"IDAT", zlib.compress(b"\0" * 50)) + chunk(b"IEND", b"")
    with pytest.raises(ValueError, match="expected 110"):
        decode_png(png)
