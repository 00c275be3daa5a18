"""`btf-host synth`: a synthetic image inside a mask, at a measured or interpolated angle."""
from __future__ import annotations

import argparse
import json
import sys
import warnings
from pathlib import Path

import numpy as np

from btf.fit.features import PcaBasis
from onboard.cli.runner import SEED, bounded
from tools.analysis.interpolation import models_by_direction, requested_direction, synthesize_at_direction
from tools.analysis.models_doc import dependence_from_document, models_from_document
from tools.analysis.radiometry import check_space, sweep_dependence, sweep_models
from tools.analysis.synth import ExtrapolationWarning, MissingModels, ReachWarning, synthesize_at
from tools.cli.options import (
    FEATURE_SPACES,
    CliError,
    add_force,
    add_source_filters,
    check_out,
    choose_source,
    elevation,
)
from tools.data.images import DEEP_SUFFIXES, TIFF_SUFFIXES, ImageError, read_mask, to_rgb, write_image
from tools.store.database import CorruptDatabase, Store


def add_arguments(p: argparse.ArgumentParser) -> None:
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--db", help="database of captures")
    src.add_argument("--model", help="MODELS.json: one document of 'btf-host fit --json', or a list of them")
    p.add_argument("--mask", required=True,
                   help="label mask PNG: the regions to fill, each with its label's models; sets the image's size")
    p.add_argument("--angle",
                   help="view elevation, or EL,AZ[,LIGHT_EL,LIGHT_AZ] in degrees (needed with --db and with a "
                        "models file of several angles; several angles at once need --db)")
    p.add_argument("--azimuth", type=float, help="view azimuth, degrees")
    p.add_argument("--light-elevation", type=float, help="light elevation, degrees (with --light-azimuth)")
    p.add_argument("--light-azimuth", type=float, help="light azimuth, degrees")
    p.add_argument("--out", required=True, help="output image (never an input; an existing file needs --force)")
    add_force(p)
    p.add_argument("--seed", type=SEED, default=0, help="seed of the drawing (the same seed, the same image)")
    p.add_argument("--space", choices=FEATURE_SPACES, help="which stored feature space (--db)")
    add_source_filters(p)
    p.add_argument("--independent", action="store_true",
                   help="draw every pixel on its own even when grain and band correlation are stored "
                        "(still within each region's observed levels)")
    p.add_argument("--exposure", type=bounded(float, 1, 1e8, "microseconds"), metavar="US",
                   help="synthesize as if every capture had been taken at this exposure, in microseconds "
                        "(--db, rgb or gray; default: each capture's own)")
    p.add_argument("--normalise-reference", action="store_true",
                   help="scale each capture so its reference card's level is the sweep's median (takes out "
                        "drift of the light between captures; --db, rgb or gray)")


