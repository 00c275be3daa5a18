"""The robot's pose by step on replayed photographs, against the numpy floor of its histograms.

Photographs shipped in public packages (scikit-image's data and matplotlib's sample data; the
tests use none of these) are mirror-tiled to 640x480, 1 MP and 5 MP frames in a temporary
folder and replayed through the replay camera (`[hal] camera = "replay:DIR"`) into the robot's
own pipeline at the runtime defaults of examples/robot.toml (ISODATA, dependence on, 16 labels).
Each step is timed by the robot's own per-pose instrument (`PoseTiming`: features,
segmentation, fit, dependence; encode is the MODELS and MASK bodies, as `Captures.packets`
makes them) and set against the floor of that frame's histograms: per band one `np.bincount`
of label * 256 + level (the label part built once, outside the timing), the least numpy does
to count what the fit reads. Rounds interleave the pose, the floor and the fitter's own add +
fit, each keeping its best, so load from other processes hits all alike. The dependence pass
is `btf.fit.dependence` as it stands on this branch, reported on its own line.

The sweep: seven views of each photograph, panned across it and brighter view by view (x0.85
to x1.15, as a sweep's angles catch more or less light), replayed in order; how often ISODATA
fits its centres again. Memory: `btf-robot run --log-json` itself on a 5 MP sweep, its peak
resident set (the kernel's high-water mark, read after each pose), and its own per-pose log lines.
"""
from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import cv2
import numpy as np

from benchmarks.common import Context, Section, verdict
from benchmarks.photo_cases import load
from btf.fit.fitter import FrameFitter
from hal.factory import build_hal
from hal.interfaces import ViewAngles
from onboard import config
from onboard.capture.pipeline import Pipeline, PoseTiming
from onboard.capture.segmentation import Segmentation
from onboard.link.bodies import mask_body, models_body
from radio.keys import write_key

PHOTOS = ("rocket", "chelsea", "astronaut", "motorcycle", "grace_hopper")
SIZES = {"640x480": (480, 640), "1 MP": (1000, 1000), "5 MP": (1944, 2592)}
VIEWS = 7  # a sweep's poses over one scene
# (frame, figure, limit): the whole pose and add + fit against the floor, dependence against the fit
TARGETS = (("1 MP", "pose", 6.0), ("5 MP", "pose", 3.5), ("1 MP", "dependence / fit", 1.0),
           ("1 MP", "add+fit", 1.25), ("640x480", "add+fit", 1.8))
STEPS = PoseTiming.STEPS


def tiled(image: np.ndarray, h: int, w: int) -> np.ndarray:
    """`image` mirror-tiled to at least h x w (edges meet their mirror images), cut to h x w."""
    ry, rx = -(-h // image.shape[0]), -(-w // image.shape[1])
    row = np.concatenate([image if j % 2 == 0 else image[:, ::-1] for j in range(rx)], axis=1)
    return np.concatenate([row if i % 2 == 0 else row[::-1] for i in range(ry)], axis=0)[:h, :w]


def view(image: np.ndarray, h: int, w: int, k: int) -> np.ndarray:
    """The k-th view of a sweep over `image`: panned k/VIEWS across it, its light x(0.85 + 0.05 k)."""
    canvas = tiled(image, 2 * h, 2 * w)
    y, x = k * h // VIEWS, k * w // VIEWS
    return np.clip(canvas[y:y + h, x:x + w] * (0.85 + 0.05 * k), 0, 255).astype(np.uint8)


def write_png(path: Path, rgb: np.ndarray) -> Path:
    cv2.imwrite(str(path), cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_PNG_COMPRESSION, 1])
    return path


