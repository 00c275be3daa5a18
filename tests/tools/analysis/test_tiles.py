"""Tiling changes memory, not results: compare, synth, pdfs and mask in tiles of a few pixels
give what one whole-image pass gives (bit for bit; correlation to float tolerance), and
synthesis spread over threads what it gives on one."""
import multiprocessing
import threading

import numpy as np
import pytest

from benchmarks.scenes import field, voronoi_labels
from btf.dependence import Dependence
from btf.fit.fitter import FrameFitter, fit_histogram
from tools.analysis import fields, metrics, pdfs, synth, tiles
from tools.analysis.fields import grain_of, index_units
from tools.analysis.interpolation import synthesize_blend
from tools.analysis.levelmap import uniform_table, z_bits, z_table
from tools.data import masks

DEP = Dependence.from_lags((0.5, 0.3, 0.6), (0.8, 0.6, 0.4, 0.2), (0.7, 0.5, 0.3, 0.1))


@pytest.fixture
def tiny_tiles(monkeypatch):
    """Tiles of 7 pixels and random draws 6 at a time: every tile and chunk boundary is hit."""
    monkeypatch.setattr(tiles, "TILE_PIXELS", 7)
    monkeypatch.setattr(tiles, "DRAW_CHUNK", 6)


def _scene(h=41, w=57, n=4, seed=3):
    mask = voronoi_labels(h, w, n, seed=seed)
    frame, _ = field(h, w)
    f = FrameFitter(n, 3)
    f.add(frame, mask)
    return frame, mask, {k: r.model for k, r in f.fit().items()}


def test_row_tiles_cover_every_row_once_in_order():
    blocks = tiles.row_tiles(10, 3, 7)
    assert [(b.start, b.stop) for b in blocks] == [(0, 2), (2, 4), (4, 6), (6, 8), (8, 10)]
    assert tiles.row_tiles(5, 100, 7) == [slice(r, r + 1) for r in range(5)]  # at least one row
    with pytest.raises(ValueError, match="positive"):
        tiles.row_tiles(5, 5, 0)


def test_a_stream_served_in_pieces_is_the_stream_drawn_at_once(tiny_tiles):
    for n, pieces in ((13, (1, 5, 2, 5)), (12, (12,)), (7, (3, 3, 1))):
        draws = tiles.Draws(lambda k, g=np.random.default_rng(1): np.frombuffer(g.bytes(2 * k), np.uint16), n)
        got = np.concatenate([draws.take(k) for k in pieces])
        want = np.frombuffer(np.random.default_rng(1).bytes(2 * n), np.uint16)
        assert np.array_equal(got, want)


def test_compare_in_tiles_equals_the_whole_image_metrics(tiny_tiles):
    rng = np.random.default_rng(2)
    a = rng.integers(0, 180, (23, 31, 3)).astype(np.uint8)
    b = np.clip(a.astype(int) + rng.integers(-30, 30, a.shape), 0, 179).astype(np.uint8)
    mask = rng.integers(0, 3, (23, 31)).astype(np.uint8) * 2
    got = metrics.compare_bands(a, b, ("H", "S", "V"), 256, mask, circular=("H",))
    for r in got.regions:
        k = "HSV".index(r.band)
        sel = mask == r.label
        nlev = 180 if r.band == "H" else 256
        hr, ht = metrics.histogram(a[sel, k], nlev), metrics.histogram(b[sel, k], nlev)
        assert (r.count_ref, r.hist_diff, r.chi2, r.ks, r.w1) == (
            sel.sum(), metrics.hist_diff(hr, ht), metrics.chi2(hr, ht),
            metrics.ks(hr, ht, r.band == "H"), metrics.w1(hr, ht, r.band == "H"))
    assert [r.label for r in got.regions] == [0, 2, 4] * 3
    assert got.correlation["H"] == pytest.approx(metrics.circular_correlation(a[..., 0], b[..., 0], 180), abs=1e-12)
    for k, name in ((1, "S"), (2, "V")):
        assert got.correlation[name] == pytest.approx(metrics.correlation(a[..., k], b[..., k]), abs=1e-12)


def _whole_synthesize(mask, models, rng, dependence=None, levels=256):
    """Synthesis the way it runs without tiles or threads: whole regions in label order, one draw
    per region and band, a correlated region from a stream of its own taken from `rng`."""
    out = np.zeros(mask.shape + (3,), np.uint8 if levels <= 256 else np.uint16)
    bits = z_bits(levels)
    scale, offset = index_units(bits)
    for label in np.unique(mask):
        sel = mask == label
        maps = synth.band_maps(models, label, 3, levels, None)
        if dependence and label in dependence:
            rows, cols = np.flatnonzero(sel.any(axis=1)), np.flatnonzero(sel.any(axis=0))
            box = sel[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1]
            fields = synth.region_fields(grain_of(dependence[label], maps), maps, dependence[label].matrix(),
                                         box.shape, None if box.all() else box, tiles.streams(rng, 1)[0], levels)
            for b in range(3):
                out[sel, b] = z_table(maps[b], bits).take(fields[b][box].astype(np.int32), mode="clip")
            continue
        for b in range(3):
            n = int(sel.sum())
            if levels <= 256:
                out[sel, b] = uniform_table(maps[b]).take(np.frombuffer(rng.bytes(2 * n), np.uint16))
            else:
                z = rng.standard_normal(n, dtype=np.float32) * np.float32(scale) + np.float32(offset)
                out[sel, b] = z_table(maps[b], bits).take(z.astype(np.int32), mode="clip")
    return out


