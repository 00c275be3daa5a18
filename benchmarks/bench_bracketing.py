"""Bracketing: time per pose and the clipped regions' error, with and without it, on the fake
scenes in bright sun (the camera locked at 40 ms, four times the light the renderer's 10 ms
reference fills: the field's tan sand and gravel, the white plate and the brightest grains of
the black plate clip).

A pose here is `Pipeline.shoot` at a pose the arm already holds (each pipeline's fake arm is
moved there first, untimed): the frame (the fake camera
renders it), features, segmentation, the fit and, with bracketing, the shorter exposures. The
arm's move is the same with and without and is left out. The error is `benchmarks.clipped_truth`'s:
the mean quantile error over the probability mass the clip hid, against the unclipped truth,
over the regions with more than 20% of a band clipped.
"""
from __future__ import annotations

import numpy as np

from benchmarks.clipped_truth import hidden_error, host_models, robot_pipeline, unclipped
from benchmarks.common import Context, Section, paired_rounds
from hal.interfaces import ViewAngles

BRIGHT_SUN_US = 40_000.0
LIMIT = 0.2
ELEVATIONS = (90.0, 80.0, 70.0, 60.0, 50.0, 40.0, 30.0)


def _scene_row(scene: str, size: tuple[int, int], rounds: int, elevations: tuple[float, ...]) -> tuple[str, dict]:
    plain = robot_pipeline(scene, size, BRIGHT_SUN_US, 0.0)
    brack = robot_pipeline(scene, size, BRIGHT_SUN_US, LIMIT)
    views = [ViewAngles(e) for e in elevations]
    per_pose = {"plain": 0.0, "bracketed": 0.0}
    before, after, frames, regions = [], [], 0, 0
    for v in views:
        plain.move(v)  # each pipeline's own fake arm; the move is not timed
        brack.move(v)
        times = paired_rounds({"plain": lambda: plain.shoot(v, v), "bracketed": lambda: brack.shoot(v, v)}, rounds)
        for k, t in times.items():
            per_pose[k] += float(np.median(t)) / len(views)
        cap_plain, cap_brack = plain.shoot(v, v), brack.shoot(v, v)
        frames += len(cap_brack.camera.brackets)
        regions += len(cap_brack.camera.bracketed)
        truth, mask = unclipped(scene, v, size, BRIGHT_SUN_US)
        for label in sorted({lab for lab, _ in cap_plain.results}):
            if max(cap_plain.results[(label, b)].censored_high for b in range(3)) > LIMIT:
                before.append(hidden_error(host_models(cap_plain), truth, mask, label))
                after.append(hidden_error(host_models(cap_brack), truth, mask, label))
    err = (f"{np.mean(before):.2f} → {np.mean(after):.2f} ({len(before)} regions)" if before else "no region clips")
    row = (f"| {scene} | {size[1]}x{size[0]} | {per_pose['plain'] * 1e3:.0f} ms | {per_pose['bracketed'] * 1e3:.0f} ms "
           f"| {per_pose['bracketed'] / per_pose['plain']:.2f}x | {frames / len(views):.2f} | "
           f"{regions / len(views):.2f} | {err} |")
    return row, {"before": before, "after": after}


def run(ctx: Context) -> list[Section]:
    size = ctx.pick((120, 160), (48, 64))
    rounds = ctx.pick(5, 1)
    elevations = ctx.pick(ELEVATIONS, (90.0, 50.0))
    lines = ["| scene | frame | time per pose, censoring alone | with bracketing | ratio | extra frames per pose "
             "| regions bracketed per pose | hidden-quantile error (levels) |",
             "|---|---|---:|---:|---:|---:|---:|---|"]
    errors: dict[str, dict] = {}
    for scene in ("field", "white", "black"):
        row, errors[scene] = _scene_row(scene, size, rounds, elevations)
        lines.append(row)
    lines += ["", f"Bright sun: the camera locked at {BRIGHT_SUN_US / 1e3:.0f} ms (gain 1, 5500 K); "
              f"`[camera] bracket_limit = {LIMIT}`, `bracket_max = 2`. Time per pose: the median of "
              f"{rounds} paired rounds over {len(elevations)} elevations at azimuth 0, the fake camera's "
              "rendering included (`Context: fake scene rendering`)."]
    return [Section("Bracketing: time per pose and error in bright sun (fake scenes)", lines)]