def robot_config(folder: Path, size: tuple[int, int], state: Path, **sweep) -> Path:
    """A robot at the example's defaults on the fake body, its camera replaying `folder`."""
    sweep_lines = "".join(f"{k} = {v}\n" for k, v in sweep.items())
    text = (f'state_dir = "{state}"\n[hal]\nbody = "fake"\ncamera = "replay:{folder}"\n'
            f"size = [{size[0]}, {size[1]}]\nreplay_loop = true\n"
            f'[link]\nurl = "loop://"\nkey_file = "{state.parent / "robot.key"}"\n[sweep]\n{sweep_lines}')
    path = state.parent / "robot.toml"
    path.write_text(text)
    return path


def robot(folder: Path, size: tuple[int, int], work: Path) -> tuple[Pipeline, Segmentation]:
    """The robot's HAL (its camera replaying `folder`), segmentation and pipeline."""
    cfg = config.load(robot_config(folder, size, work / "state"))
    hal = build_hal(cfg.hal, state_dir=cfg.state_dir)
    hal.camera.open(size[1], size[0])
    seg = Segmentation(cfg, hal)
    return Pipeline(cfg, hal, seg), seg


def floor(frame: np.ndarray, base: np.ndarray, n: int) -> None:
    """The frame's histograms by plain numpy: per band one bincount of label * 256 + level."""
    for b in range(frame.shape[2]):
        np.bincount((base + frame[..., b]).reshape(-1), minlength=n * 256)


def encode(cap) -> float:
    """Seconds to make the capture's MODELS and MASK bodies (a new view's map is sent)."""
    t0 = time.perf_counter()
    models_body(1, 1, 0.0, "rgb", cap)
    mask_body(1, 1, cap.labels, cap.small)
    return time.perf_counter() - t0


def pose_rounds(pipe: Pipeline, frame: np.ndarray, rounds: int) -> dict[str, float]:
    """Best seconds of each step, of the floor, and of add + fit, over interleaved rounds."""
    v = ViewAngles(60.0, 0.0)
    cap = pipe.shoot(v, v)  # the camera plays the file; later rounds process the same frame again
    settings = pipe.hal.camera.settings()
    base = cap.labels.astype(np.intp) << 8
    n = pipe.cfg.segment.n_labels
    fitter = FrameFitter(n, frame.shape[2])
    best = {k: float("inf") for k in (*STEPS, "floor", "add+fit")}

    def add_fit() -> None:
        fitter.reset()
        fitter.add(frame, cap.labels)
        fitter.fit(min_count=pipe.cfg.skip.min_pixels)

    for r in range(rounds):
        order = ("pose", "floor", "add+fit") if r % 2 == 0 else ("add+fit", "floor", "pose")
        for what in order:
            if what == "pose":
                cap = pipe.process(frame, v, v, settings)
                took = {k: getattr(cap.timing, k) for k in STEPS[:-1]} | {"encode": encode(cap)}
            else:
                t0 = time.perf_counter()
                floor(frame, base, n) if what == "floor" else add_fit()
                took = {what: time.perf_counter() - t0}
            for k, t in took.items():
                best[k] = min(best[k], t)
    return best


def steps_at(size: tuple[int, int], photos, rounds: int, work: Path) -> dict[str, dict[str, float]]:
    """Per photograph: the best seconds of each step, the floor and add + fit at `size`."""
    out = {}
    for name in photos:
        folder = work / f"{name}-{size[1]}x{size[0]}"
        folder.mkdir()
        frame = tiled(load(name), *size)
        write_png(folder / f"{name}.png", frame)
        pipe, _ = robot(folder, size, folder)
        try:
            out[name] = pose_rounds(pipe, frame, rounds)
        finally:
            pipe.hal.close()
    return out


