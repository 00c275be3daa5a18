"""The page's guards on their own: how many connections it holds for a descriptor limit, which
Host headers name it, --http-host names, and refusals said once a second with their counts."""
import pytest

from tools.page.guard import MAX_CONNECTIONS, RESERVED_FDS, HostCheck, Tally, connection_cap, host_name


def test_the_connection_cap_leaves_the_station_most_of_a_small_descriptor_limit():
    assert connection_cap(1024) == min(MAX_CONNECTIONS, (1024 - RESERVED_FDS) // 2) <= 1024 // 2
    assert connection_cap(256) == 64 and connection_cap(100) == 8  # a few, however low the limit
    assert connection_cap(1 << 20) == MAX_CONNECTIONS


def test_only_the_pages_own_address_and_given_names_are_served():
    local = HostCheck("127.0.0.1", ["Station.Local"])
    for host in ("127.0.0.1:8765", "127.0.0.1", "localhost:8765", "station.local:8765", None):
        assert local.refuses(host) == "", host
    for host in ("evil.example:8765", "127.0.0.1.evil.example", "10.0.0.5:8765", "[::1]:8765", "", "a b"):
        assert "is not this page's address" in local.refuses(host) and "--http-host" in local.refuses(host), host
    anywhere = HostCheck("0.0.0.0")
    assert anywhere.refuses("192.168.1.20:8765") == anywhere.refuses("[fe80::1]:80") == ""
    assert "any IP address" in anywhere.refuses("evil.example:8765")
    assert HostCheck("station.local").refuses("station.local:80") == ""


def test_an_http_host_name_is_a_bare_name_or_address():
    assert host_name("Station.Local") == "station.local" and host_name("[::1]") == "::1"
    for bad in ("station.local:80", "", "http://x", "a b", "user@x"):
        with pytest.raises(ValueError, match="expected a host name"):
            host_name(bad)


def test_refusals_are_said_once_a_second_per_kind_with_their_counts():
    said, now = [], [0.0]
    tally = Tally(said.append, lambda: now[0])
    for i in range(5):
        tally.add("page: x refused", f"client {i}")
    tally.add("page: y refused")
    assert said == ["page: x refused: 1 (1 since the start); the last: client 0", "page: y refused: 1 (1 since the start)"]
    tally.flush()
    assert len(said) == 2  # within the second: nothing more
    now[0] = 1.0
    tally.flush()
    assert said[2:] == ["page: x refused: 4 (5 since the start); the last: client 4"]
    tally.flush()
    assert len(said) == 3 and tally.counts == {"page: x refused": 5, "page: y refused": 1}
