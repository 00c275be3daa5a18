"""`btf-host demo [--out DIR]`: the whole chain end to end on fakes (see tools.demo.end_to_end)."""
from __future__ import annotations

import argparse
import json
from pathlib import Path

from onboard.cli.runner import SEED, bounded
from tools.cli.options import CliError, writable_place


def add_arguments(p: argparse.ArgumentParser) -> None:
    p.add_argument("--out", default="demo-out",
                   help="output directory (created if missing; its scene.db, work/, report/ and the field scene's "
                        "field.png and field-mask.png are rebuilt)")
    p.add_argument("--force", action="store_true", help="use an --out directory that holds other files too")
    p.add_argument("--size", type=bounded(int, 16, 1024, "pixels"), nargs=2, default=(120, 160), metavar=("H", "W"),
                   help="camera frame height and width, each 16..1024 (default 120 160)")
    p.add_argument("--seed", type=SEED, default=1, help="seed of the channel and the synthesis")
    p.add_argument("--json", action="store_true", help="print the results as one JSON document")
    p.add_argument("--quiet", action="store_true", help="no progress bars")


def _summary(res) -> list[str]:
    lines = [f"database {res.db}: captures " + ", ".join(f"{s} {n}" for s, n in res.captures.items()),
             "link, both ends: " + ", ".join(f"{k} {v}" for k, v in res.link.items())]
    worst = min((r["synthetic"][b] / r["ceiling"][b], r["angle"], b) for r in res.mixed for b in r["synthetic"])
    mean = sum(r["synthetic"][b] for r in res.mixed for b in r["synthetic"]) / (3 * len(res.mixed))
    lines.append(f"mixed plate: mean correlation {mean:.3f} (paper 0.97); worst ratio to the "
                 f"two-seed ceiling {worst[0]:.3f} at {worst[1]:g}° band {worst[2]} (bar 0.95)")
    for s, u in res.unseen.items():
        lines.append(f"unseen 45° {s}: interpolated {u['interpolated']:.3f}, fitted {u['fitted']:.3f} "
                     f"(bar x1.5), nearest {u['nearest']:.3f}")
    for s, t in res.pdfs.items():
        lines.append(f"table 2 {s}: " + ", ".join(f"{p} {v:.3f}" for p, v in t.items()))
    for r in res.table1:
        lines.append(f"table 1 {r['space']} {r['method']:>12}: " + " ".join(
            f"{b} {v:.3f}" for b, v in r["correlation"].items()))
    lines.append("bars: " + ", ".join(f"{k} {'met' if v else 'MISSED'}" for k, v in res.bars().items()))
    lines.append(f"report {res.db.parent / 'report' / 'index.html'}; run time {res.seconds:.1f} s "
                 f"(sweeps and experiments), report {res.report_seconds:.1f} s more")
    return lines


# What a demo leaves in its --out directory (it deletes and rebuilds these).
DEMO_ENTRIES = {"scene.db", "scene.db-wal", "scene.db-shm", "work", "report", "field.png", "field-mask.png"}


def _check_out(out: Path, force: bool) -> None:
    if out.exists() and not out.is_dir():
        raise CliError(f"--out {out} is not a directory")
    writable_place(out, f"--out {out}")
    if force or not out.is_dir():
        return
    others = sorted(p.name for p in out.iterdir() if p.name not in DEMO_ENTRIES)
    work = out / "work"
    if work.is_dir() and any(work.iterdir()) and not (work / "robot.key").is_file():
        others.insert(0, "work/ (not a demo's)")
    if others:
        raise CliError(f"--out {out} holds files that are not a demo's ({', '.join(others[:3])}"
                       f"{', ...' if len(others) > 3 else ''}); the demo rebuilds scene.db, work/ and report/ "
                       "there: choose another directory or pass --force")


def run(args: argparse.Namespace) -> int:
    # heavy (OpenCV, scipy): loaded to run, not for --help
    from tools.demo.end_to_end import DemoConfig, run_demo

    h, w = args.size
    out = Path(args.out)
    _check_out(out, args.force)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise CliError(f"cannot create output directory {out}: {exc.strerror}") from None
    try:
        res = run_demo(out, DemoConfig(size=(h, w), seed=args.seed), progress=not args.quiet)
    except RuntimeError as exc:
        raise CliError(f"demo: {exc}") from None
    if args.json:
        print(json.dumps({"db": str(res.db), "captures": res.captures, "link": res.link, "mixed": res.mixed,
                          "unseen": res.unseen, "pdfs": res.pdfs, "table1": res.table1,
                          "bars": res.bars(), "seconds": res.seconds,
                          "report_seconds": res.report_seconds}, indent=1))
    else:
        print("\n".join(_summary(res)))
    return 0 if all(res.bars().values()) else 1
