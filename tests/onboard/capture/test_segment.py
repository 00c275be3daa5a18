"""Mask files, the MASK map the Segmenter compares and the packet carries, the persistent palette
and the Segmenter."""
import cv2
import msgpack
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays
from PIL import Image

from btf.fit.features import FeatureSpace, FeatureSpec, compute
from btf.fit.isodata import IsodataParams
from onboard.capture.mask_file import load_mask
from onboard.capture.palette import Palette
from onboard.capture.segmentation import Segmenter, SegmentMethod
from onboard.config import SegmentConfig
from radio import packets as pk
from radio.packets.mask import downsample_labels, pool_labels

COLOURS = np.array([[40, 40, 40], [200, 60, 60], [60, 200, 60], [60, 60, 200]], np.uint8)


def _labels(h=48, w=64):
    yy, xx = np.mgrid[0:h, 0:w]
    return ((xx // 16 + yy // 12) % 4).astype(np.uint8)


def test_gray_png_mask_and_npy_give_the_same_labels(tmp_path):
    lab = _labels()
    cv2.imwrite(str(tmp_path / "m.png"), lab)
    np.save(tmp_path / "m.npy", lab.astype(np.int64))
    np.testing.assert_array_equal(load_mask(tmp_path / "m.png", n_labels=4, shape=lab.shape), lab)
    np.testing.assert_array_equal(load_mask(tmp_path / "m.npy"), lab)


def test_colour_mask_maps_through_the_colour_table(tmp_path):
    lab = _labels()
    cv2.imwrite(str(tmp_path / "c.png"), COLOURS[lab][..., ::-1])
    table = tuple(tuple(int(v) for v in c) for c in COLOURS)
    np.testing.assert_array_equal(load_mask(tmp_path / "c.png", colours=table), lab)
    # without a table: distinct colours in ascending (R, G, B) order
    order = np.lexsort(COLOURS.T[::-1])
    rank = np.empty(4, int)
    rank[order] = np.arange(4)
    np.testing.assert_array_equal(load_mask(tmp_path / "c.png"), rank[lab])
    with pytest.raises(ValueError, match=r"colour \(200, 60, 60\) not in the colour table"):
        load_mask(tmp_path / "c.png", colours=table[:1] + table[2:])


def test_indexed_png_holds_labels_directly(tmp_path):
    lab = _labels()
    im = Image.fromarray(lab, "P")
    im.putpalette(COLOURS.ravel().tolist())
    im.save(tmp_path / "p.png")
    np.testing.assert_array_equal(load_mask(tmp_path / "p.png"), lab)


def test_mask_errors_name_the_problem(tmp_path):
    lab = _labels()
    cv2.imwrite(str(tmp_path / "m.png"), lab)
    with pytest.raises(ValueError, match="no such file"):
        load_mask(tmp_path / "none.png")
    with pytest.raises(ValueError, match="the frame is 100x48"):
        load_mask(tmp_path / "m.png", shape=(48, 100))
    with pytest.raises(ValueError, match="label 3, above the 3 labels"):
        load_mask(tmp_path / "m.png", n_labels=3)
    cv2.imwrite(str(tmp_path / "big.png"), np.full((4, 4), 1000, np.uint16))
    with pytest.raises(ValueError, match="outside 0..255"):
        load_mask(tmp_path / "big.png")
    (tmp_path / "m.bmp").write_bytes(b"BM")
    with pytest.raises(ValueError, match="neither .png nor .npy"):
        load_mask(tmp_path / "m.bmp")
    np.save(tmp_path / "f.npy", np.zeros((3, 3), np.float32))
    with pytest.raises(ValueError, match="2-D integer"):
        load_mask(tmp_path / "f.npy")


def _sent(labels, side=pk.MAX_SIDE):
    """The MASK packet the robot would send for `labels`, as the host decodes it."""
    return pk.decode(pk.encode_mask(labels, robot_id=1, seq=1, max_side=side))


def test_downsample_takes_the_block_mode():
    lab = np.zeros((6, 6), np.uint8)
    lab[:3, :3] = [[1, 1, 2], [1, 2, 2], [1, 1, 0]]  # mode 1 (5 of 9)
    lab[3:, 3:] = 7
    lab[3, 3] = 0
    small = downsample_labels(lab, max_side=2)
    np.testing.assert_array_equal(small, [[1, 0], [0, 7]])


def test_downsample_bounds_the_size_and_keeps_blocky_maps_exactly():
    yy, xx = np.mgrid[0:480, 0:640]
    lab = ((xx // 40 + yy // 30 * 3) % 5).astype(np.uint8)  # region edges on the 10-pixel grid
    small = downsample_labels(lab, 64)
    assert max(small.shape) <= 64 and small.shape == (48, 64)  # cells of 10 x 10 pixels
    np.testing.assert_array_equal(_sent(lab, 64).full_size(), lab)


@settings(max_examples=60, deadline=None)
@given(arrays(np.uint8, st.tuples(st.integers(1, 40), st.integers(1, 40)), elements=st.integers(0, 5)),
       st.integers(1, 16))
def test_downsample_upsample_shapes_and_values(lab, side):
    small = downsample_labels(lab, side)
    assert max(small.shape) <= side
    assert set(np.unique(small)) <= set(np.unique(lab))
    packet = _sent(lab, side)
    np.testing.assert_array_equal(packet.label_map(), small)
    big = packet.full_size()
    assert big.shape == lab.shape and big.dtype == np.uint8
    (h, w), (fh, fw) = small.shape, lab.shape
    if fh % h == 0 and fw % w == 0:  # whole cells: each cell's first pixel carries its label
        np.testing.assert_array_equal(big[::fh // h, ::fw // w], small)


def test_upsample_with_a_foreign_size_scales_proportionally():
    small = np.array([[0, 1], [2, 3]], np.uint8)
    packet = pk.MaskPacket(1, 1, (4, 6), (2, 2), bytes([0, 1, 2, 3]), (1, 1, 1, 1))
    np.testing.assert_array_equal(packet.label_map(), small)
    big = packet.full_size()  # a 4x6 frame would pool to 4x6 at 64, not 2x2
    np.testing.assert_array_equal(big[:, :3], [[0] * 3, [0] * 3, [2] * 3, [2] * 3])


def test_palette_keeps_labels_across_views_and_adds_new_types():
    pal = Palette(threshold=20)
    first = pal.match(np.array([[40.0, 40, 40], [200, 60, 60]]))
    np.testing.assert_array_equal(first, [0, 1])
    # next view: same clutter, slightly shifted, in another order, plus a new type
    second = pal.match(np.array([[60.0, 200, 60], [205, 58, 62], [43, 41, 38]]))
    np.testing.assert_array_equal(second, [2, 1, 0])
    assert len(pal.entries) == 3


def test_palette_gives_each_entry_to_one_centre_per_view():
    pal = Palette(threshold=50)
    pal.match(np.array([[100.0, 100, 100]]))
    out = pal.match(np.array([[110.0, 100, 100], [104.0, 100, 100]]))
    assert out[1] == 0 and out[0] == 1


def test_full_palette_maps_to_the_nearest_entry():
    pal = Palette(threshold=5, max_entries=2)
    pal.match(np.array([[0.0], [100.0]]))
    np.testing.assert_array_equal(pal.match(np.array([[70.0], [20.0]])), [1, 0])
    assert len(pal.entries) == 2


def test_palette_record_survives_msgpack_and_restart():
    pal = Palette(threshold=25, max_entries=8)
    pal.match(COLOURS.astype(float))
    again = Palette.from_record(msgpack.unpackb(msgpack.packb(pal.to_record())))
    assert again.entries == pal.entries and again.threshold == 25
    np.testing.assert_array_equal(again.match(COLOURS[::-1].astype(float) + 1), [3, 2, 1, 0])
    with pytest.raises(ValueError, match="palette record"):
        Palette.from_record({"entries": [[1.0], [1.0, 2.0]], "threshold": 5, "max_entries": 4})


def _scene(which, seed):
    rng = np.random.default_rng(seed)
    return np.clip(rng.normal(COLOURS[which].astype(float), 6), 0, 255).astype(np.uint8)


def test_isodata_segmenter_keeps_labels_consistent_across_views():
    seg = Segmenter(SegmentMethod.ISODATA, isodata=IsodataParams(k=4), palette_threshold=30)
    truth = _labels()
    spec = FeatureSpec(FeatureSpace.RGB)
    first = seg.labels_for(compute(_scene(truth, 1), spec))
    assert seg.changed
    code = {int(t): int(first[truth == t][0]) for t in range(4)}
    assert all(np.all(first[truth == t] == code[t]) for t in range(4))
    # a second view of the same clutter, laid out differently: same palette labels
    truth2 = np.rot90(truth, 2).copy()
    second = seg.labels_for(compute(_scene(truth2, 2), spec))
    assert all(np.all(second[truth2 == t] == code[t]) for t in range(4))
    assert seg.changed  # the layout moved


def test_changed_only_when_the_map_differs_enough(tmp_path):
    lab = _labels(64, 64)
    np.save(tmp_path / "m.npy", lab)
    seg = Segmenter("mask", mask_path=str(tmp_path / "m.npy"), mask_side=16)
    ff = compute(np.zeros((64, 64, 3), np.uint8), FeatureSpec(FeatureSpace.GRAY))
    np.testing.assert_array_equal(seg.labels_for(ff), lab)
    assert seg.changed and seg.small.shape == (16, 16)
    seg.labels_for(ff)
    assert not seg.changed
    seg.force_send()
    seg.labels_for(ff)
    assert seg.changed


def test_small_label_jitter_does_not_trigger_a_new_mask():
    seg = Segmenter(SegmentMethod.ISODATA, isodata=IsodataParams(k=2), mask_side=32, change_fraction=0.05)
    truth = (np.arange(128)[None, :] >= 64).repeat(96, 0).astype(np.uint8)
    spec = FeatureSpec(FeatureSpace.RGB)
    seg.labels_for(compute(_scene(truth, 3), spec))
    seg.labels_for(compute(_scene(truth, 4), spec))  # new noise, same layout
    assert not seg.changed


def test_segmenter_config_errors_are_clear(tmp_path):
    with pytest.raises(ValueError, match="needs mask_path"):
        Segmenter(SegmentMethod.MASK)
    with pytest.raises(ValueError, match="no such file"):
        Segmenter("mask", mask_path=str(tmp_path / "none.png"))
    np.save(tmp_path / "m.npy", _labels())
    seg = Segmenter("mask", mask_path=str(tmp_path / "m.npy"))
    with pytest.raises(ValueError, match="the frame is 10x10"):
        seg.labels_for(compute(np.zeros((10, 10, 3), np.uint8), FeatureSpec(FeatureSpace.RGB)))


def test_the_change_check_compares_the_map_the_mask_packet_sends(tmp_path):
    # 100 x 130 pools to 49 x 64 on the wire; the change check used to pool it to 34 x 44.
    yy, xx = np.mgrid[0:100, 0:130]
    lab = ((xx // 13 + yy // 9) % 4).astype(np.uint8)
    np.save(tmp_path / "m.npy", lab)
    seg = Segmenter("mask", mask_path=str(tmp_path / "m.npy"))
    seg.labels_for(compute(np.zeros((100, 130, 3), np.uint8), FeatureSpec(FeatureSpace.RGB)))
    assert seg.changed
    sent = _sent(lab).label_map()
    assert sent.shape == (49, 64)
    np.testing.assert_array_equal(seg.small, sent)


def test_a_change_the_sent_map_shows_is_a_change():
    # Moving a boundary by 2 pixels changes one column of the 49 x 64 map that is sent (1.6 %, under
    # the 2 % threshold); by 10 pixels, five columns (7.8 %).
    yy, xx = np.mgrid[0:100, 0:130]
    seg = Segmenter(SegmentMethod.ISODATA)
    for edge, expect in ((60, True), (62, False), (70, True)):
        lab = (xx >= edge).astype(np.uint8)
        seg.note(lab)
        sent = _sent(lab).label_map()
        np.testing.assert_array_equal(seg.small, sent)
        assert bool(seg.changed) is expect, edge


def test_the_segment_section_builds_its_segmenter(tmp_path):
    np.save(tmp_path / "m.npy", _labels())
    seg = Segmenter.from_config(SegmentConfig(method="mask", mask=tmp_path / "m.npy", n_labels=4))
    assert seg.method is SegmentMethod.MASK and seg.palette is None
    with pytest.raises(ValueError, match="label 3, above the 3 labels"):
        Segmenter.from_config(SegmentConfig(method="mask", mask=tmp_path / "m.npy", n_labels=3))
    iso = Segmenter.from_config(SegmentConfig(k=3, split_std=12.0, refit_drift=0.5, n_labels=8), seed=7)
    assert iso.method is SegmentMethod.ISODATA and iso.refit_drift == 0.5 and iso.palette.max_entries == 8
    assert iso.isodata == IsodataParams(k=3, min_samples=50, split_std=12.0, merge_distance=15.0, max_merges=2,
                                        iterations=10, subsample=20_000, seed=7)
    # the fake camera's ground truth keeps a palette too, as isodata's would
    assert Segmenter.from_config(SegmentConfig(method="scene")).palette is not None


@pytest.mark.parametrize("shape", [(100, 130), (120, 160), (480, 640), (7, 300), (64, 64)])
def test_a_mask_stretched_back_covers_each_cell_with_exactly_the_pixels_it_was_pooled_from(shape):
    from radio.packets.mask import cell_of, mask_packet

    full_h, full_w = shape
    probe = mask_packet(np.zeros(shape, np.uint8), robot_id=1, seq=1)
    h, w = probe.shape
    small = np.random.default_rng(h * w).integers(0, 6, (h, w)).astype(np.uint8)
    frame = small[cell_of(full_h, h)[:, None], cell_of(full_w, w)[None, :]]
    assert np.array_equal(mask_packet(frame, robot_id=1, seq=1).full_size(), frame)


@settings(max_examples=40, deadline=None)
@given(arrays(np.uint8, st.tuples(st.integers(1, 150), st.integers(1, 150)), elements=st.integers(0, 255)),
       st.integers(1, 64))
def test_pooling_counts_every_label_it_pools(lab, side):
    small, counts = pool_labels(lab, side)
    np.testing.assert_array_equal(small, downsample_labels(lab, side))
    np.testing.assert_array_equal(counts, np.bincount(lab.ravel(), minlength=256))


def test_the_segmenter_hands_on_the_map_it_pooled_and_the_mask_packet_carries_it(tmp_path):
    lab = _labels(480, 640)
    seg = Segmenter(SegmentMethod.ISODATA, n_labels=8)
    seg.note(lab)
    out = seg.segmented(lab)
    assert out.changed and out.labels is lab
    np.testing.assert_array_equal(out.counts[:8], np.bincount(lab.ravel(), minlength=8))
    assert pk.encode_mask(lab, robot_id=1, seq=3, pooled=out.small) == pk.encode_mask(lab, robot_id=1, seq=3)
    coarse = Segmenter(SegmentMethod.ISODATA, n_labels=8, mask_side=16)
    coarse.note(lab)
    assert coarse.segmented(lab).small is None  # not the map a MASK packet carries


def test_centres_are_refitted_when_the_scene_changes_not_when_the_view_is_brighter():
    seg = Segmenter(SegmentMethod.ISODATA, isodata=IsodataParams(k=4), palette_threshold=30)
    truth, spec = _labels(), FeatureSpec(FeatureSpace.RGB)
    base = _scene(truth, 1).astype(float)
    seg.labels_for(compute(base.astype(np.uint8), spec))
    assert seg.refits == 1
    for gain in (0.7, 0.85, 1.15, 1.25):  # the same clutter seen from views that catch more or less light
        seg.labels_for(compute(np.clip(base * gain, 0, 255).astype(np.uint8), spec))
    assert seg.refits == 1
    other = np.array([[120, 30, 160], [20, 120, 120], [230, 200, 40], [90, 90, 10]], np.uint8)  # other clutter
    seg.labels_for(compute(np.clip(np.random.default_rng(5).normal(other[truth].astype(float), 6), 0, 255)
                           .astype(np.uint8), spec))
    assert seg.refits == 2
