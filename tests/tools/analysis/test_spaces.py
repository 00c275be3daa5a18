"""`btf-host spaces` against a direct computation, on crops of public photographs (RGB, one band,
16-bit): the robot's own features and fitter, each figure recomputed from its definition."""
from __future__ import annotations

import contextlib
import io
import json

import numpy as np
import pytest

from btf.fit import dependence as robot_dependence
from btf.fit.fitter import FrameFitter
from radio import packets
from tests.support.images import public_photos
from tests.support.spaces import bands_of, table2
from tools.analysis.pdfs import table as pdf_table
from tools.analysis.synth import synthesize
from tools.cli import main
from tools.data.images import feature_bands, fit_bands, stretched_8bit, three_bands, write_image
from tools.data.masks import segment

PHOTOS = public_photos()
SPACES = {"astronaut": "rgb,hsv,pca", "coffee": "rgb,pca", "chelsea": "rgb,pca", "immunohistochemistry": "rgb,pca",
          "camera": "gray", "coins": "gray", "mri16": "gray"}
SEED = 3


def worst_band_correlation(data: np.ndarray, labels: np.ndarray) -> float:
    worst = 0.0
    for lab in np.unique(labels):
        inside = labels == lab
        if data.shape[2] > 1 and inside.sum() >= 256:
            r = np.nan_to_num(np.corrcoef(data[inside].T.astype(np.float64)))
            worst = max(worst, float(np.abs(r[np.triu_indices(len(r), 1)]).max()))
    return worst


@pytest.fixture(scope="module")
def judged(tmp_path_factory):
    """Each photograph's JSON document from the command, with its kmeans3 mask."""
    out = {}
    for name, image in PHOTOS.items():
        path = tmp_path_factory.mktemp(name) / f"{name}.png"
        write_image(path, image)
        buf = io.StringIO()
        with contextlib.redirect_stdout(buf):
            assert main(["spaces", str(path), "--json", "--masks", "kmeans3", "--spaces", SPACES[name],
                         "--seed", str(SEED)]) == 0
        labels = segment(three_bands(stretched_8bit(image)), "kmeans", 3, SEED)
        out[name] = (json.loads(buf.getvalue()), labels)
    return out


@pytest.mark.parametrize("name", list(PHOTOS))
def test_the_table_agrees_with_a_direct_computation(judged, name):
    doc, labels = judged[name]
    image = PHOTOS[name]
    assert [r["space"] for r in doc["rows"]] == SPACES[name].split(",")
    for row in doc["rows"]:
        data, levels = bands_of(image, row["space"])
        fitter = FrameFitter(int(labels.max()) + 1, data.shape[2], bins=levels)
        fitter.add(data, labels)
        fits = fitter.fit()
        models = {k: r.model for k, r in fits.items()}
        assert row["regions"] == len(np.unique(labels))
        l1 = np.mean([np.abs(fitter.counts[k] / fitter.counts[k].sum() - m.level_probabilities(levels)).sum()
                      for k, m in sorted(models.items())])
        assert row["exact_l1"] == pytest.approx(l1, abs=1e-9)
        if levels == 256:  # the Johnson column of the paper's Table 2 (btf-host pdfs) is the same L1
            t = pdf_table(data, labels, row["bands"], levels=levels)
            assert row["exact_l1"] == pytest.approx(t.total["johnson"] / len(t.rows), abs=0.02)
        assert row["table2_seeds"] == pytest.approx([table2(fitter.counts, models, levels, s) for s in (SEED, SEED + 1)],
                                                    abs=1e-12)
        assert row["decorrelation"] == pytest.approx(worst_band_correlation(data, labels), abs=1e-9)
        # Table 1 of the independent synthesis: a plain Pearson correlation per band (hue is circular)
        feats, pca = feature_bands(image, row["space"])
        fitted = fit_bands(feats, pca, labels)
        syn = synthesize(labels, models, np.random.default_rng(SEED), levels, fitted.dependence, independent=True)
        for b, band in enumerate(row["bands"]):
            if band != "H":
                want = np.corrcoef(syn[..., b].ravel().astype(float), data[..., b].ravel().astype(float))[0, 1]
                assert row["table1"]["independent"][band] == pytest.approx(want, abs=1e-9)
        # the bytes the robot would send: its own dependence record, as its pipeline measures it
        robots = robot_dependence.measure(feats.data, labels, models, levels,
                                          levels_seen={k: (d.lo, d.hi) for k, d in fitted.dependence.items()})
        assert sum(len(d.acf[0]) for d in robots.values() if d.measured) < sum(
            len(d.acf[0]) for d in fitted.dependence.values() if d.measured)  # a smaller window than the host's
        body = packets.encode_models(fitted.results, robot_id=0, seq=0, time=0.0, commanded=(0.0, 0.0),
                                     measured=(0.0, 0.0), feature_space=row["space"], bands=row["bands"],
                                     levels=levels, extras=pca.to_extras() if pca else None, dependence=robots)
        assert row["wire_bytes"] == len(body)
        assert len(packets.decode(body).fits) == row["regions"] * len(row["bands"])
        assert row["fit_ms"] > 0 and all(v is None or np.isfinite(v) for v in row["texture"].values())


def test_the_correlated_synthesis_keeps_the_band_correlation_better_than_the_independent_one(judged):
    doc, _ = judged["astronaut"]
    rgb = next(r for r in doc["rows"] if r["space"] == "rgb")
    # the texture figures are of the correlated synthesis: its band gap is small
    assert rgb["texture"]["band_gap"] < 0.2
    assert rgb["decorrelation"] > 0.5  # and the astronaut's colour bands do correlate


def test_the_choice_is_one_of_the_rows_and_a_one_band_photograph_offers_gray_alone(judged):
    for name, (doc, _) in judged.items():
        choice = doc["choice"]
        assert (choice["mask"], choice["space"]) in {(r["mask"], r["space"]) for r in doc["rows"]}
        assert choice["reason"].startswith(choice["space"])
        if PHOTOS[name].shape[2] == 1:
            assert choice["space"] == "gray" and doc["levels"] == (65536 if name == "mri16" else 256)
