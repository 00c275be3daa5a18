"""ISODATA's scene centres on a replayed sweep: a new scene is refitted at its first view, the
same scene panned and under another light level is not."""
from __future__ import annotations

import cv2
import numpy as np
import pytest
import skimage.data

from hal.interfaces import ViewAngles
from tests.support.replay import sweep_views, write_rgb
from tests.support.robots import robot_toml

H, W = 120, 160


def _photo(name: str) -> np.ndarray:
    """A photograph shipped with scikit-image, as RGB at a quarter of its side."""
    grey = getattr(skimage.data, name)()
    small = cv2.resize(grey, None, fx=0.25, fy=0.25, interpolation=cv2.INTER_AREA)
    return np.repeat(small[..., None], 3, axis=2)


def _refits(fake_robot, tmp_path, scenes: list[str]) -> str:
    """Replay a sweep over each scene in turn at the runtime's ISODATA defaults: for each view,
    'R' where the centres were fitted, '.' where the scene's were kept; scenes apart by ' '."""
    folder = tmp_path / "views"
    folder.mkdir()
    for i, name in enumerate(scenes):
        for k, view in enumerate(sweep_views(_photo(name), H, W)):
            write_rgb(folder / f"s{i}_v{k}.png", view)
    hal = {"body": "fake", "scene": None, "size": [H, W], "camera": f"replay:{folder}", "replay_loop": False}
    rt, _ = fake_robot(robot_toml({"hal": hal, "segment": {"method": "isodata"}}))
    segmenter = rt.pipeline.segmenter.segmenter
    marks = []
    try:
        for k in range(len(scenes) * 7):
            before = segmenter.refits
            pose = ViewAngles(90.0 - 10 * (k % 7), 0.0)
            rt.pipeline.shoot(pose, pose)
            marks.append("R" if segmenter.refits > before else ".")
    finally:
        rt.outbox.close()
        rt.hal.close()
    return " ".join("".join(marks[i:i + 7]) for i in range(0, len(marks), 7))


@pytest.mark.parametrize("scenes", [["grass", "moon"], ["gravel", "moon"]])
def test_a_new_scene_is_refitted_at_its_first_view_and_a_panned_brighter_one_is_not(fake_robot, tmp_path, scenes):
    # The old scene's centres cover the new one's grey levels about as well as its own would,
    # so the mean distance to them hardly grows: the new scene shows as the sample moving.
    assert _refits(fake_robot, tmp_path, scenes) == "R...... R......"