def _from_json(path: str) -> tuple[dict, dict, str, int, dict | None]:
    """(models by angle, dependence by angle, space, levels, pca record) of a models file."""
    try:
        raw = json.loads(Path(path).read_text())
    except FileNotFoundError:
        raise CliError(f"models {path}: no such file") from None
    except (OSError, UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise CliError(f"models {path}: not readable JSON ({exc})") from None
    docs = raw if isinstance(raw, list) else [raw]
    by_angle: dict = {}
    deps: dict = {}
    try:
        parsed = [models_from_document(d) for d in docs]
        found = [dependence_from_document(d, 1 + max((b for _, b in m), default=0)) for _, m, d in parsed]
    except ValueError as exc:
        raise CliError(f"models {path}: {exc}") from None
    if not parsed:
        raise CliError(f"models {path}: no documents")
    spaces = {d.get("space") for _, _, d in parsed}
    if len(spaces) != 1:
        raise CliError(f"models {path}: documents mix feature spaces {sorted(map(str, spaces))}")
    for (angle, models, _), dep in zip(parsed, found):
        if angle is None and len(parsed) > 1:
            raise CliError(f"models {path}: with several documents each needs its angle")
        by_angle[0.0 if angle is None else angle] = models
        deps[0.0 if angle is None else angle] = dep
    first = parsed[0][2]
    levels = first.get("levels") or 256
    depths = sorted({d.get("levels") or 256 for _, _, d in parsed}, key=str)
    if len(depths) > 1:
        raise CliError(f"models {path}: documents of images of {' and '.join(map(str, depths))} levels, which are "
                       "never blended; keep one depth per models file")
    if type(levels) is not int or not 2 <= levels <= 65536:
        raise CliError(f"models {path}: levels {levels!r} is not an integer in 2..65536")
    if levels > 256 and first.get("space") not in ("rgb", "gray", "raw"):
        raise CliError(f"models {path}: {levels} levels in space {first.get('space')!r}; "
                       "deep models are rgb, gray or raw")
    if parsed[0][0] is None:  # one document without an angle serves every angle
        by_angle, deps = {float("-inf"): parsed[0][1]}, {float("-inf"): found[0]}
    return by_angle, deps, str(first.get("space") or "rgb"), levels, first.get("pca")


def _source(store, args: argparse.Namespace) -> dict:
    """Store filters for the one robot, scene and feature space to synthesize from."""
    robot, scene = choose_source(store.captures(), args.db, args.robot, args.scene)
    space = args.space
    spaces = sorted({c.space for c in store.captures(robot=robot, scene=scene)})
    if space is None:
        if len(spaces) > 1:
            raise CliError(f"database {args.db}: several feature spaces {spaces}; choose one with --space")
        space = spaces[0]
    if space not in spaces:
        raise CliError(f"database {args.db}: no captures in feature space {space} (it holds {', '.join(spaces)})")
    _one_depth(store.captures(robot=robot, scene=scene, space=space), args.db, robot, scene)
    return {"robot": robot, "scene": scene, "space": space}


def _one_depth(captures, db: str, robot: str, scene: str) -> None:
    """Refuses captures of different sensor depths: their levels are not one scale to blend."""
    by_depth: dict[int, list[float]] = {}
    for c in captures:
        by_depth.setdefault(c.levels, []).append(c.elevation)
    if len(by_depth) > 1:
        said = " and ".join(f"{_bits(levels)} ({', '.join(f'{e:g}°' for e in sorted(set(els))[:4])}"
                            + (", ...)" if len(set(els)) > 4 else ")") for levels, els in sorted(by_depth.items()))
        who = f"robot {robot}" + (f" scene {scene}" if scene else "")
        raise CliError(f"database {db}: the captures of {who} mix {said} images, which are never blended; "
                       "store each depth under its own --robot or --scene (fit --db takes both) and choose one")


def _bits(levels: int) -> str:
    return f"{levels.bit_length() - 1}-bit" if levels & (levels - 1) == 0 else f"{levels}-level"


def _radiometry(args: argparse.Namespace, space: str) -> bool:
    """Whether --exposure or --normalise-reference asks for anything (checked for this space)."""
    asked = args.exposure is not None or args.normalise_reference
    if not asked:
        return False
    if not args.db:
        raise CliError("--exposure and --normalise-reference need --db (a models document carries no camera settings)")

    try:
        check_space(space, "--exposure and --normalise-reference")
    except ValueError as exc:
        raise CliError(str(exc)) from None
    return True


def _load_models(store, source: dict, args: argparse.Namespace, direction=None) -> dict:
    """Models by angle (or by direction), each capture's radiometry applied; warnings printed."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            if direction is not None:
                found = models_by_direction(store, **source, exposure_us=args.exposure,
                                            normalise=args.normalise_reference)
            elif _radiometry(args, source["space"]):
                found = sweep_models(store, store.latest_by_angle(**source), args.exposure, args.normalise_reference)
            else:
                found = store.models_by_angle(**source)
        except ValueError as exc:
            raise CliError(f"database {args.db}: {exc}") from None
    _warn(caught)
    return found


def _open_db(path: str):
    try:
        return Store.open(path, create=False)
    except CorruptDatabase as exc:
        raise CliError(str(exc)) from None


def _stored_basis(bases: dict, db: str):
    """The one PCA basis of the stored pca captures (components of different bases do not mix)."""
    distinct = {b for b in bases.values()}
    if None in distinct:
        raise CliError(f"database {db}: pca captures without a stored PCA basis; cannot turn them into RGB")
    if len(distinct) != 1:
        raise CliError(f"database {db}: pca captures use {len(distinct)} different PCA bases (one per scene)")
    return distinct.pop()


def _read_mask(path: str) -> np.ndarray:
    try:
        return read_mask(path)
    except ImageError as exc:
        raise CliError(str(exc)) from None


def _write(args: argparse.Namespace, bands: np.ndarray, space: str, pca=None) -> int:
    """The image at the models' depth: uint8 up to 256 levels, else 16-bit (PNG or TIFF)."""
    try:
        write_image(args.out, to_rgb(bands, space, pca))
    except ImageError as exc:
        raise CliError(str(exc)) from None
    return 0


def _run_direction(args: argparse.Namespace, direction) -> int:
    """Several angles: barycentric quantile blending over the stored directions (tools.analysis.interpolation)."""

    if not args.db:
        raise CliError("synth: several angles need --db (a models document holds one angle)")
    if args.space == "pca":
        raise CliError("synth --db: pca bases are not stored yet; use --model from 'btf-host fit --json'")
    with _open_db(args.db) as store:
        source = _source(store, args)
        _radiometry(args, source["space"])
        by_direction = _load_models(store, source, args, direction)
        levels = store.levels(**source)
    _check_depth(args.out, levels)
    mask = _read_mask(args.mask)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ExtrapolationWarning)
        try:
            bands = synthesize_at_direction(by_direction, mask, direction, np.random.default_rng(args.seed), levels)
        except (MissingModels, ValueError) as exc:
            raise CliError(str(exc)) from None
    _warn(caught)
    return _write(args, bands, source["space"])


