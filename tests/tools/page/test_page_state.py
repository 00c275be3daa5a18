"""What the page draws, without a browser: the sweep's grid from the robot's own STATUS answer,
advanced by captures between reports; the failsafe assumed while the link is silent; the robot's
disk and rejections; goodput; the latest capture per pose; azimuths in [0, 360); what watch says
of a robot not heard yet; a one-band photograph's histograms with its measured levels; hsv and pca captures drawn as RGB pictures."""
import dataclasses

import cv2
import numpy as np
import pytest
from skimage import data as skdata

from hal.interfaces import ViewAngles
from onboard.link.status import sweep_report
from onboard.sweep.plan import SkippedPose, SweepPlan, SweepProgress
from radio import packets as pk
from tests.support.packets import models_body
from tests.support.spaces import stored_plate
from tools.cli.watch import summary
from tools.data.images import read_image, write_image, write_mask
from tools.page.data import CaptureIndex, render
from tools.report.capture_views import capture_mask, histogram_png
from tools.report.look import capture_title
from tools.station.receiver import Item, ItemKind, Receiver
from tools.station.snapshot import StationSnapshot
from tools.station.sweep_grid import grid_json, plan_of_command
from tools.store.database import Store


def report(plan, next_index=0, skipped=(), mode="sweeping"):
    """The robot's STATUS report (onboard.link.status.Status.report), as its answer carries it."""
    progress = SweepProgress(4, plan, next_index, skipped=[SkippedPose(i, ViewAngles(e, a), r) for i, e, a, r in skipped])
    return pk.StatusReport(mode=mode, outbox=2, paused="", disk=pk.Disk("ok", 10**9), rejected=pk.Kept(),
                           failsafe=pk.Kept(), failsafe_s=1.5, torque=True,
                           faults=pk.Kept(("servo 2: overload (retried)",)), errors=pk.Kept(),
                           sweep=sweep_report(progress, whole=True))


def answer_report(rep):
    """The report as it arrives: through the ACK packet's encoder and decoder."""
    body = pk.encode(pk.AckPacket(7, "STATUS", status=rep))
    return pk.decode(body).status


def capture_item(seq, elevation, azimuth):
    body, _, _ = models_body(seq, elevation)
    p = pk.decode(body)
    p = dataclasses.replace(p, commanded=(elevation, azimuth))
    return Item(ItemKind.CAPTURE, p.robot_id, seq, True, "capture", p)


def test_the_grid_comes_from_the_robots_plan_and_advances_with_each_capture():
    plan = SweepPlan(80.0, 60.0, 10.0, (0.0, 90.0))  # 80, 70, 60 at 0 then at 90
    snap = StationSnapshot("pty", "db", 0.0)
    snap.note_status_answer(answer_report(report(plan, 1, [(2, 60.0, 0.0, "servo 1: no answer")])), 10.0)
    grid = snap.to_json(10.0)["sweep"]["grid"]
    assert grid["elevations"] == [80.0, 70.0, 60.0] and grid["azimuths"] == [0.0, 90.0]
    # row by row (azimuth 0, then 90): 80 done, pending; 70 measuring, pending; 60 skipped, pending
    assert grid["cells"] == "dpmpsp" and grid["reasons"] == {"2,0": "servo 1: no answer"}
    snap.note_capture(capture_item(5, 70.0, 0.0), 11.0)
    assert snap.to_json(11.0)["sweep"]["grid"]["cells"] == "dmdpsp"
    snap.note_capture(capture_item(6, 80.0, 90.0), 12.0)
    assert snap.to_json(12.0)["sweep"]["grid"]["cells"] == "dddmsp"
    # the robot's next report says the same: nothing counted twice
    snap.note_status_answer(answer_report(report(plan, 4, [(2, 60.0, 0.0, "servo 1: no answer")])), 13.0)
    js = snap.to_json(13.0)
    assert js["sweep"]["grid"]["cells"] == "dddmsp" and js["sweep"]["next"] == 4
    assert js["robot"]["failsafe_s"] == 1.5 and js["robot"]["torque"] is True
    assert js["robot"]["faults"] == ["servo 2: overload (retried)"] and js["robot"]["outbox"] == 2


