"""Feature bands: OpenCV-exact 8-bit conversions, lazy band selection, invertible PCA, raw bands."""
import cv2
import msgpack
import numpy as np
import pytest

from btf.fit import features as F
from btf.fit.features import FeatureSpace, FeatureSpec, PcaBasis, compute


def _random_image(seed: int, h: int = 97, w: int = 131) -> np.ndarray:
    return np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8)


def _every_colour() -> np.ndarray:
    v = np.arange(1 << 24, dtype=np.uint32)
    return np.stack([(v >> 16) & 255, (v >> 8) & 255, v & 255], -1).astype(np.uint8).reshape(4096, 4096, 3)


def test_hsv_and_gray_match_opencv_for_every_8bit_colour():
    img = _every_colour()
    for rows in range(0, 4096, 1024):  # bounded memory for the check itself
        part = img[rows:rows + 1024]
        hsv = compute(part, FeatureSpec(FeatureSpace.HSV)).data
        np.testing.assert_array_equal(hsv, cv2.cvtColor(part, cv2.COLOR_RGB2HSV))
        gray = compute(part, FeatureSpec(FeatureSpace.GRAY)).data[..., 0]
        np.testing.assert_array_equal(gray, cv2.cvtColor(part, cv2.COLOR_RGB2GRAY))


@pytest.mark.parametrize("seed", range(3))
def test_bgr_frames_match_opencv_bgr_conversions(seed):
    img = _random_image(seed)
    hsv = compute(img, FeatureSpec(FeatureSpace.HSV, bgr=True)).data
    np.testing.assert_array_equal(hsv, cv2.cvtColor(img, cv2.COLOR_BGR2HSV))
    gray = compute(img, FeatureSpec(FeatureSpace.GRAY, bgr=True)).data[..., 0]
    np.testing.assert_array_equal(gray, cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    rgb = compute(img, FeatureSpec(FeatureSpace.RGB, bgr=True)).data
    np.testing.assert_array_equal(rgb, img[..., ::-1])


def test_band_selection_keeps_requested_order_and_names():
    img = _random_image(4)
    full = compute(img, FeatureSpec(FeatureSpace.HSV))
    part = compute(img, FeatureSpec(FeatureSpace.HSV, bands=("V", "H")))
    assert full.band_names == ("H", "S", "V") and part.band_names == ("V", "H")
    np.testing.assert_array_equal(part.data[..., 0], full.data[..., 2])
    np.testing.assert_array_equal(part.band("H"), full.band("H"))
    assert part.levels == 256 and part.data.dtype == np.uint8
    rgb = compute(img, FeatureSpec(FeatureSpace.RGB, bands=("B",)))
    np.testing.assert_array_equal(rgb.data[..., 0], img[..., 2])


def test_value_only_never_computes_hue(monkeypatch):
    def boom(*args, **kwargs):
        raise AssertionError("hue computed although only V was asked for")

    monkeypatch.setattr(F, "_hue_index", boom)
    img = _random_image(5)
    v = compute(img, FeatureSpec(FeatureSpace.HSV, bands=("V",))).data[..., 0]
    np.testing.assert_array_equal(v, img.max(axis=2))
    with pytest.raises(AssertionError):
        compute(img, FeatureSpec(FeatureSpace.HSV, bands=("H",)))


def test_gray_never_builds_hsv(monkeypatch):
    monkeypatch.setattr(F, "_hsv_chunk", lambda *a: (_ for _ in ()).throw(AssertionError("hsv built")))
    img = _random_image(6)
    compute(img, FeatureSpec(FeatureSpace.GRAY))


def test_large_frames_are_processed_in_chunks_with_the_same_result():
    img = np.random.default_rng(7).integers(0, 256, (300, 700, 3), dtype=np.uint8)  # > 3 chunks
    np.testing.assert_array_equal(compute(img, FeatureSpec(FeatureSpace.HSV)).data,
                                  cv2.cvtColor(img, cv2.COLOR_RGB2HSV))


def _scene(seed: int) -> np.ndarray:
    """Correlated colours like a natural scene: a brightness field times a tint, plus noise."""
    rng = np.random.default_rng(seed)
    lum = rng.uniform(40, 200, (120, 90, 1))
    tint = np.array([1.0, 0.85, 0.6])
    return np.clip(lum * tint + rng.normal(0, 6, (120, 90, 3)), 0, 255).astype(np.uint8)


def test_pca_decorrelates_and_orders_components_by_variance():
    img = _scene(1)
    basis = PcaBasis.fit(img, sample=5000, seed=3)
    rot = np.asarray(basis.rotation)
    np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-9)
    y = (img.reshape(-1, 3) - np.asarray(basis.mean)) @ rot
    cov = np.cov(y, rowvar=False)
    off = cov - np.diag(np.diag(cov))
    assert np.abs(off).max() < 0.05 * cov[0, 0]
    assert cov[0, 0] > cov[1, 1] > 0 and cov[1, 1] >= cov[2, 2] * 0.5


