"""`btf-host export`: the database's BTF as Parquet or CSV, partitioned by robot and scene, read
back by pyarrow, DuckDB, pandas and Dask; grown databases add only new files; a failure mid-export
leaves no partial file."""
import json
import shutil
import sqlite3

import pytest

from tests.support.btf_sweeps import curved_su, linear_normal, write_sweep
from tools.data import export as exporter
from tools.store.database import Store

pa_ds = pytest.importorskip("pyarrow.dataset")
duckdb = pytest.importorskip("duckdb")
pd = pytest.importorskip("pandas")
ELEVATIONS = (20.0, 40.0, 60.0, 80.0)


@pytest.fixture
def db(tmp_path):
    path = tmp_path / "s.db"
    write_sweep(path, linear_normal, ELEVATIONS, robot="7", scene="plate")
    write_sweep(path, curved_su, ELEVATIONS, robot="dataset:/data/a b", scene="", labels=(3,))
    return path


def stored(db):
    """(robot, capture id, label, band) -> the stored model's row values the export must carry."""
    with Store.open(db) as store:
        return {(c.robot, c.id, lab, b): (r.model.family.value, r.model.gamma, r.model.delta, r.model.xi, r.model.lam,
                                          r.count, c.sequence, c.incarnation, c.scene, c.measured[0])
                for c in store.captures() for (lab, b), r in store.models(c.id).items()}


def as_rows(records):
    return {(str(r["robot"]), int(r["capture_id"]), int(r["label"]), int(r["band"])):
            (r["family"], r["gamma"], r["delta"], r["xi"], r["lam"], int(r["pixels"]), int(r["sequence"]),
             r["incarnation"], r["scene"], r["elevation"]) for r in records}


def readers(out, fmt="parquet"):
    """The export as each reader sees it: a list of row dicts per reader."""
    if fmt == "parquet":
        import dask.dataframe as dd

        yield "pyarrow", pa_ds.dataset(out, partitioning="hive").to_table().to_pylist()
        yield "duckdb", duckdb.sql(f"SELECT * FROM read_parquet('{out}/**/*.parquet', hive_partitioning = true)").df().to_dict("records")
        yield "pandas", pd.read_parquet(out).to_dict("records")
        yield "dask", dd.read_parquet(str(out)).compute().to_dict("records")
    else:
        yield "duckdb", duckdb.sql(f"SELECT * FROM read_csv('{out}/**/*.csv', hive_partitioning = true, "
                                   "hive_types_autocast = false, allow_quoted_nulls = false)").df().to_dict("records")


@pytest.mark.filterwarnings("ignore:The inplace keyword")  # dask's own call into pandas
def test_every_reader_gets_one_row_per_stored_model_with_its_parameters(host, db, tmp_path):
    code, out, err = host("export", "--db", db, "--out", tmp_path / "x")
    assert code == 0 and "new export: 36 row(s) in 2 file(s), 2 robot and scene partition(s)" in out, err
    truth = stored(db)
    assert len(truth) == 4 * 6 + 4 * 3
    for name, records in readers(tmp_path / "x"):
        assert len(records) == len(truth), name
        assert as_rows(records) == truth, name
    row = pa_ds.dataset(tmp_path / "x", partitioning="hive").to_table().to_pylist()[0]
    assert row["exposure_us"] == 5000.0 and row["gain"] == 2.0 and row["commanded_elevation"] in ELEVATIONS
    if row["label"] == 1:  # its record of the older layout: the separable window of radius 8
        assert row["dependence_radius"] == 8 and row["dependence_acf"][:2] == pytest.approx([0.9, 0.8])
        assert (row["level_lo"], row["level_hi"]) == ((10, 200), (20, 210), (30, 220))[row["band"]]
    else:
        assert row["dependence_acf"] is None and row["level_lo"] is None
    assert row["mean"] > row["sd"] > 0 and row["skewness"] is not None
    datasets = {r["dataset"]: r["robot"] for r in pa_ds.dataset(tmp_path / "x", partitioning="hive").to_table().to_pylist()}
    assert datasets == {None: "7", "/data/a b": "dataset:/data/a b"}


def test_csv_has_the_same_rows_with_lists_as_json(host, db, tmp_path):
    code, _, err = host("export", "--db", db, "--out", tmp_path / "c", "--format", "csv")
    assert code == 0, err
    (_, records), = readers(tmp_path / "c", "csv")
    assert as_rows(records) == stored(db)
    one = next(r for r in records if r["label"] == 1)
    assert json.loads(one["dependence_corr"]) == [0.5, 0.4, 0.3]


