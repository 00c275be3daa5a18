"""Feature bands from a camera frame: rgb, hsv, gray, pca and raw multi-band.

Only the bands a `FeatureSpec` asks for are computed, in bounded row chunks. The
8-bit conversions are bit-exact with OpenCV's `cvtColor` (RGB2HSV, RGB2GRAY) so the
robot and a host using cv2 see the same numbers; the robot itself never imports cv2.
"""
from __future__ import annotations

import enum
from dataclasses import dataclass

import numpy as np

# Pixels per chunk: keeps temporaries (a few int16/int32 arrays) near a megabyte.
CHUNK_PIXELS = 1 << 16


class FeatureSpace(enum.Enum):
    RGB = "rgb"
    HSV = "hsv"
    GRAY = "gray"
    PCA = "pca"
    RAW = "raw"


BAND_NAMES: dict[FeatureSpace, tuple[str, ...]] = {
    FeatureSpace.RGB: ("R", "G", "B"),
    FeatureSpace.HSV: ("H", "S", "V"),
    FeatureSpace.GRAY: ("Y",),
}


@dataclass(frozen=True)
class FeatureSpec:
    """What to compute. `bands=None` means every band of the space.

    `names` names the channels of a raw frame (default B0..Bn-1); `bgr` says the
    frame's channels are in OpenCV's B,G,R order rather than R,G,B.
    """

    space: FeatureSpace
    bands: tuple[str, ...] | None = None
    names: tuple[str, ...] | None = None
    bgr: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.space, FeatureSpace):
            object.__setattr__(self, "space", FeatureSpace(self.space))
        if self.bands is not None:
            if len(self.bands) == 0:
                raise ValueError("feature spec: bands is empty (use None for all bands)")
            if len(set(self.bands)) != len(self.bands):
                raise ValueError(f"feature spec: duplicate band in {list(self.bands)}")
            known = BAND_NAMES.get(self.space)
            if known is not None:
                bad = [b for b in self.bands if b not in known]
                if bad:
                    raise ValueError(
                        f"feature spec: unknown {self.space.value} band(s) {bad}; "
                        f"valid are {list(known)}"
                    )


@dataclass(frozen=True)
class FeatureFrame:
    data: np.ndarray  # H x W x B, uint8 or uint16
    band_names: tuple[str, ...]
    levels: int  # 256 or 65536
    space: FeatureSpace

    def band(self, name: str) -> np.ndarray:
        try:
            return self.data[..., self.band_names.index(name)]
        except ValueError:
            raise ValueError(f"no band {name!r}; this frame has {list(self.band_names)}") from None


# --- OpenCV-exact 8-bit tables --------------------------------------------------------
_HSV_SHIFT = 12
_GRAY_SHIFT = 15
_GRAY_COEFFS = (9798, 19235, 3735)  # 0.299, 0.587, 0.114 in Q15; OpenCV's 8-bit path


def _round_half_even(x: np.ndarray) -> np.ndarray:
    return np.rint(x).astype(np.int64)


def _hsv_tables() -> tuple[np.ndarray, np.ndarray]:
    i = np.arange(256, dtype=np.float64)
    with np.errstate(divide="ignore"):
        sdiv = np.where(i > 0, _round_half_even((255 << _HSV_SHIFT) / np.maximum(i, 1)), 0)
        hdiv = np.where(i > 0, _round_half_even((180 << _HSV_SHIFT) / (6.0 * np.maximum(i, 1))), 0)
    half = 1 << (_HSV_SHIFT - 1)
    v = np.arange(256)[:, None]
    d = np.arange(256)[None, :]
    s_lut = ((d * sdiv[v] + half) >> _HSV_SHIFT).clip(0, 255).astype(np.uint8)  # [v, diff]
    num = np.arange(-255, 5 * 255 + 1)[:, None]  # hue numerator range over all cases
    h = (num * hdiv[d] + half) >> _HSV_SHIFT
    h = np.where(h < 0, h + 180, h).clip(0, 179).astype(np.uint8)  # [num + 255, diff]
    return s_lut.ravel(), h.ravel()


_S_LUT, _H_LUT = _hsv_tables()


def _hsv_chunk(rgb: np.ndarray, want: tuple[str, ...], out: np.ndarray, cols: list[int]) -> None:
    r, g, b = (rgb[:, k] for k in range(3))
    v = np.maximum(np.maximum(r, g), b)
    if "V" in want:
        out[:, cols[want.index("V")]] = v
    if "S" not in want and "H" not in want:
        return
    diff = v - np.minimum(np.minimum(r, g), b)
    vi = v.astype(np.intp)
    di = diff.astype(np.intp)
    if "S" in want:
        out[:, cols[want.index("S")]] = _S_LUT[(vi << 8) | di]
    if "H" in want:
        out[:, cols[want.index("H")]] = _H_LUT[_hue_index(r, g, b, v, di)]


