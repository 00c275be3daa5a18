"""The channel simulator as ports, so any link can run through a seeded lossy radio.

`Cable` joins two ends: what one end writes crosses its own `radio.channel.Channel` (loss,
bit errors, duplication, reordering, latency, bandwidth) to the other, on the cable's clock.
`linktest` runs two links over the ends of one cable on a simulated clock.

`ChannelPort` is a pyserial port that puts a cable in front of another port: its own end is
what the link writes to and reads from, and the far end is bridged to the wrapped port. It is
the `btfsim://` URL handler (`radio/urlhandler/protocol_btfsim.py`)::

    btfsim://?port=/dev/ttyUSB0&loss=0.2&bursty=1&ber=1e-4&seed=1

`port` is the wrapped port's URL (a device, pty path, `loop://`, `socket://...`; an `&` inside
it is written `%26`); the other options are `ChannelConfig`'s fields and `seed`. A bare
`btfsim://?loss=0.2` wraps `loop://`. The port's outgoing channel is seeded `seed + 1`, its
incoming one `seed`. Bytes cross only while the port is used (read, write, in_waiting): the
link pump does that every step.
"""
from __future__ import annotations

import dataclasses
import time
import urllib.parse
from typing import Any, Callable

from serial import SerialBase, SerialException

from radio.channel import Channel, ChannelConfig
from radio.ports import PortBusy, open_url

SLICE = 0.002  # seconds a read waits on the wrapped port before it looks at the channel again
Tap = Callable[[str, bytes], None]  # ("out", bytes this end wrote) / ("in", bytes from the far port)


class CableEnd:
    """One end of a `Cable`: a non-blocking port (read returns what has arrived by now)."""

    timeout = 0.0

    def __init__(self, outgoing: Channel, incoming: Channel, clock: Callable[[], float]) -> None:
        self.outgoing, self.incoming, self.clock = outgoing, incoming, clock
        self._rx = bytearray()

    def _take(self) -> None:
        self._rx += self.incoming.deliver(self.clock())

    @property
    def in_waiting(self) -> int:
        self._take()
        return len(self._rx)

    @property
    def out_waiting(self) -> int:
        """Bytes written and not yet on the air."""
        return self.outgoing.backlog(self.clock())

    def read(self, size: int = 1) -> bytes:
        self._take()
        data = bytes(self._rx[:size])
        del self._rx[:size]
        return data

    def write(self, data: bytes) -> int:
        self.outgoing.transmit(bytes(data), self.clock())
        return len(data)

    def close(self) -> None:
        pass


