"""The project's PNG codec, numpy and zlib only: the robot reads mask files with it and the host
stores label maps with it (photographs of any format the host reads with OpenCV, tools.data.images).

Reads non-interlaced grayscale (1-16 bit), gray+alpha, RGB, RGBA (8/16 bit) and
indexed colour (1-8 bit); writes 8/16-bit grayscale, RGB and RGBA.
"""
from __future__ import annotations

import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

import numpy as np

SIGNATURE = b"\x89PNG\r\n\x1a\n"
CHANNELS = {0: 1, 2: 3, 3: 1, 4: 2, 6: 4}  # PNG colour type -> samples per pixel
DEPTHS = {0: (1, 2, 4, 8, 16), 2: (8, 16), 3: (1, 2, 4, 8), 4: (8, 16), 6: (8, 16)}
MAX_PIXELS = 1 << 28  # refuse absurd headers before allocating


@dataclass(frozen=True)
class PngImage:
    pixels: np.ndarray  # H x W (gray, indexed) or H x W x C; uint8 or uint16
    color_type: int
    bit_depth: int
    palette: np.ndarray | None  # N x 3 uint8 for indexed images


def _chunks(buf: bytes):
    pos = len(SIGNATURE)
    while pos + 8 <= len(buf):
        length, kind = struct.unpack(">I4s", buf[pos:pos + 8])
        body = buf[pos + 8:pos + 8 + length]
        crc = buf[pos + 8 + length:pos + 12 + length]
        if len(body) != length or len(crc) != 4:
            raise ValueError(f"png: truncated {kind!r} chunk")
        if zlib.crc32(kind + body) != struct.unpack(">I", crc)[0]:
            raise ValueError(f"png: bad CRC in {kind!r} chunk")
        yield kind, body
        pos += 12 + length
        if kind == b"IEND":
            return
    raise ValueError("png: missing IEND chunk (truncated file)")


def _unfilter(raw: np.ndarray, height: int, stride: int, bpp: int) -> np.ndarray:
    rows = raw.reshape(height, stride + 1)
    out = np.zeros((height, stride), dtype=np.uint8)
    prev = np.zeros(stride, dtype=np.uint8)
    for y in range(height):
        kind, line = rows[y, 0], rows[y, 1:]
        if kind == 0:
            cur = line.copy()
        elif kind == 1:  # Sub: a running sum per byte lane, wrapping mod 256
            cur = np.cumsum(line.reshape(-1, bpp), axis=0, dtype=np.uint8).ravel()
        elif kind == 2:
            cur = line + prev
        elif kind in (3, 4):
            cur = _sequential(line.tolist(), prev.tolist(), bpp, kind)
        else:
            raise ValueError(f"png: unknown filter type {kind} in row {y}")
        out[y] = cur
        prev = out[y]
    return out


def _sequential(line: list[int], up: list[int], bpp: int, kind: int) -> np.ndarray:
    """Average and Paeth depend on the byte just decoded; plain ints are fastest here."""
    cur = [0] * len(line)
    for i, f in enumerate(line):
        a = cur[i - bpp] if i >= bpp else 0
        b = up[i]
        if kind == 3:
            cur[i] = (f + ((a + b) >> 1)) & 255
            continue
        c = up[i - bpp] if i >= bpp else 0
        p = a + b - c
        pa, pb, pc = abs(p - a), abs(p - b), abs(p - c)
        pred = a if pa <= pb and pa <= pc else (b if pb <= pc else c)
        cur[i] = (f + pred) & 255
    return np.array(cur, dtype=np.uint8)


def decode_png(buf: bytes) -> PngImage:
    if not buf.startswith(SIGNATURE):
        raise ValueError("png: not a PNG file (bad signature)")
    header = None
    palette = None
    idat = []
    for kind, body in _chunks(buf):
        if kind == b"IHDR":
            if len(body) != 13:
                raise ValueError("png: malformed IHDR")
            header = struct.unpack(">IIBBBBB", body)
        elif kind == b"PLTE":
            palette = np.frombuffer(body, np.uint8).reshape(-1, 3).copy()
        elif kind == b"IDAT":
            idat.append(body)
    if header is None:
        raise ValueError("png: no IHDR chunk")
    width, height, depth, ctype, _comp, _filt, interlace = header
    if ctype not in CHANNELS or depth not in DEPTHS[ctype]:
        raise ValueError(f"png: unsupported colour type {ctype} with bit depth {depth}")
    if interlace:
        raise ValueError("png: interlaced images are not supported")
    if not (0 < width and 0 < height and width * height <= MAX_PIXELS):
        raise ValueError(f"png: bad image size {width}x{height}")
    if ctype == 3 and palette is None:
        raise ValueError("png: indexed image without a PLTE chunk")
    ch = CHANNELS[ctype]
    stride = (width * ch * depth + 7) // 8
    bpp = max(1, ch * depth // 8)
    expected = height * (stride + 1)
    inflater = zlib.decompressobj()
    try:
        data = inflater.decompress(b"".join(idat), expected)
    except zlib.error as exc:
        raise ValueError(f"png: corrupt image data ({exc})") from None
    if len(data) != expected:
        raise ValueError(f"png: image data holds {len(data)} bytes, expected {expected}")
    rows = _unfilter(np.frombuffer(data, np.uint8), height, stride, bpp)
    if depth == 16:
        px = rows.view(">u2").astype(np.uint16).reshape(height, width, ch)
    elif depth == 8:
        px = rows.reshape(height, width, ch)
    else:  # 1, 2, 4 bits: unpack big-endian fields and drop row padding
        bits = np.unpackbits(rows, axis=1).reshape(height, -1, depth)
        weights = (1 << np.arange(depth - 1, -1, -1)).astype(np.uint8)
        px = (bits * weights).sum(axis=2, dtype=np.uint8)[:, :width, None]
    px = px[..., 0] if ch == 1 else px
    return PngImage(np.ascontiguousarray(px), ctype, depth, palette)


def read_png(path: str | Path) -> PngImage:
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"png: no such file: {p}")
    return decode_png(p.read_bytes())


def _chunk(kind: bytes, body: bytes) -> bytes:
    return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))


def encode_png(image: np.ndarray) -> bytes:
    """PNG bytes for a uint8/uint16 H x W, H x W x 1, x 3 (RGB) or x 4 (RGBA) array."""
    a = np.asarray(image)
    if a.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"png: can only write uint8 or uint16, got {a.dtype}")
    if a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[2] not in (1, 3, 4) or a.shape[0] == 0 or a.shape[1] == 0:
        raise ValueError(f"png: can only write H x W x 1, 3 or 4 images, got shape {np.shape(image)}")
    h, w, ch = a.shape
    ctype = {1: 0, 3: 2, 4: 6}[ch]
    depth = 16 if a.dtype == np.uint16 else 8
    body = a.astype(">u2").view(np.uint8) if depth == 16 else a
    rows = np.zeros((h, 1 + w * ch * depth // 8), dtype=np.uint8)  # filter byte 0: None
    rows[:, 1:] = body.reshape(h, -1)
    ihdr = struct.pack(">IIBBBBB", w, h, depth, ctype, 0, 0, 0)
    return SIGNATURE + _chunk(b"IHDR", ihdr) + _chunk(b"IDAT", zlib.compress(rows.tobytes(), 6)) \
        + _chunk(b"IEND", b"")


def write_png(path: str | Path, image: np.ndarray) -> None:
    Path(path).write_bytes(encode_png(image))