def _hue_index(r: np.ndarray, g: np.ndarray, b: np.ndarray, v: np.ndarray, di: np.ndarray) -> np.ndarray:
    ri, gi, bi = (c.astype(np.int16) for c in (r, g, b))
    d16 = di.astype(np.int16)
    vr = v == r
    vg = (v == g) & ~vr
    num = np.where(vr, gi - bi, np.where(vg, bi - ri + 2 * d16, ri - gi + 4 * d16))
    return ((num.astype(np.intp) + 255) << 8) | di


def _gray_chunk(rgb: np.ndarray) -> np.ndarray:
    cr, cg, cb = _GRAY_COEFFS
    acc = rgb[:, 0].astype(np.int32) * cr
    acc += rgb[:, 1].astype(np.int32) * cg
    acc += rgb[:, 2].astype(np.int32) * cb
    acc += 1 << (_GRAY_SHIFT - 1)
    acc >>= _GRAY_SHIFT
    return acc.astype(np.uint8)


# --- PCA ------------------------------------------------------------------------------
@dataclass(frozen=True)
class PcaBasis:
    """A decorrelating rotation fitted once per scene, with an 8-bit scale per component.

    q = clip(rint(((x - mean) @ rotation) * scale + offset), 0, 255); `invert` maps q back.
    """

    mean: tuple[float, ...]
    rotation: tuple[tuple[float, ...], ...]  # n x n, column k is component P(k+1)
    scale: tuple[float, ...]
    offset: tuple[float, ...]

    @property
    def n(self) -> int:
        return len(self.mean)

    @staticmethod
    def fit(frame: np.ndarray, sample: int = 20000, seed: int = 0, margin: float = 0.1) -> "PcaBasis":
        x = _as_pixels(frame, np.uint8, "pca")
        if sample < 2:
            raise ValueError(f"pca: sample must be at least 2, got {sample}")
        rng = np.random.default_rng(seed)
        pick = x if len(x) <= sample else x[np.sort(rng.choice(len(x), sample, replace=False))]
        pick = pick.astype(np.float64)
        mean = pick.mean(axis=0)
        n = x.shape[1]
        cov = np.cov(pick - mean, rowvar=False).reshape(n, n) if len(pick) > 1 else np.zeros((n, n))
        w, vecs = np.linalg.eigh(cov)
        vecs = vecs[:, np.argsort(w)[::-1]]
        # Sign convention: each component's largest-magnitude weight is positive.
        signs = np.sign(vecs[np.argmax(np.abs(vecs), axis=0), np.arange(n)])
        vecs = vecs * np.where(signs == 0, 1.0, signs)
        proj = (pick - mean) @ vecs
        lo, hi = proj.min(axis=0), proj.max(axis=0)
        pad = margin * (hi - lo)
        # Never reach past what any 8-bit pixel can project to.
        cube_lo = (np.minimum(vecs, 0) * 255).sum(axis=0) - mean @ vecs
        cube_hi = (np.maximum(vecs, 0) * 255).sum(axis=0) - mean @ vecs
        lo = np.maximum(lo - pad, cube_lo)
        hi = np.minimum(hi + pad, cube_hi)
        span = np.maximum(hi - lo, 8.0)  # constant scenes: keep the scale finite
        centre = (lo + hi) / 2
        scale = 255.0 / span
        offset = 127.5 - centre * scale
        return PcaBasis(
            mean=tuple(float(m) for m in mean),
            rotation=tuple(tuple(float(v) for v in row) for row in vecs),
            scale=tuple(float(s) for s in scale),
            offset=tuple(float(o) for o in offset),
        )

    def _affine(self) -> tuple[np.ndarray, np.ndarray]:
        rot = np.asarray(self.rotation, dtype=np.float64)
        m = rot * np.asarray(self.scale)[None, :]
        c = np.asarray(self.offset) - np.asarray(self.mean) @ m
        return m.astype(np.float32), c.astype(np.float32)

    def apply(self, frame: np.ndarray, cols: tuple[int, ...] | None = None) -> np.ndarray:
        """H x W x len(cols) uint8 components (all of them by default)."""
        x = _as_pixels(frame, np.uint8, "pca")
        if x.shape[1] != self.n:
            raise ValueError(f"pca: basis is for {self.n} channels, frame has {x.shape[1]}")
        m, c = self._affine()
        sel = list(range(self.n)) if cols is None else list(cols)
        m, c = m[:, sel], c[sel]
        out = np.empty((len(x), len(sel)), dtype=np.uint8)
        for a in range(0, len(x), CHUNK_PIXELS):
            y = x[a:a + CHUNK_PIXELS].astype(np.float32) @ m
            y += c
            np.rint(y, out=y)
            np.clip(y, 0, 255, out=y)
            out[a:a + CHUNK_PIXELS] = y
        return out.reshape(frame.shape[:2] + (len(sel),))

    def invert(self, q: np.ndarray) -> np.ndarray:
        """Components (H x W x n, any numeric type) back to the original space, float64 in 0..255."""
        q = np.asarray(q, dtype=np.float64)
        if q.shape[-1] != self.n:
            raise ValueError(f"pca: expected {self.n} components in the last axis, got {q.shape[-1]}")
        rot = np.asarray(self.rotation)
        y = (q - np.asarray(self.offset)) / np.asarray(self.scale)
        return np.clip(y @ rot.T + np.asarray(self.mean), 0.0, 255.0)

    def to_record(self) -> dict[str, list]:
        return {"mean": list(self.mean), "rotation": [list(r) for r in self.rotation],
                "scale": list(self.scale), "offset": list(self.offset)}

    @staticmethod
    def from_record(rec: dict) -> "PcaBasis":
        try:
            mean = tuple(float(v) for v in rec["mean"])
            rot = tuple(tuple(float(v) for v in row) for row in rec["rotation"])
            scale = tuple(float(v) for v in rec["scale"])
            offset = tuple(float(v) for v in rec["offset"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"pca record: malformed ({exc})") from None
        n = len(mean)
        if n == 0 or len(rot) != n or any(len(r) != n for r in rot) or len(scale) != n or len(offset) != n:
            raise ValueError("pca record: mean, rotation, scale and offset sizes disagree")
        vals = np.array(mean + scale + offset + sum(rot, ()))
        if not np.all(np.isfinite(vals)) or min(scale) <= 0:
            raise ValueError("pca record: non-finite value or non-positive scale")
        return PcaBasis(mean, rot, scale, offset)


    # Packet extras carry lists of at most 64 scalars: a basis of up to 8 channels fits.
    EXTRA_KEYS = ("pca_mean", "pca_rotation", "pca_scale", "pca_offset")

    def to_extras(self) -> dict[str, list[float]]:
        """The basis as packet extras (rotation flattened row by row), for the host to invert."""
        if self.n > 8:
            raise ValueError(f"pca: a {self.n}-channel basis does not fit packet extras (at most 8)")
        return {"pca_mean": list(self.mean), "pca_rotation": [v for row in self.rotation for v in row],
                "pca_scale": list(self.scale), "pca_offset": list(self.offset)}

    @staticmethod
    def from_extras(extras: dict) -> "PcaBasis | None":
        """The basis in a packet's extras; None if it carries none, ValueError if malformed."""
        keys = PcaBasis.EXTRA_KEYS
        present = [k for k in keys if k in extras]
        if not present:
            return None
        if len(present) != len(keys):
            raise ValueError(f"pca extras: missing {sorted(set(keys) - set(present))}")
        for k in keys:
            v = extras[k]
            if not isinstance(v, (list, tuple)) or any(type(x) not in (int, float) for x in v):
                raise ValueError(f"pca extras: {k} must be a list of numbers")
        flat = list(extras["pca_rotation"])
        n = len(extras["pca_mean"])
        if n == 0 or len(flat) != n * n:
            raise ValueError(f"pca extras: rotation has {len(flat)} values for {n} channels")
        rows = [flat[i * n:(i + 1) * n] for i in range(n)]
        return PcaBasis.from_record({"mean": extras["pca_mean"], "rotation": rows,
                                     "scale": extras["pca_scale"], "offset": extras["pca_offset"]})


# --- compute --------------------------------------------------------------------------
def _remedy(frame: np.ndarray) -> str:
    """The space that reads a frame the colour spaces cannot."""
    return "space gray fits a one-band camera" if frame.shape[2] == 1 else "space raw fits the camera's own bands"


def _as_pixels(frame: np.ndarray, dtype: type, what: str) -> np.ndarray:
    if not isinstance(frame, np.ndarray) or frame.ndim != 3:
        raise ValueError(f"{what}: frame must be an H x W x C array, got shape {np.shape(frame)}")
    if frame.dtype != dtype:
        raise ValueError(f"{what}: frame must be {np.dtype(dtype).name}, got {frame.dtype} ({_remedy(frame)})")
    if frame.shape[0] == 0 or frame.shape[1] == 0:
        raise ValueError(f"{what}: frame is empty ({frame.shape})")
    return frame.reshape(-1, frame.shape[2])


def _rgb_pixels(frame: np.ndarray, spec: FeatureSpec) -> np.ndarray:
    x = _as_pixels(frame, np.uint8, spec.space.value)
    if x.shape[1] not in (3, 4):
        raise ValueError(f"{spec.space.value}: frame needs 3 colour channels, got {x.shape[1]} ({_remedy(frame)})")
    x = x[:, :3]
    return x[:, ::-1] if spec.bgr else x


def compute(frame: np.ndarray, spec: FeatureSpec, pca: PcaBasis | None = None) -> FeatureFrame:
    """The bands `spec` asks for, and nothing more."""
    space = spec.space
    if space is FeatureSpace.RAW:
        return _raw(frame, spec)
    if space is FeatureSpace.PCA:
        if pca is None:
            raise ValueError("pca: a PcaBasis is required (fit one per scene with PcaBasis.fit)")
        names = tuple(f"P{k + 1}" for k in range(pca.n))
        want = spec.bands or names
        bad = [b for b in want if b not in names]
        if bad:
            raise ValueError(f"pca: unknown band(s) {bad}; valid are {list(names)}")
        src = frame[..., ::-1] if spec.bgr and frame.ndim == 3 else frame
        data = pca.apply(src, tuple(names.index(b) for b in want))
        return FeatureFrame(data, tuple(want), 256, space)
    want = spec.bands or BAND_NAMES[space]
    if space is FeatureSpace.GRAY and isinstance(frame, np.ndarray) and (frame.ndim == 2 or frame.shape[-1:] == (1,)):
        return _one_band(frame.reshape(frame.shape[:2] + (1,)))
    x = _rgb_pixels(frame, spec)
    h, w = frame.shape[:2]
    out = np.empty((h * w, len(want)), dtype=np.uint8)
    if space is FeatureSpace.RGB:
        for k, b in enumerate(want):
            out[:, k] = x[:, "RGB".index(b)]
    else:
        cols = list(range(len(want)))
        for a in range(0, len(x), CHUNK_PIXELS):
            chunk = x[a:a + CHUNK_PIXELS]
            if space is FeatureSpace.GRAY:
                out[a:a + CHUNK_PIXELS, 0] = _gray_chunk(chunk)
            else:
                _hsv_chunk(chunk, tuple(want), out[a:a + CHUNK_PIXELS], cols)
    return FeatureFrame(out.reshape(h, w, len(want)), tuple(want), 256, space)


def _one_band(frame: np.ndarray) -> FeatureFrame:
    """A mono or thermal sensor's one band is its gray, at its own depth."""
    if frame.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"gray: frame must be uint8 or uint16, got {frame.dtype}")
    if frame.shape[0] == 0 or frame.shape[1] == 0:
        raise ValueError(f"gray: frame is empty ({frame.shape})")
    levels = 256 if frame.dtype == np.uint8 else 65536
    return FeatureFrame(np.ascontiguousarray(frame), BAND_NAMES[FeatureSpace.GRAY], levels, FeatureSpace.GRAY)


def _raw(frame: np.ndarray, spec: FeatureSpec) -> FeatureFrame:
    if not isinstance(frame, np.ndarray) or frame.ndim not in (2, 3):
        raise ValueError(f"raw: frame must be H x W or H x W x C, got shape {np.shape(frame)}")
    if frame.dtype not in (np.uint8, np.uint16):
        raise ValueError(f"raw: frame must be uint8 or uint16, got {frame.dtype}")
    f = frame[..., None] if frame.ndim == 2 else frame
    c = f.shape[2]
    names = spec.names or tuple(f"B{k}" for k in range(c))
    if len(names) != c:
        raise ValueError(f"raw: {len(names)} band names given for a frame with {c} channels")
    want = spec.bands or names
    bad = [b for b in want if b not in names]
    if bad:
        raise ValueError(f"raw: unknown band(s) {bad}; valid are {list(names)}")
    idx = [names.index(b) for b in want]
    data = f[..., idx] if idx != list(range(c)) else f
    levels = 256 if f.dtype == np.uint8 else 65536
    return FeatureFrame(np.ascontiguousarray(data), tuple(want), levels, FeatureSpace.RAW)
