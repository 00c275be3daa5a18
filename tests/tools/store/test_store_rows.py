"""Rows we never write (NaN or infinite parameters, text in number columns, broken band lists,
damaged masks) are one line naming the row and exit status 2, never a traceback."""
import sqlite3

import numpy as np
import pytest

from btf.fit.png import encode_png
from tests.support.packets import filled_database
from tools.cli import main
from tools.station.receiver import mask_key
from tools.store.database import CorruptDatabase, Store

BAD_ROWS = {
    "gamma is 'NaN', not a number": "UPDATE models SET gamma = 'NaN' WHERE label = 1 AND band = 0",
    "lam is inf, not a finite number": "UPDATE models SET lam = 9e999 WHERE band = 2",
    "xi is -inf": "UPDATE models SET xi = -9e999",
    "delta must be positive": "UPDATE models SET delta = -1.5",
    "unknown family 'XX'": "UPDATE models SET family = 'XX'",
    "band = 1000000000000 outside": "UPDATE models SET band = 1000000000000 WHERE label = 1 AND band = 2",
    "count is 'many', not an integer": "UPDATE models SET count = 'many'",
    "censored fractions": "UPDATE models SET censored_high = 3.0",
    "p0 is inf": "UPDATE models SET p0 = 9e999",
    "bands is 'R,G,B', not a JSON list": "UPDATE captures SET bands = 'R,G,B'",
    "elevation is 'high', not a number": "UPDATE captures SET elevation = 'high'",
    "time is inf": "UPDATE captures SET time = 9e999",
    "not a PNG of its stored size": "UPDATE masks SET data = x'00ff'",
    "height = 100000 outside": "UPDATE masks SET height = 100000",
}


def _spoiled(tmp_path, sql):
    db = filled_database(tmp_path / "scene.db")
    conn = sqlite3.connect(db)
    conn.execute(sql)
    conn.commit()
    conn.close()
    return db


@pytest.mark.parametrize("reason", sorted(BAD_ROWS))
def test_report_on_a_bad_row_is_one_line_and_status_2(tmp_path, capsys, reason):
    db = _spoiled(tmp_path, BAD_ROWS[reason])
    before = db.read_bytes()
    assert main(["report", "--db", str(db), "--out", str(tmp_path / "rep"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert reason in err[0] and str(db) in err[0] and "Traceback" not in err[0]
    assert db.read_bytes() == before  # left untouched


@pytest.mark.parametrize("reason", ["gamma is 'NaN', not a number", "lam is inf, not a finite number",
                                    "bands is 'R,G,B', not a JSON list", "time is inf"])
def test_synth_on_a_bad_row_is_one_line_and_status_2_as_report_is(tmp_path, capsys, reason):
    db = _spoiled(tmp_path, BAD_ROWS[reason])
    mask = tmp_path / "mask.png"
    mask.write_bytes(encode_png(np.full((20, 30), 1, np.uint8)))
    before = db.read_bytes()
    code = main(["synth", "--db", str(db), "--mask", str(mask), "--angle", "50", "--out", str(tmp_path / "o.png")])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1, err
    assert reason in err[0] and str(db) in err[0] and "Traceback" not in err[0]
    assert db.read_bytes() == before and not (tmp_path / "o.png").exists()


def test_the_store_names_the_capture_and_model_of_a_nan_row(tmp_path):
    db = _spoiled(tmp_path, BAD_ROWS["gamma is 'NaN', not a number"])
    with Store.open(db) as s:
        cap = s.captures()[0]
        with pytest.raises(CorruptDatabase, match=r"capture \d+: model \(label 1, band 0\): gamma is 'NaN'"):
            s.models(cap.id)
        other = {label for label, _ in s.models(cap.id, band=1)}
        assert 1 in other  # the good rows still read


def test_a_mask_row_is_checked_before_its_png_is_decoded(tmp_path):
    db = filled_database(tmp_path / "scene.db")
    with Store.open(db) as s:
        good = s.mask(mask_key(1), "3")
    conn = sqlite3.connect(db)
    # A PNG whose header claims 16384 x 16384 pixels under the row's real size.
    png = conn.execute("SELECT data FROM masks").fetchone()[0]
    big = png[:16] + (16384).to_bytes(4, "big") * 2 + png[24:]
    conn.execute("UPDATE masks SET data = ?", (big,))
    conn.commit()
    conn.close()
    with Store.open(db) as s, pytest.raises(CorruptDatabase, match="not a PNG of its stored size"):
        s.mask(mask_key(1), "3")
    assert good.shape == (40, 48)
