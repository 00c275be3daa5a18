"""The page under hostile clients never stops the station: with the common limit of 1024 file
descriptors, slow connections past the page's cap are refused at once and the rest time out,
thousands of event streams are refused past their caps with the station's memory and `cmd ping`
unharmed, a request naming another host is refused (DNS rebinding), and a request with a header
or an address of 1 MiB is one counted line, never a traceback."""
import http.client
import os
import re
import resource
import socket
import statistics
import time
from collections import Counter
from urllib.parse import urlsplit

import pytest

from radio.packets.commands import CommandName
from tests.support.browser import page_address
from tests.support.station_rig import Rig
from tools.page.guard import HEADER_TIMEOUT_S, connection_cap
from tools.page.server import STREAMS, STREAMS_PER_CLIENT
from tools.station.control import StationClient, socket_path

FD_LIMIT = 1024


def limit_fds() -> None:
    resource.setrlimit(resource.RLIMIT_NOFILE, (FD_LIMIT, FD_LIMIT))


@pytest.fixture
def many_sockets():
    """Room in this process for thousands of client sockets."""
    soft, hard = resource.getrlimit(resource.RLIMIT_NOFILE)
    want = 4096 if hard == resource.RLIM_INFINITY else min(hard, 4096)
    if want < 2600:
        pytest.skip(f"this process may open {hard} files, too few for the clients")
    resource.setrlimit(resource.RLIMIT_NOFILE, (want, hard))
    yield
    resource.setrlimit(resource.RLIMIT_NOFILE, (soft, hard))


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


def ping_s(rig) -> float:
    """Seconds from a PING sent through the station's socket to the robot's answer."""
    client = StationClient.connect(socket_path(rig.db), timeout=30)
    assert client is not None, "the station's socket refused"
    try:
        t0 = time.perf_counter()
        client.send({"op": "command", "name": CommandName.PING.name, "args": {}})
        while (msg := client.receive(timeout=30))["op"] != "answer":
            pass
        assert msg["answer"]["ok"]
        return time.perf_counter() - t0
    finally:
        client.close()


def median_ping_s(rig, n: int = 5) -> float:
    return statistics.median(ping_s(rig) for _ in range(n))


class Client:
    """One connection of a hostile client; `state()`: open (nothing said yet), refused (a 503, or
    closed without a word), else the first line of the answer (kept: a stream goes on)."""

    def __init__(self, address: tuple[str, int], request: bytes, source: str = "127.0.0.1") -> None:
        self.source = source
        self.sock = socket.create_connection(address, timeout=30, source_address=(source, 0))
        self.sock.sendall(request)
        self.sock.setblocking(False)
        self.answer: str | None = None

    def state(self) -> str:
        if self.answer in (None, "200"):
            try:
                data = self.sock.recv(65536)
            except BlockingIOError:
                return self.answer or "open"
            except ConnectionResetError:
                data = b""
            if self.answer is None:
                self.answer = "refused" if not data or data.startswith(b"HTTP/1.1 503") else data.split(b" ")[1].decode()
            elif not data:
                self.answer = "closed"
        return self.answer


def until(predicate, limit_s: float) -> bool:
    end = time.monotonic() + limit_s
    while not predicate() and time.monotonic() < end:
        time.sleep(0.1)
    return predicate()


def stderr_of(rig) -> str:
    return (rig.where / f"station-{rig.stations}.err").read_text()


def rss_kb(pid: int) -> int:
    with open(f"/proc/{pid}/status") as fh:
        return next(int(line.split()[1]) for line in fh if line.startswith("VmRSS:"))


def test_slow_connections_past_the_cap_are_refused_at_once_the_rest_time_out_and_ping_stays_fast(
        station, many_sockets):
    rig, proc, url = station
    cap = connection_cap(FD_LIMIT)
    half = f"GET / HTTP/1.1\r\nHost: {url.netloc}\r\nX-Slow: ".encode()  # never finished
    clients = []
    try:
        for _ in range(cap + 200):
            clients.append(Client((url.hostname, url.port), half))
        states = lambda: Counter(c.state() for c in clients)  # noqa: E731
        assert until(lambda: states()["refused"] >= 200, 60)
        assert states() == {"open": cap, "refused": 200}  # the flood is in place
        assert median_ping_s(rig) < 1.0
        code, (answer,), err = rig.cmd("ping")
        assert code == 0 and answer["ok"], err
        # half-sent headers do not hold a connection: every one is closed by the station
        assert until(lambda: states() == {"refused": cap + 200}, HEADER_TIMEOUT_S + 60)
    finally:
        for c in clients:
            c.sock.close()
    assert proc.poll() is None
    err = stderr_of(rig)
    assert "Too many open files" not in err and "Traceback" not in err
    said = [e["text"] for e in rig.log() if e["kind"] == "station" and e["text"].startswith("page: ")]
    assert any(t.startswith(f"page: connections refused past its most of {cap} open: ") for t in said), said
    assert any(t.startswith("page: connections closed, no whole request within") for t in said), said


def flood_streams(rig, proc, url, token: str, streams: int, clients: int) -> None:
    idle = rss_kb(proc.pid)
    ask = f"GET /events HTTP/1.1\r\nHost: {url.netloc}\r\nX-BTF-Token: {token}\r\n\r\n".encode()
    flood = []
    try:
        for i in range(streams):
            flood.append(Client((url.hostname, url.port), ask, f"127.0.0.{2 + i % clients}"))
        assert until(lambda: all(c.state() != "open" for c in flood), 60)
        # at most STREAMS streams, at most STREAMS_PER_CLIENT from one address; the rest refused
        streaming = Counter(c.source for c in flood if c.state() == "200")
        assert sum(streaming.values()) == STREAMS and max(streaming.values()) <= STREAMS_PER_CLIENT, streaming
        assert {c.state() for c in flood} == {"200", "refused"}
        assert median_ping_s(rig) < 1.0
        assert rss_kb(proc.pid) < 2 * idle, (rss_kb(proc.pid), idle)
    finally:
        for c in flood:
            c.sock.close()
    assert proc.poll() is None and "Traceback" not in stderr_of(rig)


def test_event_streams_past_their_caps_are_refused_and_memory_and_ping_hold(station, many_sockets):
    rig, proc, url = station
    token = url.query.removeprefix("token=")
    flood_streams(rig, proc, url, token, streams=200, clients=8)

    def opens() -> bool:
        conn = http.client.HTTPConnection(url.hostname, url.port, timeout=30)
        try:
            conn.request("GET", "/events", headers={"X-BTF-Token": token})
            return conn.getresponse().status == 200
        finally:
            conn.close()

    assert until(opens, 30)  # once the station has seen the flood's streams closed, a page opens again


@pytest.mark.slow
@pytest.mark.skipif(not os.environ.get("BTF_STRESS"), reason="stress run only (make stress)")
def test_two_thousand_event_streams_leave_the_station_its_memory_and_ping(station, many_sockets):
    rig, proc, url = station
    flood_streams(rig, proc, url, url.query.removeprefix("token="), streams=2000, clients=20)


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
