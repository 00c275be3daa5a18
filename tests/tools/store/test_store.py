"""The SQLite store: idempotent captures, queries, masks, and refusal of foreign files."""
import dataclasses
import sqlite3

import numpy as np
import pytest

from btf.fit.fitter import fit_histogram
from btf.johnson import Family
from tests.support.databases import older_database
from tools.store.database import CorruptDatabase, Store


def results(shift=0):
    rng = np.random.default_rng(shift)
    out = {}
    for label in (0, 1):
        for band in (0, 1, 2):
            v = np.clip(rng.normal(60 + 40 * label + shift, 8 + band, 5000), 0, 255).astype(np.int64)
            out[(label, band)] = fit_histogram(np.bincount(v, minlength=256))
    return out


def add(store, seq, angle, shift=0):
    return store.add_capture("bot", seq, 1000.0 + seq, (angle, 0.0), (angle + 0.2, 1.0),
                             "rgb", ("R", "G", "B"), results(shift))


def test_capture_round_trip_and_idempotent_insert(tmp_path):
    with Store.open(tmp_path / "s.db") as s:
        assert add(s, 1, 30.0) is True
        assert add(s, 1, 30.0) is False  # the same packet received twice
        (cap,) = s.captures()
        assert (cap.robot, cap.sequence, cap.measured, cap.commanded) == ("bot", 1, (30.2, 1.0), (30.0, 0.0))
        assert cap.band_names == ("R", "G", "B")
        stored = s.models(cap.id)
        assert len(stored) == 6
        want = results()[(1, 2)]
        got = s.models(cap.id, label=1, band=2)[(1, 2)]
        assert got.model == want.model and got.count == want.count
        assert got.percentiles == pytest.approx(want.percentiles)
        assert isinstance(got.model.family, Family)
    with Store.open(tmp_path / "s.db") as s:  # reopening keeps everything
        assert len(s.captures()) == 1 and s.next_sequence("bot") == 2


def test_angles_and_models_at(tmp_path):
    with Store.open(tmp_path / "s.db") as s:
        add(s, 1, 0.0)
        add(s, 2, 60.0, shift=20)
        assert s.angles() == [pytest.approx(0.2), pytest.approx(60.2)]
        at = s.models_at(60.0)
        assert at[(0, 0)] == results(20)[(0, 0)].model
        assert s.models_at(30.0) == {}
        assert list(s.models_by_angle()) == s.angles()
        assert s.labels() == [0, 1]


def test_masks_round_trip(tmp_path):
    mask = (np.arange(12).reshape(3, 4) % 3).astype(np.uint8)
    with Store.open(tmp_path / "s.db") as s:
        assert s.add_mask("mixed", mask) is True
        assert s.add_mask("mixed", mask) is False
        assert np.array_equal(s.mask("mixed"), mask)
        assert s.mask("other") is None


@pytest.mark.parametrize("content", [b"this is not a database at all", b"SQLite format 3\x00" + b"\x07" * 600])
def test_garbage_file_is_refused_and_untouched(tmp_path, content):
    p = tmp_path / "x.db"
    p.write_bytes(content)
    with pytest.raises(CorruptDatabase, match="x.db"):
        Store.open(p)
    assert p.read_bytes() == content


def test_foreign_sqlite_database_is_refused_and_untouched(tmp_path):
    p = tmp_path / "other.db"
    con = sqlite3.connect(p)
    con.execute("CREATE TABLE people (name TEXT)")
    con.commit()
    con.close()
    before = p.read_bytes()
    with pytest.raises(CorruptDatabase, match="not a btfscout database"):
        Store.open(p)
    assert p.read_bytes() == before


def test_failed_insert_leaves_nothing_half_written(tmp_path):
    good = results()[(0, 0)]

    # five percentiles: the models insert fails after the capture row went in
    bad = dataclasses.replace(good, percentiles=(1.0, 2.0, 3.0, 4.0, 5.0))

    with Store.open(tmp_path / "s.db") as s:
        with pytest.raises(sqlite3.Error):
            s.add_capture("bot", 5, 0.0, None, 10.0, "rgb", ("R",), {(0, 0): good, (1, 0): bad})
        assert s.captures() == []
        assert add(s, 5, 10.0) is True  # the sequence number is still free


def test_batch_commits_many_writes_together_and_rolls_back_all_on_error(tmp_path):
    with Store.open(tmp_path / "s.db") as s:
        with s.batch():
            assert add(s, 1, 30.0) is True
            assert add(s, 1, 30.0) is False  # a duplicate inside a batch drops only itself
            assert add(s, 2, 40.0) is True
            s.add_mask("m", np.zeros((4, 5), np.uint8), "bot")
        assert [c.sequence for c in s.captures()] == [1, 2]
        with pytest.raises(RuntimeError):
            with s.batch():
                add(s, 3, 50.0)
                s.add_mask("n", np.ones((4, 5), np.uint8), "bot")
                raise RuntimeError("interrupted")
        assert [c.sequence for c in s.captures()] == [1, 2]
        assert s.mask("n", "bot") is None and s.mask("m", "bot") is not None
    # another connection sees exactly the committed rows
    con = sqlite3.connect(tmp_path / "s.db")
    assert con.execute("SELECT COUNT(*) FROM captures").fetchone()[0] == 2
    assert con.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    con.close()


