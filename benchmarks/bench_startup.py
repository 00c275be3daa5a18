"""Start-up of both command lines: `btf-robot --help`, `btf-host --help` and `btf-host resolve`
as a ratio to `python -c pass`, each a fresh process, timed in interleaved rounds (best of the
rounds).

The bars: every one under 0.3 s, and each `--help` within 3x `python -c pass` (the runner imports
only the chosen subcommand's module). Heavy libraries (scipy, OpenCV, scikit-image, matplotlib,
tqdm, dask) load only in the commands that use them; `tests/test_cli_surprises.py` checks that
these commands import none of them.
"""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

from benchmarks.common import Context, Section, paired_times, verdict

ROOT = Path(__file__).resolve().parents[1]
BAR_SECONDS = 0.3
BAR_RATIO = 3.0  # --help against python -c pass


def _cli(name: str, package: str) -> list[str]:
    """The installed entry point `name` beside this interpreter, else the same main via -c."""
    script = Path(sys.executable).parent / name
    if script.is_file():
        return [str(script)]
    return [sys.executable, "-c", f"import sys; from {package} import main; sys.exit(main())"]


def _runner(argv: list[str]):
    def run() -> None:
        subprocess.run(argv, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, check=True)
    return run


def run(ctx: Context | None = None) -> Section:
    ctx = ctx or Context()
    host, robot = _cli("btf-host", "tools.cli"), _cli("btf-robot", "onboard.cli")
    commands = {
        "python -c pass": [sys.executable, "-c", "pass"],
        "python -c 'import numpy'": [sys.executable, "-c", "import numpy"],
        "btf-robot --help": robot + ["--help"],
        "btf-host --help": host + ["--help"],
        "btf-host resolve": host + ["resolve"],
        "btf-host resolve --json": host + ["resolve", "--json"],
        "python -c 'import scipy.stats'": [sys.executable, "-c", "import scipy.stats"],
    }
    rounds = ctx.pick(15, 2)
    t = paired_times({k: _runner(v) for k, v in commands.items()}, rounds)
    base = t["python -c pass"]
    lines = [f"Each command a fresh process; best of {rounds} interleaved rounds. `btf-host` is "
             f"`{Path(host[0]).name}`, `btf-robot` `{Path(robot[0]).name}`; numpy and scipy.stats are context.", "",
             "| command | time ms | / python -c pass |", "|---|---:|---:|"]
    lines += [f"| {k} | {v * 1e3:.1f} | {v / base:.2f}x |" for k, v in t.items()]
    lines.append("")
    for k in ("btf-robot --help", "btf-host --help", "btf-host resolve"):
        ratio_bar = f", <= {BAR_RATIO:g}x: {verdict(t[k] / base, BAR_RATIO)}" if k.endswith("--help") else ""
        lines.append(f"**{k}: {t[k] / base:.2f}x python -c pass, {t[k]:.3f} s** "
                     f"(bar < {BAR_SECONDS} s: {verdict(t[k], BAR_SECONDS)}{ratio_bar})")
        lines.append("")
    return Section("Start-up", lines)