@pytest.mark.parametrize("levels", [256, 1024])
def test_synthesis_in_tiles_equals_whole_regions(tiny_tiles, levels):
    _, mask, models = _scene()
    got = synth.synthesize(mask, models, np.random.default_rng(5), levels)
    assert np.array_equal(got, _whole_synthesize(mask, models, np.random.default_rng(5), levels=levels))


def test_correlated_synthesis_in_tiles_equals_whole_regions(tiny_tiles):
    _, mask, models = _scene()
    deps = {1: DEP, 3: DEP}
    got = synth.synthesize(mask, models, np.random.default_rng(5), dependence=deps)
    assert np.array_equal(got, _whole_synthesize(mask, models, np.random.default_rng(5), deps))


def _quadrants(h=160, w=200):
    """Four regions that fill their boxes (80 x 100, fast FFT lengths): drawn whole, their band
    covariance summed over the grid."""
    mask = np.zeros((h, w), np.uint8)
    mask[h // 2:] += 2
    mask[:, w // 2:] += 1
    frame, _ = field(h, w)
    f = FrameFitter(4, 3)
    f.add(frame, mask)
    return frame, mask, {k: r.model for k, r in f.fit().items()}


@pytest.mark.parametrize("scene,deps", [(_scene, {1: DEP, 3: DEP}), (_scene, {k: DEP for k in range(4)}),
                                        (_quadrants, {k: DEP for k in range(4)})])
def test_correlated_synthesis_on_threads_is_the_synthesis_on_one(tiny_tiles, monkeypatch, scene, deps):
    _, mask, models = scene()
    monkeypatch.setattr(tiles, "CORES", 1)
    alone = synth.synthesize(mask, models, np.random.default_rng(5), dependence=deps)
    threads = set()
    inverse = fields.np.fft.irfft

    def watched(*args, **kwargs):
        threads.add(threading.current_thread().name)
        return inverse(*args, **kwargs)
    monkeypatch.setattr(fields.np.fft, "irfft", watched)
    monkeypatch.setattr(tiles, "PARALLEL_PIXELS", 1)
    monkeypatch.setattr(tiles, "CORES", 4)
    shared = synth.synthesize(mask, models, np.random.default_rng(5), dependence=deps)
    assert any(t.startswith("tiles") for t in threads), threads  # the bands' transforms ran on the pool
    assert np.array_equal(shared, alone)


@pytest.mark.parametrize("scene", [_scene, _quadrants])
def test_small_regions_drawn_a_region_per_thread_are_the_synthesis_on_one(tiny_tiles, monkeypatch, scene):
    _, mask, models = scene()
    deps = {k: DEP for k in range(4)}
    monkeypatch.setattr(tiles, "CORES", 1)
    alone = synth.synthesize(mask, models, np.random.default_rng(5), dependence=deps)
    boxes = [(r.rows.stop - r.rows.start) * (r.cols.stop - r.cols.start) for r in (tiles.region(mask, k) for k in deps)]
    drawn_on = []
    fill = synth._fill_correlated

    def watched(out, mask, where, *args):
        drawn_on.append((where.label, threading.current_thread().name))
        return fill(out, mask, where, *args)
    monkeypatch.setattr(synth, "_fill_correlated", watched)
    monkeypatch.setattr(tiles, "PARALLEL_PIXELS", max(boxes) + 1)  # every box small, all of them not
    monkeypatch.setattr(tiles, "CORES", 2)
    shared = synth.synthesize(mask, models, np.random.default_rng(5), dependence=deps)
    assert sorted(label for label, _ in drawn_on) == [0, 1, 2, 3]
    assert all(name.startswith("tiles") for _, name in drawn_on), drawn_on  # whole regions on the pool
    assert np.array_equal(shared, alone)


def test_a_part_that_fails_is_raised_once_every_other_part_has_ended(monkeypatch):
    monkeypatch.setattr(tiles, "PARALLEL_PIXELS", 1)
    monkeypatch.setattr(tiles, "CORES", 4)
    ended = threading.Event()

    def work(i):
        if i == 0:
            raise ValueError("part 0")
        ended.wait(0.2)  # still running when part 0 has failed
        ended.set()

    with pytest.raises(ValueError, match="part 0"):
        tiles.in_parallel(work, 2, 1 << 20)
    assert ended.is_set()


def _synthesize_in_child(queue) -> None:
    _, mask, models = _scene()
    queue.put(synth.synthesize(mask, models, np.random.default_rng(5), dependence={1: DEP, 3: DEP}))


def test_a_process_forked_after_a_threaded_synthesis_synthesizes_on_threads_of_its_own(monkeypatch):
    monkeypatch.setattr(tiles, "PARALLEL_PIXELS", 1)
    monkeypatch.setattr(tiles, "CORES", 4)
    _, mask, models = _scene()
    here = synth.synthesize(mask, models, np.random.default_rng(5), dependence={1: DEP, 3: DEP})
    assert tiles._POOL  # the parent's pool is up
    fork = multiprocessing.get_context("fork")
    queue = fork.Queue()
    child = fork.Process(target=_synthesize_in_child, args=(queue,))
    child.start()
    try:
        got = queue.get(timeout=60)  # the parent's pool, copied without its threads, would wait forever
    finally:
        child.join(10)
        if child.is_alive():
            child.kill()
    assert np.array_equal(got, here)


def test_interpolation_and_direction_blending_do_not_depend_on_the_tile_size(monkeypatch):
    _, mask, lo = _scene()
    _, _, hi = _scene(seed=3)
    hi = {k: type(m)(m.family, m.gamma, m.delta, m.xi + 20, m.lam) for k, m in hi.items()}
    runs = []
    for tile, chunk in ((7, 6), (1 << 18, 1 << 18)):
        monkeypatch.setattr(tiles, "TILE_PIXELS", tile)
        monkeypatch.setattr(tiles, "DRAW_CHUNK", chunk)
        runs.append((synth.interpolate(lo, hi, 0.3, mask, np.random.default_rng(6)),
                     synth.interpolate(lo, hi, 0.3, mask, np.random.default_rng(6), dependence=({1: DEP}, {1: DEP})),
                     synthesize_blend(mask, [(0.25, lo), (0.75, hi)], np.random.default_rng(7))))
    for small, whole in zip(*runs):
        assert np.array_equal(small, whole)


def test_pdfs_in_tiles_equals_one_pass(monkeypatch):
    frame, mask, _ = _scene(150, 160, 3)
    monkeypatch.setattr(pdfs, "FIT_SAMPLE", 900)  # so the sample is drawn and gathered by position

    def johnson(values, levels):
        return fit_histogram(np.bincount(values, minlength=levels)).model

    tables = []
    for tile in (7, 1 << 18):
        monkeypatch.setattr(tiles, "TILE_PIXELS", tile)
        tables += [pdfs.table(frame, mask, ("R", "G", "B"), None, 256, 4),
                   pdfs.table(frame, mask, ("R", "G", "B"), johnson, 256, 4)]
    rows = [[(r.label, r.band, r.count, r.errors, r.failed) for r in t.rows] for t in tables]
    assert rows[0] == rows[1] == rows[2] == rows[3]
    assert all(r[2] > 900 for r in rows[0])


def test_gather_reads_the_values_at_positions_in_row_major_order(tiny_tiles):
    frame, mask, _ = _scene()
    where = tiles.region(mask, 2)
    values = frame[..., 1][mask == 2]
    positions = np.random.default_rng(0).permutation(where.count)[:50]
    assert np.array_equal(pdfs.gather(frame, 1, mask, where, positions), values[positions])


def test_masks_below_one_segment_tile_are_segmented_whole():
    image, _ = field(90, 120, seed=1)
    for method in ("felzenszwalb", "slic"):
        a = masks.segment(image, method, 4, 3, tile=120)
        b = masks.segment(image, method, 4, 3)
        assert np.array_equal(a, b)


@pytest.mark.parametrize("method", masks.METHODS)
def test_mask_classes_are_ordered_darkest_first_in_tiles(method):
    image, _ = field(96, 128, seed=1)
    labels = masks.segment(image, method, 4, 0, tile=32)
    assert labels.dtype == np.uint8 and labels.shape == image.shape[:2]
    present = np.unique(labels)
    assert np.array_equal(present, np.arange(len(present))) and 2 <= len(present) <= 8
    brightness = [image[labels == c].sum(axis=1).mean() for c in present]
    assert brightness == sorted(brightness)


def test_relabel_maps_through_the_table_in_tiles(tiny_tiles):
    labels = np.random.default_rng(0).integers(0, 5, (19, 23)).astype(np.int32)
    table = np.array([4, 3, 2, 1, 0])
    assert np.array_equal(masks.relabel(labels, table), table[labels].astype(np.uint8))


def test_the_cli_offers_the_methods_tools_masks_has():
    from tools.cli import mask as cmd_mask

    assert cmd_mask.METHODS == masks.METHODS


def test_segment_tiles_are_even_and_snapped_to_the_superpixel_grid():
    assert masks._bounds(1000, 1024, 30.0) == [0, 1000]
    cuts = masks._bounds(2200, 1024, 90.8)
    assert len(cuts) == 4 and all(abs(c / 90.8 - round(c / 90.8)) < 0.01 for c in cuts[1:-1])
    assert max(b - a for a, b in zip(cuts, cuts[1:])) <= 1024
