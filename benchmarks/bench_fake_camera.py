"""The fake camera's frame against the robot's own work on it, at 1 MP and 5 MP.

A test or the demo times the robot's code only when the simulator costs less than it. The
frame is `FakeCamera.capture` on the field scene with the grey reference card, a new view
each frame (the plate's surface built before timing; its first build is reported apart);
the robot's work is `Pipeline.process` on that frame with ISODATA scene centres, the fit,
dependence and the MODELS body (what one pose costs beside moving the arm). Best of paired
rounds, so load from other processes hits both alike.
"""
from __future__ import annotations

import itertools
import tempfile
import time
from pathlib import Path

from benchmarks.common import Context, Section, paired_times
from btf.fit.isodata import IsodataParams
from hal.fakes.camera import FakeCamera
from hal.interfaces import ViewAngles
from onboard import config
from onboard.capture.pipeline import Pipeline
from onboard.capture.segmentation import Segmenter, SegmentMethod
from onboard.link.bodies import models_body

SIZES = {"1 MP": (1000, 1000), "5 MP": (1944, 2592)}


def _pose(frame, view: ViewAngles) -> Pipeline:
    d = Path(tempfile.mkdtemp(prefix="btf-bench-"))
    (d / "r.toml").write_text('[hal]\nbody = "fake"\n')
    seg = Segmenter(SegmentMethod.ISODATA, n_labels=16, isodata=IsodataParams(k=4, subsample=20000))
    pipe = Pipeline(config.load(d / "r.toml"), None, lambda feats, fr, m: (seg.labels_for(feats), seg.changed))
    pipe.process(frame, view, view)  # the scene's centres, once
    return pipe


def measure(size: tuple[int, int], repeat: int) -> dict[str, float]:
    """Seconds: the first frame (builds the plate), a later frame, the robot's work on one."""
    views = itertools.cycle([ViewAngles(60.0, az) for az in range(0, 360, 15)])
    current = [next(views)]
    camera = FakeCamera("field", lambda: current[0], seed=7, size=size, reference=True)
    camera.open(size[1], size[0])
    t0 = time.perf_counter()
    frame = camera.capture()
    first = time.perf_counter() - t0
    pipe = _pose(frame, current[0])

    def capture() -> None:
        current[0] = next(views)
        camera.capture()

    def pose() -> None:
        models_body(1, 1, 0.0, "rgb", pipe.process(frame, current[0], current[0]))

    best = paired_times({"frame": capture, "pose": pose}, repeat)
    return {"first": first, **best}


def run(ctx: Context) -> list[Section]:
    sizes = ctx.pick(SIZES, {"tiny": (48, 64)})
    repeat = ctx.pick(7, 1)
    lines = ["| frame | fake camera frame | robot's work on it | frame / work | first frame (builds the plate) |",
             "|---|---:|---:|---:|---:|"]
    for name, (h, w) in sizes.items():
        t = measure((h, w), repeat)
        lines.append(f"| {name} ({w}x{h}) | {t['frame'] * 1e3:.0f} ms | {t['pose'] * 1e3:.0f} ms | "
                     f"{t['frame'] / t['pose']:.2f} | {t['first'] * 1e3:.0f} ms |")
    lines += ["", f"Field scene with the grey card, 60 degrees, a new azimuth each frame; best of {repeat} "
              "paired rounds. The robot's work: features, ISODATA with the scene's centres, the fit, "
              "dependence and the MODELS body."]
    return [Section("Fake camera: a frame against the robot's work on it", lines)]


if __name__ == "__main__":
    print("\n".join(run(Context())[0].markdown()))
