"""Ingest: every (image, label, band) fitted by the robot's fitter, the same database on any executor."""
from __future__ import annotations

import sqlite3

import numpy as np
import pytest

from btf.fit.fitter import FrameFitter
from tests.support.databases import SCHEMA_1
from tools.cli import main
from tools.data.datasets import Angles, write_rendered
from tools.data.images import read_image, read_mask
from tools.data.ingest import IngestError, dataset_robot, ingest
from tools.store.database import Store

VIEWS = [Angles(el, az, lel, 0.0) for el in (30.0, 60.0, 90.0) for az in (0.0, 90.0) for lel in (40.0, 70.0)]


def _rows(db):
    """Every table's rows in a fixed order (the whole database content)."""
    con = sqlite3.connect(db)
    try:
        return {t: con.execute(f"SELECT * FROM {t} ORDER BY 1, 2, 3").fetchall()
                for t in ("captures", "models", "masks")}
    finally:
        con.close()


@pytest.fixture(scope="module")
def utia(tmp_path_factory):
    root = tmp_path_factory.mktemp("utia")
    write_rendered(root, "utia", VIEWS, size=(32, 40), seed=3)
    return root


def test_models_are_the_robots_fit_with_angles_and_source(utia, tmp_path):
    report = ingest(utia, "utia", tmp_path / "a.db", mask=utia / "masks", workers=0)
    assert (report.total, report.stored, report.skipped) == (12, 12, 0)
    with Store.open(tmp_path / "a.db") as store:
        caps = store.captures(robot=dataset_robot(utia))
        assert len(caps) == 12
        c = next(c for c in caps if c.source == "tl050_pl000_tv060_pv090.png")
        assert c.measured == (30.0, 90.0) and c.illumination == (40.0, 0.0) and c.scene == utia.name
        image = read_image(utia / c.source)
        labels = read_mask(utia / "masks" / "tl050_pl000_tv060_pv090.png")
        fitter = FrameFitter(int(labels.max()) + 1, 3)
        fitter.add(image, labels)
        expected = fitter.fit()
        stored = store.models(c.id)
        assert set(stored) == set(expected) and len(stored) >= 6
        for key, m in stored.items():
            assert m.model == expected[key].model
            assert m.count == expected[key].count
        assert np.array_equal(store.mask(f"{dataset_robot(utia)}/{c.sequence}", dataset_robot(utia)), labels)


def test_same_database_from_serial_process_pool_and_dask(utia, tmp_path):
    from distributed import LocalCluster

    ingest(utia, "utia", tmp_path / "serial.db", mask=utia / "masks", workers=0)
    ingest(utia, "utia", tmp_path / "pool.db", mask=utia / "masks", workers=2)
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=False, dashboard_address=None) as cluster:
        ingest(utia, "utia", tmp_path / "dask.db", mask=utia / "masks", scheduler=cluster.scheduler_address)
    serial = _rows(tmp_path / "serial.db")
    assert len(serial["models"]) >= 12 * 6
    assert _rows(tmp_path / "pool.db") == serial
    assert _rows(tmp_path / "dask.db") == serial


def test_resume_after_a_failure_gives_the_clean_database(utia, tmp_path):
    import shutil

    data = tmp_path / "data"
    shutil.copytree(utia, data)
    broken = sorted(p for p in data.glob("*.png"))[7]
    good = broken.read_bytes()
    broken.write_bytes(b"not a png")
    with pytest.raises(IngestError, match=broken.name):
        ingest(data, "utia", tmp_path / "r.db", mask=data / "masks", workers=2)
    with Store.open(tmp_path / "r.db") as store:
        assert 0 < len(store.captures()) < 12
    broken.write_bytes(good)
    report = ingest(data, "utia", tmp_path / "r.db", mask=data / "masks", workers=2)
    assert report.skipped > 0 and report.skipped + report.stored == 12
    ingest(data, "utia", tmp_path / "clean.db", mask=data / "masks", workers=0)
    assert _rows(tmp_path / "r.db") == _rows(tmp_path / "clean.db")
    again = ingest(data, "utia", tmp_path / "r.db", mask=data / "masks", workers=0)
    assert (again.stored, again.skipped) == (0, 12)


@pytest.mark.parametrize("layout", ["curet", "folder"])
def test_every_layout_stores_its_angles(tmp_path, layout):
    write_rendered(tmp_path / "d", layout, VIEWS[:4], size=(24, 24))
    ingest(tmp_path / "d", layout, tmp_path / "x.db", workers=0, space="gray")
    with Store.open(tmp_path / "x.db") as store:
        caps = store.captures()
        got = sorted((round(c.measured[0], 6), round(c.measured[1], 6), round(c.illumination[0], 6))
                     for c in caps)
        assert got == sorted((a.elevation, a.azimuth, a.light_elevation) for a in VIEWS[:4])
        assert {c.band_names for c in caps} == {("Y",)}
        assert all(len(store.models(c.id)) == 1 for c in caps)  # no mask: label 0 only


