"""Lags the robot could not measure (too few pixel pairs): the host leaves them to the grain's fit
instead of reading them as independent, and stores, documents and exports them as null."""
from __future__ import annotations

import json

import numpy as np
import pyarrow.parquet as pq
import pytest

from btf.dependence import Dependence, window
from btf.fit.fitter import FrameFitter
from btf.johnson import Johnson
from tools.analysis.fields import draw, grain_of
from tools.analysis.latent import grain_curve
from tools.analysis.levelmap import level_map
from tools.analysis.models_doc import dependence_from_document, dependence_record
from tools.analysis.spectrum import RING, full_window, ring_spectrum
from tools.analysis.synth import synthesize
from tools.data import export as exporter
from tools.store.database import Store

NORMALS = tuple(level_map(Johnson.normal(128.0, 20.0), 256) for _ in range(3))
LAGS = window(6)
# a sheared, stretched exponential grain: what the spectrum's model continues exactly
TARGET = np.array([float(0.85 ** np.hypot(dy, (dx - 0.5 * dy) / 1.5)) for dy, dx in LAGS])
FAR = np.array([abs(dx) >= 3 for _, dx in LAGS])  # a strip three pixels wide has no pairs there


def _holed(rows: int = 1) -> Dependence:
    acf = tuple(float(v) for v in np.where(FAR, 0.0, TARGET))
    gaps = tuple(np.flatnonzero(FAR).tolist())
    return Dependence((0.4, 0.2, 0.1), (acf,) * rows, 6, (10, 10, 10), (240, 240, 240), (gaps,) * rows)


def _implied(spectrum: np.ndarray) -> np.ndarray:
    lags, _ = full_window(6, TARGET)
    return np.fft.ifft2(spectrum).real[lags[1:85, 0] % RING, lags[1:85, 1] % RING]


def test_unknown_lags_are_left_to_the_fit_not_pulled_to_zero():
    curve = grain_curve(list(NORMALS))
    holed = tuple(np.where(FAR, 0.0, TARGET))
    fitted = _implied(ring_spectrum(6, holed, curve, RING, RING, known=~FAR))
    assert np.abs(fitted - TARGET)[~FAR].max() < 0.02
    assert np.abs(fitted - TARGET)[FAR].max() < 0.05  # continued from the measured lags
    zeros = _implied(ring_spectrum(6, holed, curve, RING, RING))  # the zeros read as measured
    assert np.abs(zeros - TARGET)[FAR].max() > 0.3 and np.abs(zeros - TARGET)[~FAR].max() > 0.1
    assert np.array_equal(ring_spectrum(6, tuple(TARGET), curve, 32, 32, known=np.ones(84, bool)),
                          ring_spectrum(6, tuple(TARGET), curve, 32, 32))


@pytest.mark.parametrize("rows", [1, 3])
def test_a_record_with_unmeasured_lags_synthesizes_finite_fields_with_its_grain(rows):
    grain = grain_of(_holed(rows), NORMALS)
    assert all(np.all(np.isfinite(r)) and r.min() >= 0 for r in grain.rings)
    fields = draw(grain, (256, 256), np.random.default_rng(1))
    assert all(np.all(np.isfinite(f)) for f in fields)
    a, b = fields[0][1:, 1:].ravel(), fields[0][:-1, :-1].ravel()  # lag (1, 1)
    assert np.corrcoef(a, b)[0, 1] == pytest.approx(TARGET[LAGS.index((1, 1))], abs=0.05)


def test_a_region_whose_every_lag_is_unmeasured_is_drawn_independent_and_finite():
    labels = np.zeros((64, 64), np.uint8)
    models = {(0, 0): Johnson.normal(120.0, 15.0)}
    dep = Dependence((), ((0.0,) * 84,), 6, (60,), (180,), (tuple(range(84)),))
    out = synthesize(labels, models, np.random.default_rng(2), dependence={0: dep})
    assert out.shape == (64, 64, 1) and np.ptp(out) > 0
    assert np.array_equal(ring_spectrum(6, dep.acf[0], grain_curve(list(NORMALS[:1])), 16, 16,
                                        known=np.zeros(84, bool)), np.ones((16, 16)))


def _fits():
    img = np.random.default_rng(3).integers(40, 220, (64, 64, 3), dtype=np.uint8)
    f = FrameFitter(1, 3, bins=256)
    f.add(img, np.zeros((64, 64), np.uint8))
    return f.fit(min_count=64)


def test_unmeasured_lags_round_trip_through_the_store_the_document_and_the_export(tmp_path):
    dep = _holed(3)
    with Store.open(tmp_path / "s.db") as store:
        assert store.add_capture("bot", 1, 0.0, None, (60.0, 0.0), "rgb", ("R", "G", "B"), _fits(),
                                 dependence={0: dep})
        (capture,) = store.captures()
        assert store.dependence(capture.id) == {0: dep}
        raw = store._conn.execute("SELECT acf FROM dependence").fetchone()[0]
        assert json.loads(raw)[2][LAGS.index((0, 3))] is None
        assert exporter.write_part(store, [capture], tmp_path / "x", "parquet") == 3
    doc = json.loads(json.dumps({"dependence": dependence_record({0: dep})}))
    assert dependence_from_document(doc, 3) == {0: Dependence(dep.corr, dep.acf, 6, unmeasured=dep.unmeasured)}
    rows = pq.read_table(next((tmp_path / "x").glob("*.parquet"))).to_pylist()
    for row in rows:
        acf = row["dependence_acf"]
        assert [k for k, v in enumerate(acf) if v is None] == list(dep.unmeasured[row["band"]])
        assert acf[LAGS.index((1, 1))] == pytest.approx(TARGET[LAGS.index((1, 1))])