def test_a_sweep_this_station_sent_has_its_grid_before_the_robot_reports_it():
    assert plan_of_command({"elevations": [80.0, 40.0]}) is None  # azimuths from the robot's config
    plan = plan_of_command({"elevations": [80.0, 40.0], "azimuths": [0.0]})
    assert grid_json(plan, 0, set(), [], True)["cells"] == "mp"
    plan = plan_of_command({"start": 90.0, "stop": 70.0, "step": 10.0, "azimuths": [0.0, 180.0]})
    assert grid_json(plan, None, {4}, [], False) == {"elevations": [90.0, 80.0, 70.0], "azimuths": [0.0, 180.0],
                                                    "cells": "pppdpp", "reasons": {}}


def test_a_plan_too_long_for_a_status_is_left_out_saying_so_and_the_answer_still_encodes():
    plan = SweepPlan(0.0, 0.0, 1.0, tuple(float(a) for a in range(300)), (80.0,))
    sweep = answer_report(report(plan)).sweep
    assert sweep.plan is None and sweep.plan_left_out and sweep.poses == 300
    listed = SweepPlan(0.0, 0.0, 1.0, tuple(float(a) for a in range(64)), tuple(80.0 - i * 0.37 for i in range(64)))
    assert answer_report(report(listed)).sweep.plan.elevations == listed.elevations  # 64 x 64 travels whole now
    short = answer_report(report(SweepPlan(90.0, 30.0, 10.0, (0.0,))))
    assert short.sweep.plan.step == 10.0


def test_a_silent_link_past_the_robots_failsafe_is_shown_as_the_failsafe():
    snap = StationSnapshot("pty", "db", 0.0)
    assert snap.to_json(0.0)["robot"]["failsafe_assumed"] is False  # never heard: nothing assumed
    snap.note_link(True, 1.0)
    snap.link.last_heard = 1.0
    snap.note_status_answer(pk.StatusReport(mode="idle", failsafe_s=3.0), 1.0)
    snap.note_link(False, 6.0)
    assert snap.to_json(3.5)["robot"]["failsafe_assumed"] is False
    assert snap.to_json(6.0)["robot"]["failsafe_assumed"] is True
    snap.note_link(True, 7.0)
    assert snap.to_json(7.0)["robot"]["failsafe_assumed"] is False


def test_the_robots_disk_and_rejections_and_the_goodput_are_in_the_snapshot():
    snap = StationSnapshot("pty", "db", 0.0)
    snap.note_status_answer(pk.StatusReport(mode="idle", disk=pk.Disk("low", 123456), rejected=pk.Kept(
        (pk.Rejection("crc", 3), pk.Rejection("tag", 1)))), 1.0)
    for t in range(10):
        snap.note_delivered(100, 100.0 + t)
    js = snap.to_json(109.0)
    assert (js["robot"]["disk"], js["robot"]["disk_free"]) == ("low", 123456)
    assert js["robot"]["rejected"] == {"crc": 3, "tag": 1}
    assert js["link"]["goodput_bps"] == 100.0 and js["link"]["delivered_bytes"] == 1000
    assert snap.to_json(200.0)["link"]["goodput_bps"] == 0.0


def test_the_page_lists_the_latest_capture_at_each_pose(tmp_path):
    with Store.open(tmp_path / "scene.db") as s:
        rx = Receiver(s, scene="mixed")
        for seq, el in ((1, 60.0), (2, 70.0), (3, 60.0)):
            rx.handle(models_body(seq, el)[0])
    index = CaptureIndex(str(tmp_path / "scene.db"))
    cards = index.refresh()
    assert sorted((c["seq"], c["commanded"][0]) for c in cards) == [(2, 70.0), (3, 60.0)]
    assert index.refresh() == []
    with Store.open(tmp_path / "scene.db") as s:
        Receiver(s, scene="mixed").handle(models_body(4, 70.0)[0])
    assert [c["seq"] for c in index.refresh()] == [4]
    assert sorted(c["seq"] for c in index.latest.values()) == [3, 4]
    index.close()


def test_azimuths_are_shown_in_one_convention_never_as_360(tmp_path):
    with Store.open(tmp_path / "scene.db") as s:
        for seq, az in ((1, 359.96), (2, -0.04), (3, 90.0)):
            body, _, _ = models_body(seq, 65.3)
            p = dataclasses.replace(pk.decode(body), measured=(65.3, az), commanded=(65.0, 10.0 * seq))
            assert Receiver(s, scene="mixed").handle(pk.encode(p)).stored
    index = CaptureIndex(str(tmp_path / "scene.db"))
    assert sorted(c["azimuth"] for c in index.refresh()) == [0.0, 0.0, 90.0]
    index.close()
    with Store.open(tmp_path / "scene.db") as s:
        titles = [capture_title(c) for c in s.captures()]
    assert not any("360.0" in t for t in titles) and any("65.3° / 90.0°" in t for t in titles), titles


