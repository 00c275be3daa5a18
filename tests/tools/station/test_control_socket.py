"""The control socket across a restart: the killed station's socket file stays until the new
one is renamed over it, so a `cmd` waiting for the next station never finds no file and gives up."""
import asyncio
import os
import socket
import stat

from tools.station import control


def test_a_restarting_station_replaces_a_stale_socket_with_no_moment_without_a_file(tmp_path, monkeypatch):
    path = tmp_path / "scene.db.sock"
    stale = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    stale.bind(str(path))
    stale.close()  # what a station killed with -9 leaves behind
    assert control.StationClient.connect(path, timeout=1) is None
    there_at_bind = []

    class Watched(socket.socket):
        def bind(self, address):
            if self.family == socket.AF_UNIX:
                there_at_bind.append(path.exists())
            super().bind(address)

    monkeypatch.setattr(control.socket, "socket", Watched)
    server = control.ControlServer(None, path)

    async def start_and_connect():
        await server.start()
        client = await asyncio.to_thread(control.StationClient.connect, path, 1)
        try:
            return client is not None
        finally:
            if client is not None:
                client.close()
            await server.close()

    assert asyncio.run(start_and_connect())
    assert there_at_bind == [True]  # the old file was still there while the new socket was bound
    assert not path.exists() and not list(tmp_path.iterdir())  # closed: nothing left, no temporary


def test_the_replaced_socket_is_private(tmp_path):
    path = tmp_path / "scene.db.sock"
    path.write_bytes(b"")  # any stale file
    server = control.ControlServer(None, path)

    async def mode():
        await server.start()
        try:
            return os.stat(path).st_mode
        finally:
            await server.close()

    got = asyncio.run(mode())
    assert stat.S_ISSOCK(got) and stat.S_IMODE(got) == 0o600
