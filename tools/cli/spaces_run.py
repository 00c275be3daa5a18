"""`btf-host spaces` at work: the photograph (a file or a stored capture), its masks, the table,
the picture and the choice."""
from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import cv2
import numpy as np

from tools.analysis.spaces import Judgement, SpaceRow, judge, spaces_of
from tools.cli.options import CliError
from tools.data.images import (
    ImageError,
    read_image,
    read_mask,
    segmentation_view,
    to_rgb,
    view_rgb,
    write_image,
)
from tools.data.masks import segment
from tools.report.capture_views import Frames, capture_mask
from tools.store.database import CorruptDatabase, Store, StoreUnavailable

HEADER = (f"{'mask':<10} {'space':<5} {'reg':>3} {'table2':>7} {'noise':>6} {'L1':>6} {'decor':>5} "
          f"{'outside':>7} {'plaid':>5} {'acf':>5} {'bandgap':>7} {'bytes':>6} {'fit ms':>7}  "
          "Table 1 correlation per band: correlated/independent")


def _num(v: float | None, width: int, digits: int) -> str:
    return f"{'-':>{width}}" if v is None else f"{v:{width}.{digits}f}"


def row_line(r: SpaceRow) -> str:
    f, t = r.figures, r.texture
    corr = " ".join(f"{b} {r.correlation['correlated'][b]:.3f}/{r.correlation['independent'][b]:.3f}"
                    for b in r.bands)
    wire = f"{r.wire_bytes:6d}" if r.wire_bytes is not None else f"{'>max':>6}"
    return (f"{r.mask:<10} {r.space:<5} {r.regions:3d} {f.error:7.4f} {f.noise:6.4f} {r.l1:6.4f} "
            f"{f.decorrelation:5.2f} {_num(t['outside'], 7, 4)} {_num(t['plaid'], 5, 2)} {_num(t['acf_gap'], 5, 2)} "
            f"{_num(t['band_gap'], 7, 3)} {wire} {r.fit_seconds * 1e3:7.1f}  {corr}")


def table_lines(result: Judgement) -> list[str]:
    lines = [HEADER] + [row_line(r) for r in result.rows]
    for r in result.rows:
        lines += [f"note: {r.mask} {r.space}: {n}" for n in r.notes]
    return lines


def _view(bands: np.ndarray, space: str, pca, photo: np.ndarray) -> np.ndarray:
    """8-bit RGB of a synthesis in its feature space, stretched as its photograph is."""
    img = to_rgb(bands, space, pca)
    return view_rgb(img[..., None] if img.ndim == 2 else img, photo)


MIN_PANEL = 256  # a small photograph's panels are enlarged (pixel for pixel) to at least this width