def test_a_grown_database_adds_only_its_new_captures(host, db, tmp_path):
    out = tmp_path / "x"
    assert host("export", "--db", db, "--out", out)[0] == 0
    first = {p: p.read_bytes() for p in out.rglob("*.parquet")}
    write_sweep(db, linear_normal, (30.0, 50.0), robot="7", scene="plate", first_sequence=20)
    code, text, err = host("export", "--db", db, "--out", out)
    assert code == 0 and "added to the export: 12 row(s) in 1 file(s)" in text, err
    assert all(p.read_bytes() == data for p, data in first.items())  # nothing rewritten
    assert len(list(out.rglob("*.parquet"))) == 3
    records = pa_ds.dataset(out, partitioning="hive").to_table().to_pylist()
    assert as_rows(records) == stored(db) and len(records) == len(stored(db))
    assert "0 row(s) in 0 file(s)" in host("export", "--db", db, "--out", out)[1]


def _visible(root):
    return sorted(str(p.relative_to(root)) for p in root.rglob("*"))


def test_a_database_damaged_mid_export_leaves_no_partial_file(host, db, tmp_path):
    out = tmp_path / "x"
    con = sqlite3.connect(db)
    last = con.execute("SELECT MAX(id) FROM captures WHERE robot = '7'").fetchone()[0]
    con.execute("UPDATE models SET gamma = 'broken' WHERE capture = ?", (last,))
    con.commit()
    con.close()
    code, text, err = host("export", "--db", db, "--out", out)
    assert code == 2 and text == "" and "gamma" in err and len(err.strip().splitlines()) == 1
    assert not out.exists() and [p.name for p in tmp_path.iterdir()] == ["s.db"] + [
        p.name for p in tmp_path.iterdir() if p.name.startswith("s.db-")]


def test_a_failure_while_adding_leaves_whole_files_only(db, tmp_path, monkeypatch):
    out = tmp_path / "x"
    with Store.open(db) as store:
        exporter.export(store, out)
    before = _visible(out)
    write_sweep(db, curved_su, (30.0, 50.0, 70.0), robot="7", scene="plate", first_sequence=20)
    real, calls = exporter.capture_rows, []

    def failing(store, capture):
        calls.append(capture.id)
        if len(calls) == 2:
            raise OSError(28, "No space left on device")
        return real(store, capture)

    monkeypatch.setattr(exporter, "BATCH_CAPTURES", 1)  # the first rows are on disk when it fails
    monkeypatch.setattr(exporter, "capture_rows", failing)
    with Store.open(db) as store, pytest.raises(OSError):
        exporter.export(store, out)
    assert _visible(out) == before  # no temporary file, no part of one
    monkeypatch.setattr(exporter, "capture_rows", real)
    with Store.open(db) as store:
        report = exporter.export(store, out)
    assert report.rows == 3 * 6 and as_rows(pa_ds.dataset(out, partitioning="hive").to_table().to_pylist()) == stored(db)


def test_force_replaces_only_an_earlier_export_and_errors_are_one_line(host, db, tmp_path):
    def error(*argv):
        code, out, err = host(*argv)
        assert code == 2 and out == "" and len(err.strip().splitlines()) == 1, (code, out, err)
        return err

    # a directory of anything else is never replaced: not the user's notes, not the database itself
    other = tmp_path / "other"
    other.mkdir()
    (other / "notes.txt").write_text("mine")
    shutil.copy(db, other / "scene.db")
    for force in ((), ("--force",)):
        said = error("export", "--db", other / "scene.db", "--out", other, *force)
        assert "holds notes.txt, scene.db" in said and "not an export" in said
    assert (other / "notes.txt").read_text() == "mine" and stored(other / "scene.db") == stored(db)
    empty = tmp_path / "empty"
    empty.mkdir()
    assert host("export", "--db", db, "--out", empty)[0] == 0 and len(list(empty.rglob("*.parquet"))) == 2
    assert "not a csv export" in error("export", "--db", db, "--out", empty, "--format", "csv")
    assert "pass --force" in error("export", "--db", db, "--out", empty, "--format", "csv")
    assert host("export", "--db", db, "--out", empty, "--format", "csv", "--force")[0] == 0
    assert not list(empty.rglob("*.parquet")) and len(list(empty.rglob("*.csv"))) == 2
    assert "choose from 'parquet', 'csv'" in error("export", "--db", db, "--out", tmp_path / "y", "--format", "xlsx")
    assert "no such database" in error("export", "--db", tmp_path / "none.db", "--out", tmp_path / "y")
    with Store.open(tmp_path / "empty.db"):
        pass
    assert "no captures" in error("export", "--db", tmp_path / "empty.db", "--out", tmp_path / "y")
    (tmp_path / "file").write_text("x")
    assert "is a file" in error("export", "--db", db, "--out", tmp_path / "file")
    assert "does not exist" in error("export", "--db", db, "--out", tmp_path / "no" / "such" / "dir")
