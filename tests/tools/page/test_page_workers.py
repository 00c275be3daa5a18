"""The page's worker processes end with their station, even one killed before they were ready."""
import os
from pathlib import Path

from benchmarks.hostile_clients import until
from tests.support.browser import page_address
from tests.support.station_rig import Rig, kill9
from tools.page import data, drawing


def children(pid: int) -> list[int]:
    out = []
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:  # ended meanwhile
            continue
        if int(fields[1]) == pid:
            out.append(int(stat.parent.name))
    return out


def test_the_pages_workers_end_with_a_station_killed_before_they_were_ready(tmp_path):
    rig = Rig(tmp_path)
    try:
        station = rig.station("--http", "127.0.0.1:0")
        page_address(tmp_path / f"station-{rig.stations}.err")  # its workers are starting now
        workers = children(station.pid)
        kill9(station)
        assert workers and until(lambda: not any(os.path.exists(f"/proc/{p}") for p in workers), 60), workers
    finally:
        rig.close()


def test_a_drawing_worker_warms_up_by_drawing_one_plot(monkeypatch):
    """The warm-up draws a plot as a request would; a failure there would be swallowed by the pool
    and the first operator to click a capture would wait for matplotlib instead."""
    drawn = []
    real = drawing.histogram_png
    monkeypatch.setattr(drawing, "histogram_png", lambda *a, **k: drawn.append(real(*a, **k)))
    data._warm()
    assert drawn and drawn[0].startswith(b"\x89PNG")


def libraries(pid: int) -> set[str]:
    """Which of the drawing libraries the process has loaded (their compiled modules mapped)."""
    try:
        maps = Path(f"/proc/{pid}/maps").read_text()
    except OSError:  # ended meanwhile
        return set()
    return {lib for lib in ("scipy", "cv2", "matplotlib") if f"/{lib}/" in maps}


def test_the_station_serves_its_page_without_loading_what_only_its_workers_draw_with(tmp_path):
    """Synthesis, OpenCV and matplotlib load in the drawing workers alone: the station's own
    process, which must start fast and stay small, never maps them."""
    rig = Rig(tmp_path)
    try:
        station = rig.station("--http", "127.0.0.1:0")
        page_address(tmp_path / f"station-{rig.stations}.err")
        assert until(lambda: any(libraries(p) == {"scipy", "cv2", "matplotlib"} for p in children(station.pid)),
                     60), [libraries(p) for p in children(station.pid)]  # a worker warmed up: it drew a plot
        assert libraries(station.pid) == set()
    finally:
        rig.stop(station)
        rig.close()