def sweep_refits(size: tuple[int, int], photos, work: Path) -> tuple[list[str], float, float]:
    """Replay VIEWS views of each photograph in turn: which poses fitted ISODATA centres ('R'),
    the median segmentation time of those poses and of the others (seconds)."""
    folder = work / f"sweep-{size[1]}x{size[0]}"
    folder.mkdir()
    for i, name in enumerate(photos):
        image = load(name)
        for k in range(VIEWS):
            write_png(folder / f"p{i}_v{k}.png", view(image, *size, k))
    pipe, seg = robot(folder, size, folder)
    marks, refit_s, kept_s = [], [], []
    try:
        for i in range(len(photos) * VIEWS):
            before = seg.segmenter.refits
            v = ViewAngles(90.0 - 10 * (i % VIEWS), 0.0)
            cap = pipe.shoot(v, v)
            fitted = seg.segmenter.refits > before
            marks.append("R" if fitted else ".")
            (refit_s if fitted else kept_s).append(cap.timing.segmentation)
    finally:
        pipe.hal.close()
    runs = ["".join(marks[j:j + VIEWS]) for j in range(0, len(marks), VIEWS)]
    return runs, float(np.median(refit_s)) if refit_s else 0.0, float(np.median(kept_s)) if kept_s else 0.0


