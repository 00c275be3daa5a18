"""A robot whose camera replays image files (hal.replay): small RGB frames, a config, a sweep."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from radio import packets as pk
from tests.support.robots import robot_toml

H, W = 24, 32
ELEVATIONS = [90, 80, 70, 60, 50, 40, 30]  # the default sweep


def rgb_frame(seed: int) -> np.ndarray:
    """Two regions of distinct colour with grain, so the robot finds something to fit."""
    rng = np.random.default_rng(seed)
    img = np.empty((H, W, 3), np.float64)
    img[:, : W // 2] = (200, 120, 40)
    img[:, W // 2:] = (40, 90, 180)
    return np.clip(img + rng.normal(0, 6, img.shape), 0, 255).astype(np.uint8)


def sweep_views(image: np.ndarray, h: int, w: int, views: int = len(ELEVATIONS)) -> list[np.ndarray]:
    """A sweep's views of one scene: `image` (RGB) mirror-tiled to 2h x 2w, each view h x w panned
    a further 1/views across it and brighter, its light x0.85 .. x1.15 (as a sweep's angles catch
    more or less light)."""
    ry, rx = -(-2 * h // image.shape[0]), -(-2 * w // image.shape[1])
    row = np.concatenate([image if j % 2 == 0 else image[:, ::-1] for j in range(rx)], axis=1)
    canvas = np.concatenate([row if i % 2 == 0 else row[::-1] for i in range(ry)], axis=0).astype(np.float64)
    gains = np.linspace(0.85, 1.15, views)
    return [np.clip(canvas[k * h // views:][:h, k * w // views:][:, :w] * gains[k], 0, 255).astype(np.uint8)
            for k in range(views)]


def write_rgb(path: Path, rgb: np.ndarray) -> Path:
    assert cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    return path


def robot_text(camera: str, loop: bool, body: str = "fake", *changes: dict) -> str:
    """A robot on the `body` HAL whose camera plays files, segmenting by ISODATA into 2 classes."""
    replay = {"body": body, "size": [H, W], "scene": None, "camera": camera, "replay_loop": loop}
    return robot_toml({"hal": replay, "segment": {"method": None, "k": 2}}, *changes)


def run_sweep(fake_robot, text: str) -> tuple[list, dict[float, str]]:
    """A whole sweep: the decoded packets, and the file each capture's frame came from, by elevation."""
    rt, tr = fake_robot(text)
    sources: dict[float, str] = {}
    process = rt.pipeline.process

    def noting(frame, commanded, measured, settings=None):
        sources[commanded.elevation] = Path(settings.source).name  # the settings read with the frame
        return process(frame, commanded, measured, settings)

    rt.pipeline.process = noting
    try:
        rt.run(lambda r: r.progress is not None and r.idle())
    finally:
        rt.outbox.close()
        rt.hal.close()  # the emulated body's servo chain runs in a thread of its own
    return [pk.decode(body) for _, body in tr.sent], sources


def models(packets: list) -> list:
    return [p for p in packets if isinstance(p, pk.ModelsPacket)]


def write_shots(folder: Path) -> Path:
    """shot_1.png, shot_2.jpg, shot_10.png: 8-bit RGB; a text file the camera leaves alone."""
    folder.mkdir()
    for i in (10, 1):
        write_rgb(folder / f"shot_{i}.png", rgb_frame(i))
    write_rgb(folder / "shot_2.jpg", rgb_frame(2))
    (folder / "notes.txt").write_text("taken on the test plate")
    return folder