def test_folder_without_angles_uses_the_default_elevation(tmp_path):
    write_rendered(tmp_path / "d", "folder", VIEWS[:2], size=(16, 16), masks=False)
    (tmp_path / "d" / "angles.csv").unlink()
    ingest(tmp_path / "d", "folder", tmp_path / "x.db", workers=0, default_elevation=75.0)
    with Store.open(tmp_path / "x.db") as store:
        assert [(c.measured, c.illumination) for c in store.captures()] == [((75.0, 0.0), (None, None))] * 2


def test_bad_masks_and_spaces_are_named(utia, tmp_path):
    with pytest.raises(IngestError, match="pca"):
        ingest(utia, "utia", tmp_path / "x.db", space="pca", workers=0)
    with pytest.raises(IngestError, match="no such file or folder"):
        ingest(utia, "utia", tmp_path / "x.db", mask=tmp_path / "none.png", workers=0)
    (tmp_path / "masks").mkdir()
    with pytest.raises(IngestError, match="masks folder has none"):
        ingest(utia, "utia", tmp_path / "x.db", mask=tmp_path / "masks", workers=0)
    small = tmp_path / "small.png"
    from tools.data.images import write_mask
    write_mask(small, np.zeros((5, 5), np.uint8))
    with pytest.raises(IngestError, match="differs from the image"):
        ingest(utia, "utia", tmp_path / "x.db", mask=small, workers=0)




def test_schema_1_database_is_upgraded_in_place(utia, tmp_path):
    from tools.store.schema import APPLICATION_ID

    db = tmp_path / "old.db"
    con = sqlite3.connect(db)
    con.executescript(SCHEMA_1 + f"PRAGMA user_version = 1; PRAGMA application_id = {APPLICATION_ID};"
                      "INSERT INTO captures (robot, sequence, time, elevation, azimuth, space, bands)"
                      " VALUES ('rover', 0, 1.0, 45, 10, 'rgb', '[\"R\"]');")
    con.close()
    ingest(utia, "utia", db, workers=0)
    with Store.open(db) as store:
        old = store.captures(robot="rover")
        assert [(c.measured, c.illumination, c.source) for c in old] == [((45.0, 10.0), (None, None), None)]
        assert len(store.captures()) == 13
        assert {c.illumination for c in store.captures(robot=dataset_robot(utia))} == {(40.0, 0.0), (70.0, 0.0)}


def test_cli_ingest_and_its_errors(utia, tmp_path, capsys):
    assert main(["ingest", str(utia), "--layout", "utia", "--db", str(tmp_path / "c.db"),
                 "--mask", str(utia / "masks"), "--workers", "0"]) == 0
    out = capsys.readouterr()
    assert "12 image(s) stored, 0 already there" in out.out and "12/12" in out.err
    assert main(["ingest", str(utia), "--layout", "utia", "--db", str(tmp_path / "c.db"), "--quiet"]) == 0
    assert "0 image(s) stored, 12 already there" in capsys.readouterr().out
    bad = [
        (["ingest", str(tmp_path / "nope"), "--layout", "utia"], "no such directory"),
        (["ingest", str(utia), "--layout", "bonn"], "--layout: invalid choice: 'bonn'"),
        (["ingest", str(utia), "--layout", "curet"], "angles.txt: no such file"),
        (["ingest", str(utia), "--layout", "utia", "--workers", "-1"], "--workers"),
        (["ingest", str(utia), "--layout", "utia", "--space", "lab"], "--space: invalid choice: 'lab'"),
    ]
    (tmp_path / "odd").mkdir()
    (tmp_path / "odd" / "photo.png").write_bytes((utia / "masks" / next(iter(
        sorted(p.name for p in (utia / "masks").iterdir())))).read_bytes())
    bad.append((["ingest", str(tmp_path / "odd"), "--layout", "utia"], "photo.png: file name does not read"))
    for argv, problem in bad:
        assert main(argv + ["--db", str(tmp_path / "e.db"), "--quiet"]) == 2
        err = capsys.readouterr().err.strip()
        assert problem in err and len(err.splitlines()) == 1


def test_results_are_written_in_batches_and_a_failure_keeps_the_batch_before_it():
    from tools.data.ingest import _batches

    assert [len(c) for c in _batches(iter(range(10)), 4, 1e9)] == [4, 4, 2]
    assert [len(c) for c in _batches(iter(range(3)), 64, 0.0)] == [1, 1, 1]  # no wait past the deadline

    def failing():
        yield from range(5)
        raise IngestError("image 5 is broken")

    got = []
    with pytest.raises(IngestError, match="broken"):
        for chunk in _batches(failing(), 4, 1e9):
            got.append(chunk)
    assert got == [[0, 1, 2, 3], [4]]
