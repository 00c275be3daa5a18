"""`python -m benchmarks [name ...]`: run benchmarks/bench_*.py and write benchmarks/RESULTS.md.

Each module exposes `run(ctx: Context) -> list[str] | Section | list[Section]`. With names, only
benchmarks/bench_<name>.py modules run (and RESULTS.md holds only those). `--quick` shrinks
every size and repeat count to a smoke test; `--out DIR` writes RESULTS.md and plots there.
"""
from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys
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
    parser.add_argument("--out", type=Path, default=HERE, help="directory for RESULTS.md and plots")
    args = parser.parse_args(argv)
    available = discover()
    unknown = [n for n in args.names if n not in available]
    if unknown:
        print(f"benchmarks: error: no benchmarks/bench_{unknown[0]}.py (have: {', '.join(available)})",
              file=sys.stderr)
        return 2
    ctx = Context(quick=args.quick, out=args.out)
    lines = ["# Benchmark results", "", "Every figure is a ratio of times measured in the same run "
             "(absolute times are context).", "", *machine_lines(), ""]
    if args.quick:
        lines += ["**--quick run: sizes and repeats shrunk to a smoke test; no figure here means anything.**", ""]
    t_all = time.perf_counter()
    for name in args.names or available:
        t0 = time.perf_counter()
        for section in run_one(name, ctx):
            lines += section.markdown()
        print(f"bench_{name}: {time.perf_counter() - t0:.1f} s", file=sys.stderr)
    lines += [f"_Whole run: {time.perf_counter() - t_all:.0f} s._", ""]
    ctx.out.mkdir(parents=True, exist_ok=True)
    results = ctx.out / "RESULTS.md"
    results.write_text("\n".join(lines) + "\n", encoding="utf-8")
    print(f"wrote {results}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