def test_capture_by_seq_finds_one_robot_capture(tmp_path):
    with Store.open(tmp_path / "s.db") as s:
        add(s, 4, 30.0)
        s.add_capture("other", 4, 0.0, None, 70.0, "rgb", ("R", "G", "B"), results())
        got = s.capture_by_seq("bot", 4)
        assert (got.robot, got.sequence, got.elevation) == ("bot", 4, 30.2)
        assert s.capture_by_seq("other", 4).elevation == 70.0
        assert s.capture_by_seq("bot", 5) is None


def test_pca_basis_is_stored_with_its_capture_and_inherited_by_later_ones(tmp_path):
    from btf.fit.features import PcaBasis

    rng = np.random.default_rng(0)
    a = PcaBasis.fit(rng.integers(0, 255, (20, 30, 3), dtype=np.uint8))
    b = PcaBasis.fit(rng.integers(50, 90, (20, 30, 3), dtype=np.uint8))
    with Store.open(tmp_path / "s.db") as s:
        add(s, 1, 30.0)
        for seq, angle, basis in ((2, 40.0, a), (3, 50.0, None), (5, 60.0, b), (6, 70.0, None)):
            s.add_capture("bot", seq, 0.0, None, angle, "pca", ("P1", "P2", "P3"), results(), pca=basis)
        by_seq = {c.sequence: s.pca_basis(c.id) for c in s.captures()}
        assert by_seq == {1: None, 2: a, 3: a, 5: b, 6: b}
        assert s.pca_by_angle(space="pca") == {40.0: a, 50.0: a, 60.0: b, 70.0: b}


def test_a_directory_is_refused_as_a_database(tmp_path):
    (tmp_path / "d.db").mkdir()
    with pytest.raises(CorruptDatabase, match="not a regular file"):
        Store.open(tmp_path / "d.db")
    assert list((tmp_path / "d.db").iterdir()) == []


def test_a_record_reads_back_as_it_was_stored_its_read_included(tmp_path):
    from btf.record import FittedModel, rebuild

    h = np.bincount(np.clip(np.rint(np.random.default_rng(3).gamma(1.5, 9, 40_000)), 0, 255).astype(int),
                    minlength=256)
    fit = fit_histogram(h)
    pct = fit.percentiles
    shifted = FittedModel.solve(pct, 0.3, fit.count, shift=0.5, beta1=1.0, beta2=4.0)
    exact = FittedModel.solve(pct, 0.524, fit.count, exact_family=True)
    fallback = FittedModel.solve((0.0, 0.0, 255.0, 255.0), 0.1, 5000, censored_low=0.4, censored_high=0.3,
                                 fallback=True)
    records = {(0, 0): fit, (0, 1): shifted, (0, 2): exact, (1, 0): fallback, (1, 1): fit, (1, 2): fit}
    with Store.open(tmp_path / "s.db") as s:
        s.add_capture("bot", 1, 0.0, None, 30.0, "rgb", ("R", "G", "B"), records)
        back = s.models(s.captures()[0].id)
    assert back == records
    assert all(rebuild(r) == r.model for r in back.values())


def test_rejected_packets_are_kept_raw_newest_first_and_bounded(tmp_path, monkeypatch):
    from tools.store import database

    monkeypatch.setattr(database, "REJECTED_KEPT", 3)
    with Store.open(tmp_path / "x.db") as s:
        for i in range(5):
            s.add_rejected(100.0 + i, 1, "ab12", i, f"undecodable packet: {i}", bytes([i]) * 3)
        s.add_rejected(200.0, None, "", 2**63 + 5, "an automatic id past SQLite's integers", b"\x93")
        kept = s.rejected()
    assert [r.msg_id for r in kept] == [None, 4, 3] and kept[1].body == b"\x04" * 3
    assert kept[1].reason == "undecodable packet: 4" and kept[1].sender == 1 and kept[1].incarnation == "ab12"


def test_a_database_from_before_rejected_packets_gains_the_table(tmp_path):
    db = older_database(tmp_path / "old.db", 8, "DROP TABLE rejected_packets; ALTER TABLE capture_camera DROP COLUMN source;")
    with Store.open(db) as s:
        assert len(s.captures()) == 1 and s.rejected() == []
        s.add_rejected(1.0, 1, "", 7, "refused", b"x")
        assert [r.msg_id for r in s.rejected()] == [7]


def test_a_database_from_before_space_choices_gains_the_table_and_keeps_its_captures(tmp_path):
    db = older_database(tmp_path / "old.db", 11, "DROP TABLE space_choices;",
                        "1", 1, 1.0, (90.0, 0.0), (90.0, 0.0), "pca", ("P1", "P2", "P3"), {})
    with Store.open(db) as s:
        cap = s.captures()[0]
        assert s.space_choice(cap.id) is None
        s.add_space_choice("1", 1, "pca: its bands correlate least")
        s.add_capture("1", 2, 2.0, (80.0, 0.0), (80.0, 0.0), "pca", ("P1", "P2", "P3"), {})
        s.add_capture("1", 3, 3.0, (70.0, 0.0), (70.0, 0.0), "rgb", ("R", "G", "B"), {})
        by_seq = {c.sequence: s.space_choice(c.id) for c in s.captures()}
    # a robot's later capture in the same space inherits the choice; one in another space does not
    assert by_seq == {1: "pca: its bands correlate least", 2: "pca: its bands correlate least", 3: None}