def _titled(img: np.ndarray, title: str) -> np.ndarray:
    zoom = max(1, -(-MIN_PANEL // img.shape[1]))
    if zoom > 1:
        img = np.repeat(np.repeat(img, zoom, axis=0), zoom, axis=1)
    strip = np.full((24, img.shape[1], 3), 255, np.uint8)
    cv2.putText(strip, title, (4, 17), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1, cv2.LINE_AA)
    return np.concatenate([strip, img], axis=0)


def picture(image: np.ndarray, result: Judgement) -> np.ndarray:
    """The photograph | the chosen synthesis | the worst one, titled, 8-bit RGB."""
    best, worst = result.chosen, result.worst
    panels = [_titled(view_rgb(image), "photograph")]
    for what, r in (("chosen", best), ("worst", worst)):
        panels.append(_titled(_view(r.synthesis, r.space, r.pca, image),
                              f"{what}: {r.mask} {r.space} ({r.figures.error:.3f})"))
    gap = np.full((panels[0].shape[0], 6, 3), 255, np.uint8)
    return np.concatenate([panels[0], gap, panels[1], gap, panels[2]], axis=1)


def stored_photo(db: str, capture: str, robot_config: str | None) -> tuple[np.ndarray, str, np.ndarray | None]:
    """(image, what it is, its stored mask or None) of a capture: an ingested dataset's source
    file, the file a replaying camera read, or a fake robot's render (--robot-config)."""
    robot, _, seq = capture.rpartition("/")
    if not robot or not seq.isdigit():
        raise CliError(f"--capture {capture}: expected ROBOT/SEQ, e.g. 1/12 or dataset:photos/3")
    if not Path(db).is_file():
        raise CliError(f"database {db}: no such file")
    try:
        store = Store.open(db, create=False)
    except (StoreUnavailable, CorruptDatabase) as exc:
        raise CliError(str(exc)) from None
    try:
        # a robot numbers its captures afresh in each state it keeps (its incarnation): the newest such capture
        same = sorted((c for c in store.captures(robot=robot) if c.sequence == int(seq)), key=lambda c: c.id)
        if not same:
            raise CliError(f"database {db}: no capture {capture}")
        cap = same[-1]
        if len(same) > 1:
            print(f"btf-host: note: robot {robot} numbered {len(same)} captures {seq} (one per robot state); "
                  f"judging the newest, stored as capture id {cap.id}", file=sys.stderr)
        try:
            frames = Frames.from_robot_config(robot_config)
        except ValueError as exc:
            raise CliError(f"--robot-config {robot_config}: {exc}") from None
        image = frames(cap)
        source = cap.camera.source if cap.camera is not None else None
        if image is None and source and Path(source).is_file():
            try:
                image = read_image(source)
            except ImageError:
                image = None
        if image is None:
            where = cap.source_file or source
            raise CliError(f"capture {capture} has no image to judge by ("
                           + (f"its file {where} is not readable here" if where else "no file recorded")
                           + "; a fake robot's capture renders with --robot-config ROBOT.toml)")
        return image, f"capture {capture} of {db}", capture_mask(store, cap)
    finally:
        store.close()


def photo(args: argparse.Namespace) -> tuple[np.ndarray, str, np.ndarray | None]:
    """(image, what it is, its mask: --mask, a stored capture's, or None)."""
    if args.db:
        if args.image:
            raise CliError("give the photograph or --db with --capture, not both")
        if not args.capture:
            raise CliError("--db needs --capture ROBOT/SEQ: the stored capture to judge")
        image, said, stored = stored_photo(args.db, args.capture, args.robot_config)
    else:
        if args.capture or args.robot_config:
            raise CliError("--capture and --robot-config name a stored capture: give --db DB too")
        if not args.image:
            raise CliError("give a photograph, or --db DB --capture ROBOT/SEQ")
        try:
            image, said, stored = read_image(args.image), f"photograph {args.image}", None
        except ImageError as exc:
            raise CliError(str(exc)) from None
    if args.mask:
        try:
            stored = read_mask(args.mask, image.shape[:2])
        except ImageError as exc:
            raise CliError(str(exc)) from None
    return image, said, stored


def masks_of(args: argparse.Namespace, specs: list[tuple[str, str, int]], image: np.ndarray,
             stored: np.ndarray | None) -> dict[str, np.ndarray]:
    """--mask, a stored capture's own mask (unless --masks), or the segmentations --masks names."""
    if args.mask:
        return {"mask": stored}
    if stored is not None and args.masks is None:
        return {"stored": stored}
    view = segmentation_view(image)  # what `btf-host mask` segments
    out = {}
    for name, method, k in specs:
        if image.shape[0] * image.shape[1] < k:
            raise CliError(f"--masks {name}: the photograph has fewer pixels than {k} classes")
        out[name] = segment(view, method, k, args.seed)
    return out


def execute(args: argparse.Namespace, specs: list[tuple[str, str, int]], asked: tuple[str, ...] | None) -> int:
    """The command on the masks `specs` names and the spaces `asked` (None: all the photograph offers)."""
    image, said, stored = photo(args)
    offered = spaces_of(image)
    spaces = offered if asked is None else asked
    missing = [s for s in spaces if s not in offered]
    if missing:
        raise CliError(f"--spaces {args.spaces}: {said} offers only {', '.join(offered)}; drop {', '.join(missing)}")
    masks = masks_of(args, specs, image, stored)
    levels = 256 if image.dtype == np.uint8 else 65536
    progress = None if args.json else (lambda what: print(f"judging {what} ...", file=sys.stderr, flush=True))
    result = judge(image, masks, spaces, args.seed, progress)
    if args.picture:
        try:
            write_image(args.picture, picture(image, result))
        except ImageError as exc:
            raise CliError(str(exc)) from None
    if args.json:
        doc = result.to_json()
        doc.update({"image": said, "levels": levels, "seed": args.seed})
        print(json.dumps(doc, indent=1))
        return 0
    print(f"{said}: {image.shape[1]}x{image.shape[0]}, {image.shape[2]} band(s), {levels} levels")
    for line in table_lines(result):
        print(line)
    print(f"choice: {result.mask} in {result.space}; {result.reason}")
    return 0