def test_watch_says_a_robot_not_heard_yet_and_then_what_its_answer_told():
    snap = StationSnapshot("/dev/pts/1", "scene.db", 1.7e9)
    assert "robot not heard yet" in summary(snap.to_json(1.7e9 + 1))
    plan = SweepPlan(90.0, 30.0, 30.0, (0.0,))
    snap.note_status_answer(answer_report(report(plan, mode="idle")), 1.7e9 + 2)  # an answer carries no id
    text = summary(snap.to_json(1.7e9 + 3))
    assert "robot (id not heard yet): idle at an unknown pose, outbox 2" in text and "None" not in text


def test_the_page_draws_the_chosen_capture_before_the_cards_and_each_drawing_once(tmp_path, monkeypatch):
    import asyncio
    import time
    from concurrent.futures import ThreadPoolExecutor

    import tools.page.data as page_data

    drawn = []

    def render(db, capture_id, fake, what, rev):
        drawn.append((capture_id, what, rev))
        time.sleep(0.2 if capture_id == 99 else 0.005)
        return {"png": b"%d" % capture_id}

    monkeypatch.setattr(page_data, "render", render)
    data = page_data.PageData(str(tmp_path / "scene.db"))
    data._pool = ThreadPoolExecutor(1)  # the drawings in a thread here: the queue is what is tested
    data._btf_pool = ThreadPoolExecutor(1)

    async def go():
        thumbs = [asyncio.ensure_future(data.drawn(i, "thumb")) for i in range(1, 6)]
        section = asyncio.ensure_future(data.drawn(3, "section"))
        histograms = asyncio.ensure_future(data.drawn(3, "histograms"))
        await asyncio.gather(*thumbs, section, histograms)
        early = asyncio.ensure_future(data.drawn(9, "thumb"))
        data.mask_arrived()  # before it was drawn: asked again under the new revision
        late = asyncio.ensure_future(data.drawn(9, "thumb"))
        again = asyncio.ensure_future(data.drawn(9, "thumb"))
        nines = await asyncio.gather(early, late, again)
        busy = asyncio.ensure_future(data.drawn(99, "thumb"))  # the worker busy meanwhile
        await asyncio.sleep(0.05)
        left = asyncio.ensure_future(data.drawn(20, "section"))
        chosen = asyncio.ensure_future(data.drawn(21, "section"))
        await asyncio.sleep(0.01)
        left.cancel()  # the page went on to another capture before this one's turn
        await asyncio.gather(busy, chosen)
        return nines

    assert asyncio.run(go()) == [{"png": b"9"}] * 3
    assert drawn[:2] == [(3, "section", 0), (3, "histograms", 0)]
    assert sorted(drawn[2:7]) == [(i, "thumb", 0) for i in range(1, 6)]
    assert drawn[7:] == [(9, "thumb", 1), (99, "thumb", 1), (21, "section", 1)]  # 9 once, at the revision
    # in force; 20, left before its turn, not at all
    data.close()


def test_a_pose_measured_again_after_the_plan_is_done_and_the_sweeps_missing_poses_are_listed_with_why():
    plan = SweepPlan(80.0, 60.0, 10.0, (0.0,))  # 80, 70, 60
    progress = SweepProgress(4, plan, 3, retry_skipped=2, skipped=[
        SkippedPose(0, ViewAngles(80.0, 0.0), "move failed after 3 attempts", True),
        SkippedPose(2, ViewAngles(60.0, 0.0), "settle failed", True)])
    snap = StationSnapshot("pty", "db", 0.0)
    snap.note_status_answer(answer_report(dataclasses.replace(report(plan), sweep=sweep_report(progress, whole=True))),
                            10.0)
    assert snap.to_json(10.0)["sweep"]["grid"]["cells"] == "sds" and snap.to_json(10.0)["sweep"]["missing"] is None
    snap.note_capture(capture_item(5, 80.0, 0.0), 11.0)  # the robot tried pose 80 again: measured
    js = snap.to_json(11.0)["sweep"]
    assert js["grid"]["cells"] == "dds" and [k["index"] for k in js["skipped"]] == [2]
    gone = pk.SkippedPose(2, 60.0, 0.0, "settle failed: servos [1, 2] still moving after 10.0 s", 3)
    done = pk.StatusPacket(1, 1.7e9, pk.RobotState.IDLE, None, 0, 0, 5, "sweep done", report=pk.StatusReport(
        sweep=pk.SweepReport(4, active=False, measured=2, skipped=pk.Kept((), 1), missing=pk.Kept((gone,)))))
    snap.note_status(pk.decode(pk.encode(done)), 12.0)
    js = snap.to_json(12.0)["sweep"]
    assert js["missing"] == [{"index": 2, "elevation": 60.0, "azimuth": 0.0, "tries": 3,
                              "reason": "settle failed: servos [1, 2] still moving after 10.0 s"}]
    assert js["grid"]["cells"] == "dds" and js["grid"]["reasons"] == {"2,0": gone.reason}
    lines = summary(snap.to_json(12.0)).splitlines()
    assert "sweep 4 done: 2 measured, 1 missing" in lines
    assert "  missing 60.0°/0.0° after 3 tries: settle failed: servos [1, 2] still moving after 10.0 s" in lines