class Cable:
    """Two `CableEnd`s joined by a simulated radio, one seeded channel per direction."""

    def __init__(self, config: ChannelConfig, seeds: tuple[int, int] = (0, 1),
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.channels = (Channel(config, seeds[0]), Channel(config, seeds[1]))  # a->b, b->a
        self.ends = (CableEnd(self.channels[0], self.channels[1], clock),
                     CableEnd(self.channels[1], self.channels[0], clock))


class ChannelPort(SerialBase):
    """A pyserial port whose bytes cross a seeded lossy radio to and from a wrapped port."""

    OPTIONS = ("port", "seed", *(f.name for f in dataclasses.fields(ChannelConfig)))

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self.inner: Any = None
        self.cable: Cable | None = None
        self.tap: Tap | None = None
        super().__init__(*args, **kwargs)

    @classmethod
    def over(cls, inner: Any, config: ChannelConfig, seed: int = 0, tap: Tap | None = None,
             clock: Callable[[], float] = time.monotonic, timeout: float | None = 0.0) -> "ChannelPort":
        """A port wrapping an already open one (e.g. a pty master, which has no URL)."""
        port = cls(timeout=timeout)
        port._attach(inner, config, seed, clock)
        port.tap = tap
        port.is_open = True
        return port

    def _attach(self, inner: Any, config: ChannelConfig, seed: int, clock: Callable[[], float]) -> None:
        inner.timeout = SLICE
        self.inner, self.cable = inner, Cable(config, (seed + 1, seed), clock)

    # -- pyserial's port interface ------------------------------------------------------
    def open(self) -> None:
        if self.is_open:
            raise SerialException("port is already open")
        config, seed, inner_url = parse_url(self.portstr)

        try:
            inner = open_url(inner_url, self._baudrate, timeout=SLICE, exclusive=bool(self._exclusive))
        except PortBusy:
            raise
        except (SerialException, ValueError, OSError) as exc:
            raise SerialException(f"btfsim: the wrapped port {inner_url}: {exc}") from None
        self._attach(inner, config, seed, time.monotonic)
        self.is_open = True

    def close(self) -> None:
        if self.is_open and self.inner is not None:
            self.inner.close()
        self.is_open = False

    def _reconfigure_port(self, *args: Any, **kwargs: Any) -> None:
        pass  # baud rate and the like mean nothing to the simulated radio

    @property
    def near(self) -> CableEnd:
        return self.cable.ends[0]

    @property
    def outgoing(self) -> Channel:
        """The channel this port's writes cross (its loss and error counts)."""
        return self.cable.channels[0]

    @property
    def incoming(self) -> Channel:
        """The channel the wrapped port's bytes cross on their way to this port's reads."""
        return self.cable.channels[1]

    @property
    def in_waiting(self) -> int:
        self._service(block=False)
        return self.near.in_waiting

    @property
    def out_waiting(self) -> int:
        return self.near.out_waiting

    def read(self, size: int = 1) -> bytes:
        end = None if self._timeout is None else time.monotonic() + self._timeout
        while True:
            self._service(block=False)
            data = self.near.read(size)
            if data or (end is not None and time.monotonic() >= end):
                return data
            self._service(block=True)

    def write(self, data: bytes) -> int:
        data = bytes(data)
        if self.tap is not None:
            self.tap("out", data)
        self.near.write(data)
        self._service(block=False)
        return len(data)

    def reset_input_buffer(self) -> None:
        self.near.read(1 << 30)

    def reset_output_buffer(self) -> None:
        pass  # what is on the air stays there

    def _service(self, block: bool) -> None:
        """Hand what crossed the channel to the wrapped port; put what it sent on the air.
        With `block`, wait up to SLICE for the wrapped port to send something."""
        far = self.cable.ends[1]
        arrived = far.read(1 << 30)
        if arrived:
            self.inner.write(arrived)
        waiting = self.inner.in_waiting
        if waiting or block:
            data = self.inner.read(max(waiting, 1))
            if data:
                if self.tap is not None:
                    self.tap("in", data)
                far.write(data)


def parse_url(url: str) -> tuple[ChannelConfig, int, str]:
    """(channel config, seed, wrapped port URL) of a `btfsim://?...` URL; SerialException
    naming the option for anything wrong."""
    parts = urllib.parse.urlsplit(url)
    if parts.scheme != "btfsim":
        raise SerialException(f"expected a btfsim://?port=URL&loss=... URL, got {url!r}")
    kinds = {f.name: f.type for f in dataclasses.fields(ChannelConfig)}
    values: dict[str, Any] = {}
    seed, inner = 0, "loop://"
    for name, text in urllib.parse.parse_qsl(parts.query, keep_blank_values=True):
        if name not in ChannelPort.OPTIONS:
            raise SerialException(f"btfsim: unknown option {name!r} (known: {', '.join(ChannelPort.OPTIONS)})")
        if name == "port":
            inner = text
            continue
        try:
            if name == "seed":
                seed = int(text)
            elif kinds[name] in (bool, "bool"):
                values[name] = _flag(text)
            elif kinds[name] in (int, "int"):
                values[name] = int(text)
            else:
                values[name] = float(text)
        except ValueError:
            raise SerialException(f"btfsim: {name}={text!r} is not a valid value") from None
    if not inner or inner.lower().startswith("btfsim:"):
        raise SerialException("btfsim: port= must name the port to wrap (a device, pty path, loop://, socket://)")
    try:
        return ChannelConfig(**values), seed, inner
    except ValueError as exc:
        raise SerialException(f"btfsim: {exc}") from None


def _flag(text: str) -> bool:
    low = text.strip().lower()
    if low in ("1", "true", "yes", "on", ""):
        return True
    if low in ("0", "false", "no", "off"):
        return False
    raise ValueError(text)