def robot_process(size: tuple[int, int], photos, work: Path, limit_s: float) -> tuple[float, list[dict]]:
    """`btf-robot run --log-json` sweeping VIEWS views of the first photograph at `size`: its peak
    resident set (MB) and its per-pose log lines."""
    state = work / "robot-process" / "state"
    folder = work / "robot-process" / "frames"
    folder.mkdir(parents=True)
    image = load(photos[0])
    for k in range(VIEWS):
        write_png(folder / f"v{k}.png", view(image, *size, k))
    write_key(state.parent / "robot.key")
    cfg = robot_config(folder, size, state, start=90, stop=30, step=10)
    script = Path(sys.executable).parent / "btf-robot"
    argv = [str(script)] if script.is_file() else [sys.executable, "-m", "onboard.cli"]
    proc = subprocess.Popen(argv + ["run", "--config", str(cfg), "--log-json", "--max-seconds", str(limit_s)],
                            stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    lines, peak_kb = [], 0
    for line in proc.stderr:
        record = json.loads(line) if line.startswith("{") else {}
        if "total_ms" in record:
            lines.append(record)
            peak_kb = max(peak_kb, _high_water_kb(proc.pid))
        if record.get("message", "").startswith("sweep 1 done"):
            proc.terminate()
    proc.wait()
    return peak_kb / 1024.0, lines


def _high_water_kb(pid: int) -> int:
    """The process's peak resident set so far (VmHWM, kB): its own since it started the robot's
    program (a fork's copy of this process before that does not count, as ru_maxrss would)."""
    try:
        status = Path(f"/proc/{pid}/status").read_text()
    except OSError:
        return 0
    return next((int(line.split()[1]) for line in status.splitlines() if line.startswith("VmHWM:")), 0)


def _table(per_photo: dict[str, dict[str, float]]) -> tuple[list[str], dict[str, float]]:
    """Rows of each step's best time and ratio to the floor (the median over photographs)."""
    ratio = {k: float(np.median([t[k] / t["floor"] for t in per_photo.values()])) for k in (*STEPS, "add+fit")}
    ms = {k: float(np.median([t[k] for t in per_photo.values()])) * 1e3 for k in (*STEPS, "floor", "add+fit")}
    total = {n: sum(t[k] for k in STEPS) / t["floor"] for n, t in per_photo.items()}
    ratio["pose"] = float(np.median(list(total.values())))
    ratio["pose without dependence"] = float(np.median(
        [sum(t[k] for k in STEPS if k != "dependence") / t["floor"] for t in per_photo.values()]))
    ratio["dependence / fit"] = float(np.median([t["dependence"] / t["fit"] for t in per_photo.values()]))
    rows = [f"| {k} | {ms[k]:.1f} | {ratio[k]:.2f}x |" for k in STEPS]
    rows += [f"| **whole pose (features -> encode)** | {sum(ms[k] for k in STEPS):.1f} | **{ratio['pose']:.2f}x** |",
             f"| whole pose without dependence | {sum(ms[k] for k in STEPS if k != 'dependence'):.1f} | "
             f"{ratio['pose without dependence']:.2f}x |",
             f"| fitter add + fit alone | {ms['add+fit']:.1f} | {ratio['add+fit']:.2f}x |",
             f"| floor: per band one bincount | {ms['floor']:.1f} | 1.00x |"]
    return rows, ratio


def run(ctx: Context) -> list[Section]:
    sizes = ctx.pick(SIZES, {"tiny": (60, 80)})
    photos = ctx.pick(PHOTOS, PHOTOS[:2])
    rounds = ctx.pick(7, 1)
    lines = [f"Photographs {', '.join(photos)}, each mirror-tiled to the frame size and replayed through "
             "the replay camera into the robot's pipeline (examples/robot.toml defaults: ISODATA with the "
             f"scene's centres, dependence on). Best of {rounds} interleaved rounds per photograph; each "
             "figure the median over the photographs; the ratio is to that frame's floor: per band one "
             "np.bincount of label * 256 + level. The benchmark and the robot process it starts run pinned to one core.", ""]
    ratios = {}
    cores = os.sched_getaffinity(0)
    os.sched_setaffinity(0, {min(cores)})  # one core, for this process and the robot it starts
    try:
        with tempfile.TemporaryDirectory(prefix="btf-pose-") as tmp:
            work = Path(tmp)
            for name, size in sizes.items():
                rows, ratios[name] = _table(steps_at(size, photos, rounds, work))
                lines += [f"**{name} ({size[1]}x{size[0]})**", "", "| step | ms | / floor |", "|---|---:|---:|",
                          *rows, ""]
            sweep_size = ctx.pick((1000, 1000), (60, 80))
            runs, refit_s, kept_s = sweep_refits(sweep_size, photos, work)
            robot_size = ctx.pick((1944, 2592), (60, 80))
            peak_mb, logged = robot_process(robot_size, photos, work, ctx.pick(180.0, 60.0))
    finally:
        os.sched_setaffinity(0, cores)
    lines += _summary(ratios, runs, refit_s, kept_s, sweep_size, (robot_size, peak_mb, logged))
    return [Section("Pose by step on replayed photographs", lines)]


def _summary(ratios, runs, refit_s, kept_s, sweep_size, process) -> list[str]:
    out = ["| frame | whole pose / floor | without dependence | add + fit / floor | dependence / fit |",
           "|---|---:|---:|---:|---:|"]
    out += [f"| {n} | {r['pose']:.2f}x | {r['pose without dependence']:.2f}x | {r['add+fit']:.2f}x | "
            f"{r['dependence / fit']:.2f}x |" for n, r in ratios.items()]
    names = {"pose": "whole pose / floor", "add+fit": "add + fit / floor", "dependence / fit": "dependence / fit"}
    out += [""] + [f"**{names[key]} at {frame}: {ratios[frame][key]:.2f}x** (target <= {limit}x: "
                   f"{verdict(ratios[frame][key], limit)})  " for frame, key, limit in TARGETS if frame in ratios]
    fits = sum(r.count("R") for r in runs)
    poses = sum(len(r) for r in runs)
    out += ["", f"**ISODATA refits on a sweep of replayed views** ({sweep_size[1]}x{sweep_size[0]}; "
            f"{VIEWS} views per photograph, panned and x0.85..x1.15 in light; R: centres fitted): "
            f"{' '.join(runs)}, {fits} of {poses} poses (one per scene is the first view's). "
            f"Segmentation of a refit pose {refit_s * 1e3:.0f} ms, of the others {kept_s * 1e3:.1f} ms (medians)."]
    (h, w), peak_mb, logged = process
    totals = [r["total_ms"] for r in logged]
    if totals:
        out += ["", f"**The robot process** (`btf-robot run --log-json`, a {w}x{h} sweep of {len(logged)} poses over "
                f"one photograph's views): peak resident set {peak_mb:.0f} MB; its own log gives each pose's "
                f"compute, median {np.median(totals):.0f} ms (the first pose, which fits the scene's centres: "
                f"{totals[0]:.0f} ms)."]
    return out


if __name__ == "__main__":
    print("\n".join(run(Context())[0].markdown()))