def test_pca_round_trip_error_is_within_half_a_quantisation_step():
    img = _scene(2)
    basis = PcaBasis.fit(img, sample=20000)
    q = compute(img, FeatureSpec(FeatureSpace.PCA), pca=basis)
    assert q.band_names == ("P1", "P2", "P3") and q.data.dtype == np.uint8
    back = basis.invert(q.data)
    # each component is off by at most half a step, 0.5/scale, carried by a unit rotation
    bound = 0.5 * np.abs(np.asarray(basis.rotation)) @ (1 / np.asarray(basis.scale)) + 1e-9
    inside = ((q.data > 0) & (q.data < 255)).all(axis=2)
    assert inside.mean() > 0.99
    assert np.all(np.abs(back - img)[inside] <= bound)
    assert np.all(np.isfinite(back)) and back.min() >= 0 and back.max() <= 255


def test_pca_band_subset_matches_full_and_record_survives_msgpack():
    img = _scene(3)
    basis = PcaBasis.fit(img)
    full = compute(img, FeatureSpec(FeatureSpace.PCA), pca=basis).data
    p2 = compute(img, FeatureSpec(FeatureSpace.PCA, bands=("P2",)), pca=basis).data
    np.testing.assert_array_equal(p2[..., 0], full[..., 1])
    again = PcaBasis.from_record(msgpack.unpackb(msgpack.packb(basis.to_record())))
    assert again == basis


def test_pca_on_a_constant_frame_stays_finite():
    img = np.full((20, 30, 3), 77, np.uint8)
    basis = PcaBasis.fit(img)
    vals = np.array(basis.mean + basis.scale + basis.offset + sum(basis.rotation, ()))
    assert np.all(np.isfinite(vals))
    q = basis.apply(img)
    np.testing.assert_allclose(basis.invert(q), 77, atol=0.5)


def test_pca_record_rejects_malformed_input():
    with pytest.raises(ValueError, match="pca record"):
        PcaBasis.from_record({"mean": [1.0]})
    rec = PcaBasis.fit(_scene(4)).to_record()
    rec["scale"][0] = float("nan")
    with pytest.raises(ValueError, match="non-finite"):
        PcaBasis.from_record(rec)


def test_raw_bands_pass_through_and_select_by_name():
    rng = np.random.default_rng(8)
    thermal = rng.integers(0, 65536, (40, 50), dtype=np.uint16)
    ff = compute(thermal, FeatureSpec(FeatureSpace.RAW))
    assert ff.band_names == ("B0",) and ff.levels == 65536 and ff.data.dtype == np.uint16
    np.testing.assert_array_equal(ff.data[..., 0], thermal)
    ms = rng.integers(0, 256, (40, 50, 5), dtype=np.uint8)
    spec = FeatureSpec(FeatureSpace.RAW, bands=("nir", "red"), names=("blue", "green", "red", "re", "nir"))
    ff = compute(ms, spec)
    assert ff.band_names == ("nir", "red") and ff.levels == 256
    np.testing.assert_array_equal(ff.data, ms[..., [4, 2]])


@pytest.mark.parametrize(
    "frame, spec, match",
    [
        (np.zeros((4, 4, 3), np.float32), FeatureSpec(FeatureSpace.HSV), "uint8"),
        (np.zeros((4, 4), np.uint8), FeatureSpec(FeatureSpace.RGB), "H x W x C"),
        (np.zeros((4, 4, 2), np.uint8), FeatureSpec(FeatureSpace.GRAY), "3 colour channels"),
        (np.zeros((4, 4, 1), np.float32), FeatureSpec(FeatureSpace.GRAY), "gray: frame must be uint8 or uint16"),
        (np.zeros((4, 4, 1), np.uint8), FeatureSpec(FeatureSpace.HSV), r"got 1 \(space gray fits a one-band camera"),
        (np.zeros((0, 4, 1), np.uint16), FeatureSpec(FeatureSpace.GRAY), "gray: frame is empty"),
        (np.zeros((4, 4, 6), np.uint8), FeatureSpec(FeatureSpace.RGB), r"got 6 \(space raw fits the camera's own"),
        (np.zeros((4, 4, 6), np.uint16), FeatureSpec(FeatureSpace.RGB), r"got uint16 \(space raw fits the camera"),
        (np.zeros((0, 4, 3), np.uint8), FeatureSpec(FeatureSpace.RGB), "empty"),
        (np.zeros((4, 4, 3), np.int32), FeatureSpec(FeatureSpace.RAW), "uint8 or uint16"),
        (np.zeros((4, 4, 3), np.uint8), FeatureSpec(FeatureSpace.RAW, bands=("X",)), "unknown band"),
        (np.zeros((4, 4, 3), np.uint8), FeatureSpec(FeatureSpace.RAW, names=("a",)), "1 band names"),
        (np.zeros((4, 4, 3), np.uint8), FeatureSpec(FeatureSpace.PCA), "PcaBasis is required"),
    ],
)
def test_bad_frames_and_specs_name_the_problem(frame, spec, match):
    with pytest.raises(ValueError, match=match):
        compute(frame, spec)


def test_spec_rejects_unknown_and_duplicate_bands():
    with pytest.raises(ValueError, match="unknown hsv band"):
        FeatureSpec(FeatureSpace.HSV, bands=("Q",))
    with pytest.raises(ValueError, match="duplicate"):
        FeatureSpec(FeatureSpace.RGB, bands=("R", "R"))
    assert FeatureSpec("gray").space is FeatureSpace.GRAY