def _check_depth(out: str, levels: int) -> None:
    """Refuses, before any work, an output file that cannot hold the models' depth."""
    if levels > 256 and Path(out).suffix.lower() not in DEEP_SUFFIXES:
        raise CliError(f"image {out}: 16-bit pixels need a .png or .tif file (the models have {levels} levels)")


def _check_bands(out: str, space: str, by_angle: dict) -> None:
    """Refuses, before any work, a PNG for raw bands other than one or three."""
    bands = 1 + max((b for models in by_angle.values() for _, b in models), default=0)
    if space == "raw" and bands not in (1, 3) and Path(out).suffix.lower() not in TIFF_SUFFIXES:
        raise CliError(f"image {out}: {bands} bands need a .tif file (PNG holds one or three)")


def _warn(caught) -> None:
    for w in caught:
        print(f"btf-host: warning: {w.message}", file=sys.stderr)


def run(args: argparse.Namespace) -> int:
    check_out(args.out, (args.db, args.model, args.mask), args.force)
    direction = None
    if args.angle is None and any(v is not None for v in (args.azimuth, args.light_elevation, args.light_azimuth)):
        raise CliError("--azimuth and the light's angles need --angle (the view elevation)")
    try:
        if args.angle is not None:
            direction = requested_direction(args.angle, args.azimuth, args.light_elevation, args.light_azimuth)
    except ValueError as exc:
        raise CliError(str(exc)) from None
    if direction is not None:
        return _run_direction(args, direction)
    if args.angle is not None:
        args.angle = elevation(float(args.angle))
    pca = None
    if args.db:
        if args.angle is None:
            raise CliError("--db needs --angle: which view to synthesize")
        with _open_db(args.db) as store:
            source = _source(store, args)
            space = source["space"]
            by_angle = _load_models(store, source, args)
            levels = store.levels(**source)
            dependence = (sweep_dependence(store, store.latest_by_angle(**source), args.exposure,
                                           args.normalise_reference)
                          if _radiometry(args, space) else store.dependence_by_angle(**source))
            if space == "pca":
                pca = _stored_basis(store.pca_by_angle(**source), args.db)
    else:
        _radiometry(args, "rgb")  # refuses --exposure and --normalise-reference without --db
        given = [o for o, v in (("--space", args.space), ("--robot", args.robot), ("--scene", args.scene)) if v]
        if given:  # they choose among a database's captures: a models document has its own
            raise CliError(f"{', '.join(given)}: chooses among a database's captures (--db); a models document "
                           "holds one space, robot and scene")
        by_angle, dependence, space, levels, pca_rec = _from_json(args.model)
        try:
            pca = PcaBasis.from_record(pca_rec) if pca_rec else None
        except ValueError as exc:
            raise CliError(f"models {args.model}: {exc}") from None
        bands = 1 + max((b for models in by_angle.values() for _, b in models), default=-1)
        if pca is not None and pca.n != bands:
            raise CliError(f"models {args.model}: its pca basis has {pca.n} channel(s) for {bands} band(s) of models")
    _check_depth(args.out, levels)
    _check_bands(args.out, space, by_angle)
    mask = _read_mask(args.mask)
    angle = args.angle
    if float("-inf") in by_angle:  # one document without an angle: it serves any angle
        angle = 0.0 if angle is None else angle
        by_angle, dependence = {angle: by_angle[float("-inf")]}, {angle: d for d in dependence.values()}
    elif angle is None:
        if len(by_angle) > 1:
            raise CliError(f"models {args.model}: several angles; choose one with --angle")
        angle = next(iter(by_angle))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ExtrapolationWarning)
        warnings.simplefilter("always", ReachWarning)
        try:
            bands = synthesize_at(by_angle, mask, angle, np.random.default_rng(args.seed), levels,
                                  dependence=dependence, independent=args.independent)
        except (MissingModels, ValueError) as exc:
            raise CliError(str(exc)) from None
    _warn(caught)
    return _write(args, bands, space, pca)
