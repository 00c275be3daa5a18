"""The simulated radio as a pyserial port: `btfsim://?port=URL&loss=...` in front of any port."""
import os
import re
import tty

import pytest
import serial

from radio.auth import MemoryCounterStore
from radio.channel import ChannelConfig
from radio.channel_port import Cable, ChannelPort, parse_url
from radio.link import Acked, Delivered, Link
from radio.ports import FdPort, open_url
from radio.pump import LinkPump
from tools.cli import main

KEY = bytes(range(32))


def test_the_url_names_the_wrapped_port_and_the_channel():
    cfg, seed, inner = parse_url("btfsim://?port=/dev/ttyUSB0&loss=0.2&bursty=1&ber=1e-4&seed=7&latency=0")
    assert inner == "/dev/ttyUSB0" and seed == 7
    assert cfg == ChannelConfig(loss=0.2, bursty=True, ber=1e-4, latency=0.0)
    assert parse_url("btfsim://?loss=0.1")[2] == "loop://"
    # An inner URL with its own options keeps them (its & written %26).
    assert parse_url("btfsim://?loss=0.1&port=socket://h:7%26logging=debug")[2] == "socket://h:7&logging=debug"


@pytest.mark.parametrize("url, words", [
    ("btfsim://?los=0.2", "unknown option 'los'"),
    ("btfsim://?loss=lots", "loss='lots' is not a valid value"),
    ("btfsim://?loss=1.5", "loss 1.5 outside [0, 1)"),
    ("btfsim://?port=btfsim://", "port= must name the port to wrap"),
])
def test_a_bad_url_is_refused_naming_the_option(url, words):
    with pytest.raises(serial.SerialException, match=re.escape(words)):
        open_url(url)


def test_the_host_commands_refuse_a_bad_lossy_url_with_one_line(tmp_path, capsys):
    from radio.keys import write_key

    key = write_key(tmp_path / "link.key")
    assert main(["cmd", "--port", "btfsim://?loss=2", "--key", str(key), "--db", str(tmp_path / "h.db"),
                 "status"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "loss 2.0 outside [0, 1)" in err


def test_two_links_over_a_real_pty_through_the_lossy_url():
    master, slave = os.openpty()
    tty.setraw(master)
    tty.setraw(slave)
    port = open_url(f"btfsim://?port={os.ttyname(slave)}&loss=0.2&ber=1e-4&seed=3&latency=0.002",
                    timeout=0.005)
    assert isinstance(port, ChannelPort)
    robot = LinkPump(Link(1, 0, 5, KEY, MemoryCounterStore()), port)
    host = LinkPump(Link(0, 1, 5, KEY, MemoryCounterStore()), FdPort(master, timeout=0.005))
    msgs = [os.urandom(150 + i) for i in range(30)]
    for i, m in enumerate(msgs):
        robot.send(m, msg_id=i + 1)
    got, acked = [], set()
    try:
        for _ in range(5000):
            got += [e.payload for e in host.step() if isinstance(e, Delivered)]
            acked |= {e.msg_id for e in robot.step() if isinstance(e, Acked)}
            if len(acked) == len(msgs):
                break
    finally:
        robot.close()
        host.close()
    assert got == msgs and acked == set(range(1, 31))
    assert port.outgoing.lost + port.incoming.lost > 0  # frames were lost, and resent
    assert robot.stats().retransmissions + host.stats().retransmissions > 0


def test_a_cable_paces_its_writer_to_the_radio():
    t = [0.0]
    cable = Cable(ChannelConfig(bandwidth=1000.0, latency=0.0), clock=lambda: t[0])
    a, b = cable.ends
    a.write(b"\x00" + b"\x01" * 98 + b"\x00")  # 100 bytes: 0.1 s on the air
    assert a.out_waiting == 100 and b.read(1000) == b""
    t[0] = 0.05
    assert a.out_waiting == 50
    pump = LinkPump(Link(1, 0, 5, KEY, MemoryCounterStore()), a, lambda: t[0], max_write=60)
    assert pump.room() == 10
    t[0] = 0.1
    assert len(b.read(1000)) == 100 and pump.room() == 60