def test_a_gray_photographs_histograms_carry_its_measured_levels(host, tmp_path):
    """An ingested one-band photograph: the page draws its measured histogram under the curves,
    as the report does (once only rgb captures had one)."""
    folder, masks = tmp_path / "photos", tmp_path / "masks"
    folder.mkdir(), masks.mkdir()
    image = skdata.text()
    write_image(folder / "text.png", image)
    write_mask(masks / "text.png", (image > 100).astype(np.uint8))
    db = tmp_path / "g.db"
    assert host("ingest", folder, "--layout", "folder", "--mask", masks, "--db", db, "--workers", 0, "--quiet")[0] == 0
    with Store.open(db) as store:
        (cap,) = store.captures()
        mask = capture_mask(store, cap)
        models = {k: m.model for k, m in store.models(cap.id).items()}
    assert cap.space == "gray" and cap.band_names == ("Y",)
    drawn = render(str(db), cap.id, None, "histograms", 0)["png"]
    assert drawn == histogram_png(read_image(folder / "text.png"), mask, models, cap.band_names, cap.levels)
    assert drawn != histogram_png(None, mask, models, cap.band_names, cap.levels)


def test_an_unmasked_photographs_histograms_are_drawn_over_its_whole_frame(host, tmp_path):
    """An ingest without --mask is one region, the whole frame: the section keeps the histograms'
    place, and the page draws them there as the report does (it once answered 404)."""
    folder = tmp_path / "photos"
    folder.mkdir()
    image = skdata.camera()[::4, ::4]
    write_image(folder / "camera.png", image)
    db = tmp_path / "u.db"
    assert host("ingest", folder, "--layout", "folder", "--db", db, "--workers", 0, "--quiet")[0] == 0
    with Store.open(db) as store:
        (cap,) = store.captures()
        models = {k: m.model for k, m in store.models(cap.id).items()}
    assert "histograms.png" in render(str(db), cap.id, None, "section", 0)["html"]
    drawn = render(str(db), cap.id, None, "histograms", 0)["png"]
    whole = np.zeros(image.shape, np.uint8)
    assert drawn == histogram_png(image[..., None], whole, models, cap.band_names, cap.levels)
    assert drawn != histogram_png(None, whole, models, cap.band_names, cap.levels)  # its measured bars


@pytest.mark.parametrize("space", ["pca", "hsv"])
def test_hsv_and_pca_captures_have_a_picture_on_their_card_and_in_their_section(host, tmp_path, space):
    """Their syntheses turned back into RGB, in the photograph's colours."""
    db, photo, labels = stored_plate(host, tmp_path, space)
    with Store.open(db) as store:
        (cap,) = store.captures()
    thumb = render(str(db), cap.id, None, "thumb", 0)
    section = render(str(db), cap.id, None, "section", 0)
    assert set(section["images"]) == {"independent", "correlated"} and "missing" not in thumb
    assert thumb["png"] == section["images"]["correlated"]
    for name, data in section["images"].items():
        image = cv2.imdecode(np.frombuffer(data, np.uint8), cv2.IMREAD_COLOR)[:, :, ::-1]
        for label in np.unique(labels):
            region = labels == label
            assert np.abs(image[region].mean(0) - photo[region].mean(0)).max() < 10, (name, label)
