"""The page under hostile clients never stops the station: with the common limit of 1024 file
descriptors, slow connections past the page's cap are refused at once and the rest time out,
thousands of event streams are refused past their caps with the station's memory and `cmd ping`
unharmed, a request naming another host is refused (DNS rebinding), and a request with a header
or an address of 1 MiB is one counted line, never a traceback."""
import http.client
import os
import re
import resource
from collections import Counter
from urllib.parse import urlsplit

import pytest

from benchmarks.hostile_clients import (
    FD_LIMIT, event_streams, half_requests, limit_fds, median_ping_s, room_for_sockets, rss_kb, until)
from tests.support.browser import page_address
from tests.support.station_rig import Rig
from tools.page.guard import HEADER_TIMEOUT_S, connection_cap
from tools.page.server import STREAMS, STREAMS_PER_CLIENT
from tools.station.control import socket_path


@pytest.fixture
def many_sockets():
    """Room in this process for thousands of client sockets."""
    before = room_for_sockets(2100)
    if before is None:
        pytest.skip("this process may not open the 2,100 sockets the clients need")
    yield
    resource.setrlimit(resource.RLIMIT_NOFILE, before)


@pytest.fixture
def station(tmp_path):
    """A robot waiting for commands and its station with the page, at 1024 descriptors."""
    rig = Rig(tmp_path)
    robot = rig.robot()
    proc = rig.station("--http", "127.0.0.1:0", preexec_fn=limit_fds)
    url = urlsplit(page_address(tmp_path / f"station-{rig.stations}.err"))
    rig.wait_up(proc)
    assert rig.cmd("ping")[0] == 0  # the link is up
    yield rig, proc, url
    rig.stop(proc)
    rig.stop(robot)
    rig.close()


def stderr_of(rig) -> str:
    return (rig.where / f"station-{rig.stations}.err").read_text()


def test_slow_connections_past_the_cap_are_refused_at_once_the_rest_time_out_and_ping_stays_fast(
        station, many_sockets):
    rig, proc, url = station
    cap = connection_cap(FD_LIMIT)
    clients = []
    try:
        clients = half_requests((url.hostname, url.port), url.netloc, cap + 200)
        states = lambda: Counter(c.state() for c in clients)  # noqa: E731
        assert until(lambda: states()["refused"] >= 200, 60)
        assert states() == {"open": cap, "refused": 200}  # the flood is in place
        assert median_ping_s(socket_path(rig.db)) < 1.0
        code, (answer,), err = rig.cmd("ping")
        assert code == 0 and answer["ok"], err
        # half-sent headers do not hold a connection: every one is closed by the station
        assert until(lambda: states() == {"refused": cap + 200}, HEADER_TIMEOUT_S + 60)
    finally:
        for c in clients:
            c.close()
    assert proc.poll() is None
    err = stderr_of(rig)
    assert "Too many open files" not in err and "Traceback" not in err
    said = [e["text"] for e in rig.log() if e["kind"] == "station" and e["text"].startswith("page: ")]
    assert any(t.startswith(f"page: connections refused past its most of {cap} open: ") for t in said), said
    assert any(t.startswith("page: connections closed, no whole request within") for t in said), said


def flood_streams(rig, proc, url, streams: int, sources: int) -> None:
    idle = rss_kb(proc.pid)
    flood = []
    try:
        flood = event_streams((url.hostname, url.port), url.netloc, url.query.removeprefix("token="), streams,
                              sources)
        assert until(lambda: all(c.state() != "open" for c in flood), 60)
        # at most STREAMS streams, at most STREAMS_PER_CLIENT from one address; the rest refused
        streaming = Counter(c.source for c in flood if c.state() == "200")
        assert sum(streaming.values()) == STREAMS and max(streaming.values()) <= STREAMS_PER_CLIENT, streaming
        assert {c.state() for c in flood} == {"200", "refused"}
        assert median_ping_s(socket_path(rig.db)) < 1.0
        assert rss_kb(proc.pid) < 2 * idle, (rss_kb(proc.pid), idle)
    finally:
        for c in flood:
            c.close()
    assert proc.poll() is None and "Traceback" not in stderr_of(rig)


def test_event_streams_past_their_caps_are_refused_and_memory_and_ping_hold(station, many_sockets):
    rig, proc, url = station
    flood_streams(rig, proc, url, streams=200, sources=8)

    def opens() -> bool:
        conn = http.client.HTTPConnection(url.hostname, url.port, timeout=30)
        try:
            conn.request("GET", "/events", headers={"X-BTF-Token": url.query.removeprefix("token=")})
            return conn.getresponse().status == 200
        finally:
            conn.close()

    assert until(opens, 30)  # once the station has seen the flood's streams closed, a page opens again


@pytest.mark.slow
@pytest.mark.skipif(not os.environ.get("BTF_STRESS"), reason="stress run only (make stress)")
def test_two_thousand_event_streams_leave_the_station_its_memory_and_ping(station, many_sockets):
    rig, proc, url = station
    flood_streams(rig, proc, url, streams=2000, sources=20)


def request(url, path: str, headers: dict) -> tuple[int, bytes]:
    conn = http.client.HTTPConnection(url.hostname, url.port, timeout=30)
    try:
        conn.putrequest("GET", path, skip_host=True)
        for k, v in headers.items():
            conn.putheader(k, v)
        conn.endheaders()
        resp = conn.getresponse()
        return resp.status, resp.read()
    finally:
        conn.close()


def test_a_request_naming_another_host_is_refused_and_an_http_host_name_is_served(tmp_path):
    rig = Rig(tmp_path)
    try:
        rig.station("--http", "127.0.0.1:0", "--http-public", "--http-host", "station.local")
        url = urlsplit(page_address(tmp_path / f"station-{rig.stations}.err"))
        for host in (url.netloc, f"localhost:{url.port}", f"station.local:{url.port}"):
            assert request(url, "/api/state", {"Host": host})[0] == 200, host
        status, body = request(url, "/api/state", {"Host": f"evil.example:{url.port}"})
        assert status == 403 and len(body.decode().strip().splitlines()) == 1
        assert b"is not this page's address" in body and b"--http-host" in body
    finally:
        rig.close()


def test_a_header_or_an_address_of_a_mebibyte_is_refused_in_one_counted_line_never_a_traceback(tmp_path):
    rig = Rig(tmp_path)
    try:
        proc = rig.station("--http", "127.0.0.1:0", "--http-public")
        url = urlsplit(page_address(tmp_path / f"station-{rig.stations}.err"))
        huge = "x" * (1 << 20)
        for _ in range(5):
            assert request(url, "/api/state", {"Host": url.netloc, "X-Huge": huge})[0] == 400
            assert request(url, f"/{huge}", {"Host": url.netloc})[0] == 400
        assert request(url, "/api/state", {"Host": url.netloc})[0] == 200  # and it serves on
        said = lambda: [e["text"] for e in rig.log() if e["text"].startswith("page: bad requests refused: ")]  # noqa: E731
        assert until(lambda: any("(10 since the start)" in t for t in said()), 30), said()  # each counted
        assert len(said()) < 10 and all(re.search(r": \d+ \(\d+ since the start\); the last: \S", t) for t in said())
        assert proc.poll() is None and "Traceback" not in stderr_of(rig)
    finally:
        rig.close()
