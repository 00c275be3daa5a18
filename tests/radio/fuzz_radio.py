"""Coverage-guided fuzzing of everything that reads untrusted bytes (atheris, libFuzzer).

Run by `make fuzz` (outside CI's budget): `--seeds DIR` writes genuine packets, frames and
link traffic as a starting corpus, then `python tests/radio/fuzz_radio.py DIR -atheris_runs=N`.
Targets, picked by the first input byte: the packet decoder, the frame decoder, and a Link
fed raw wire bytes. Anything but radio.FrameError escaping, or a Link delivering a message
built from bytes it never authenticated, is a crash.
"""
import sys

import atheris

with atheris.instrument_imports():
    from radio import FrameError
    from radio import packets as packet
    from radio.auth import MemoryCounterStore
    from radio.frame import decode as decode_frame
    from radio.link import Delivered, Link

KEY = bytes(range(32))


def one_input(data: bytes) -> None:
    if not data:
        return
    target, body = data[0] % 3, data[1:]
    if target == 0:
        try:
            packet.decode(body)
        except FrameError:
            pass
    elif target == 1:
        try:
            decode_frame(body, KEY)
        except FrameError:
            pass
    else:
        link = Link(0, 1, 5, KEY, MemoryCounterStore(), max_message=4096)
        link.receive(body, 0.0)
        link.receive(b"\x00" + body + b"\x00", 0.1)
        events = link.pop_events()
        if any(isinstance(e, Delivered) for e in events):
            raise AssertionError("a link delivered bytes it never authenticated")
        assert link.buffered_bytes() <= 1 << 20


def write_seeds(directory: str) -> None:
    """Genuine inputs for each target, so mutations start from deep inside the decoders."""
    from pathlib import Path

    import numpy as np

    from btf.fit.fitter import FrameFitter

    rng = np.random.default_rng(0)
    fitter = FrameFitter(3, 3)
    frame = np.clip(rng.normal(120, 40, (60, 80, 3)), 0, 255).astype(np.uint8)
    fitter.add(frame, rng.integers(0, 3, (60, 80)).astype(np.uint8))
    bodies = [
        packet.encode_models(fitter.fit(), robot_id=1, seq=7, time=1.0, commanded=(60.0, 0.0),
                             measured=(60.2, 0.1), feature_space="rgb", bands=("R", "G", "B")),
        packet.encode_mask(rng.integers(0, 4, (60, 80)).astype(np.uint8), robot_id=1, seq=7),
        packet.encode(packet.CommandPacket(3, packet.CommandName.GOTO, {"elevation": 50.0, "azimuth": 0.0})),
    ]
    robot = Link(1, 0, 5, KEY, MemoryCounterStore())
    for i, body in enumerate(bodies):
        robot.send(body, 0.0, msg_id=i + 1)
    wire = robot.poll(0.0)
    out = Path(directory)
    out.mkdir(parents=True, exist_ok=True)
    for i, body in enumerate(bodies):
        (out / f"packet-{i}").write_bytes(b"\x00" + body)
    for i, frame_bytes in enumerate(f for f in wire.split(b"\x00") if f):
        (out / f"frame-{i}").write_bytes(b"\x01" + frame_bytes)
    (out / "link").write_bytes(b"\x02" + wire)


if __name__ == "__main__":
    if len(sys.argv) == 3 and sys.argv[1] == "--seeds":
        write_seeds(sys.argv[2])
    else:
        atheris.Setup(sys.argv, one_input)
        atheris.Fuzz()
