"""`python -m benchmarks [name ...]`: run benchmarks/bench_*.py and write benchmarks/RESULTS.md.

Each module exposes `run(ctx: Context) -> list[str] | Section | list[Section]`. With names, only
benchmarks/bench_<name>.py modules run, and their sections replace those of the same title in an
existing RESULTS.md (the others stay, each re-run section saying so). `--quick` shrinks every size
and repeat count to a smoke test, written to a temporary directory unless `--out DIR` is given;
`--out DIR` writes RESULTS.md and plots there.
"""
from __future__ import annotations

import argparse
import datetime
import importlib
import os
import pkgutil
import sys
import tempfile
import time
from pathlib import Path

import benchmarks
from benchmarks.common import HERE, Context, Section, machine_lines


def discover() -> list[str]:
    return sorted(m.name[len("bench_"):] for m in pkgutil.iter_modules(benchmarks.__path__)
                  if m.name.startswith("bench_"))


def as_sections(name: str, out) -> list[Section]:
    if isinstance(out, Section):
        return [out]
    if isinstance(out, list) and all(isinstance(s, Section) for s in out) and out:
        return out
    return [Section(name, [str(line) for line in out])]


def run_one(name: str, ctx: Context) -> list[Section]:
    module = importlib.import_module(f"benchmarks.bench_{name}")
    return as_sections(name, module.run(ctx))


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m benchmarks", description=__doc__.splitlines()[0])
    parser.add_argument("names", nargs="*", help=f"modules to run (default all: {', '.join(discover())})")
    parser.add_argument("--quick", action="store_true", help="tiny sizes: a smoke test, not figures")
    parser.add_argument("--out", type=Path, default=None,
                        help="directory for RESULTS.md and plots (default benchmarks/; a temporary one with --quick)")
    args = parser.parse_args(argv)
    if args.out is None:  # a smoke test never overwrites the measured figures
        args.out = Path(tempfile.gettempdir()) / "btfscout-bench-quick" if args.quick else HERE
    available = discover()
    unknown = [n for n in args.names if n not in available]
    if unknown:
        print(f"benchmarks: error: no benchmarks/bench_{unknown[0]}.py (have: {', '.join(available)})",
              file=sys.stderr)
        return 2
    ctx = Context(quick=args.quick, out=args.out)
    header = ["# Benchmark results", "", "Every figure is a ratio of times measured in the same run "
              "(absolute times are context).", "", *machine_lines(), ""]
    if args.quick:
        header += ["**--quick run: sizes and repeats shrunk to a smoke test; no figure here means anything.**", ""]
    t_all = time.perf_counter()
    sections: list[Section] = []
    for name in args.names or available:
        t0 = time.perf_counter()
        sections += run_one(name, ctx)
        print(f"bench_{name}: {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    ctx.out.mkdir(parents=True, exist_ok=True)
    results = ctx.out / "RESULTS.md"
    took = time.perf_counter() - t_all
    if args.names and not args.quick and results.is_file():
        text = spliced(results.read_text(encoding="utf-8"), sections, " ".join(args.names), took)
    else:
        text = "\n".join([*header, *(line for s in sections for line in s.markdown()),
                          f"_Whole run: {took:.0f} s._", ""]) + "\n"
    results.write_text(text, encoding="utf-8")
    print(f"wrote {results}")
    return 0


def spliced(old: str, sections: list[Section], names: str, took: float) -> str:
    """`old` RESULTS.md with `sections` in place of those of the same titles (new ones before
    its closing line), each saying it was re-run alone, when and at what load."""
    head: list[str] = []
    parts: list[tuple[str, list[str]]] = []
    tail: list[str] = []
    for line in old.splitlines():
        if line.startswith("_Whole run:"):
            tail.append(line)
        elif tail:
            tail.append(line)
        elif line.startswith("## "):
            parts.append((line[3:].strip(), [line]))
        elif parts:
            parts[-1][1].append(line)
        else:
            head.append(line)
    try:
        load = "%.2f" % os.getloadavg()[0]
    except OSError:
        load = "unknown"
    when = datetime.datetime.now().strftime("%Y-%m-%d")
    said = (f"_This section re-run alone on {when} (`python -m benchmarks {names}`, {took:.0f} s, "
            f"load average {load} at its end); the header's machine and load are the whole run's._")
    fresh = {s.title: [*s.markdown()[:-1], said, ""] for s in sections}
    body = [fresh.pop(title, lines) for title, lines in parts]
    body += list(fresh.values())
    return "\n".join([*head, *(line for lines in body for line in lines), *tail]).rstrip("\n") + "\n"


if __name__ == "__main__":
    sys.exit(main())
