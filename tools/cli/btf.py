"""`btf-host btf --db DB [--robot R --scene S] [--json] [--plot FILE.png]`: the BTF as a table,
one row per region, band and measured angle, with the leave-one-out figures (tools.analysis.btf_loo)."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from tools.cli.options import FEATURE_SPACES, CliError, add_force, add_source_filters, check_out, sources_of
from tools.store.database import CorruptDatabase, Store


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--db", required=True, help="database written by station, listen, ingest or demo")
    add_source_filters(p)
    p.add_argument("--space", choices=FEATURE_SPACES, help="only captures in this feature space")
    p.add_argument("--json", action="store_true", help="one JSON document instead of the table")
    p.add_argument("--plot", metavar="FILE.png", help="draw the BTF of the one robot and scene into this PNG")
    add_force(p, "--plot")


def _num(v, width: int = 8, digits: int = 3) -> str:
    return f"{'-':>{width}}" if v is None else f"{v:>{width}.{digits}f}"


def table(doc: dict) -> list[str]:
    """A `table_json` document as lines of text: a heading, the rows, the leave-one-out summary."""
    lines = [f"BTF of {doc['scene'] or 'no scene'} (robot {doc['robot']}, {doc['space']}, {doc['levels']} levels): "
             f"{doc['directions']} direction(s)" + (f" (the latest capture at each, of {doc['captures']} stored)"
                                                    if doc.get("captures", 0) > doc["directions"] else "")
             + f", varied: {', '.join(doc['varied']) or 'nothing'}",
             f"{'label':>5} {'band':>4} {'angle':>16} {'family':>6} {'gamma':>8} {'delta':>8} {'xi':>8} {'lambda':>8} "
             f"{'pixels':>7} {'mean':>8} {'sd':>8} {'skew':>8} {'kurt':>8} {'interpL1':>8} {'nearL1':>8}  nearest"]
    for r in doc["rows"]:
        lines.append(f"{r['label']:>5} {r['band_name']:>4} {r['angle']:>16} {r['family']:>6} {_num(r['gamma'])} "
                     f"{_num(r['delta'])} {_num(r['xi'])} {_num(r['lam'])} {r['pixels'] or 0:>7} {_num(r['mean'])} "
                     f"{_num(r['sd'])} {_num(r['skewness'])} {_num(r['kurtosis'])} {_num(r['interpolated_l1'], 8, 4)} "
                     f"{_num(r['nearest_l1'], 8, 4)}  {r['nearest_angle'] or ''}")
    s = doc["leave_one_out"]["summary"]
    if s["interior"]:
        lines.append(f"leave one out: interpolation beats the nearest measured angle at {s['interpolation_better']} of "
                     f"{s['interior']}; mean exact L1 {s['interpolated_mean_l1']:.4f} interpolated, "
                     f"{s['nearest_mean_l1']:.4f} nearest")
        lines += [f"  not at region {r['label']} band {r['band_name']} {r['angle']}: {r['why_not']}"
                  for r in doc["leave_one_out"]["rows"] if not r["interpolation_better"]]
    else:
        lines.append("leave one out: no measured angle has measured neighbours on both sides")
    return lines


def _check(args: argparse.Namespace) -> None:
    if args.space is not None and args.space not in FEATURE_SPACES:
        raise CliError(f"--space {args.space}: a feature space is one of {', '.join(FEATURE_SPACES)}")
    if args.plot is not None:
        if Path(args.plot).suffix.lower() != ".png":
            raise CliError(f"--plot {args.plot}: the plot is a PNG file (name it .png)")
        check_out(args.plot, (args.db,), args.force, suffixes=(".png",), option="--plot")


def run(args: argparse.Namespace) -> int:
    # heavy (scipy, matplotlib): loaded to run, not for --help
    from tools.analysis.btf_loo import table_json
    from tools.analysis.btf_view import load, sources
    from tools.report.btf_plots import figure_png, region_blocks

    _check(args)
    try:
        with Store.open(args.db, create=False) as store:
            caps = [c for c in store.captures() if args.space in (None, c.space)]
            if not caps and store.captures():
                raise CliError(f"database {args.db}: no captures in feature space {args.space}")
            pairs = sources_of(caps, args.db, args.robot, args.scene)
            found = [s for s in sources(store, args.robot, args.scene)
                     if (s[0], s[1]) in pairs and args.space in (None, s[2])]
            if args.plot is not None and len(found) > 1:
                raise CliError(f"--plot draws one robot and scene; the database holds {len(found)} "
                               f"({'; '.join(f'robot {r} scene {s!r} {sp}' for r, s, sp in found[:4])}): "
                               "choose one with --robot, --scene or --space")
            btfs = [load(store, *s) for s in found]
            docs = [table_json(b) for b in btfs]
    except CorruptDatabase as exc:
        raise CliError(str(exc)) from None
    if args.plot is not None:
        try:
            Path(args.plot).write_bytes(figure_png(btfs[0], region_blocks(btfs[0])))
        except OSError as exc:
            raise CliError(f"--plot {args.plot}: cannot write ({exc.strerror})") from None
    if args.json:
        print(json.dumps({"db": str(args.db), "btfs": docs}, indent=1))
    else:
        print("\n\n".join("\n".join(table(d)) for d in docs))
        if args.plot is not None:
            print(f"plot {args.plot}")
    return 0
