"""Dataset ingest: throughput (images per second) and scaling from 1 to 2 workers; and the
station's store: captures a second with every acknowledged capture on stable storage
(`benchmarks.store_commits`).

A UTIA-layout dataset of rendered views (rendering is not timed) is ingested into a fresh
database by each executor: in-process, a process pool of 1 and of 2, and a Dask
LocalCluster of 2 worker processes (its start-up is timed apart). Each time is the best of
a few runs; every run must give the same database.
"""
from __future__ import annotations

import sqlite3
import tempfile
import time
from pathlib import Path

from benchmarks.common import Context, Section
from benchmarks.store_commits import run as run_store
from tools.data.datasets import Angles, write_rendered
from tools.data.ingest import Job, fit_job, ingest


def _views(n: int) -> list[Angles]:
    els = (30.0, 45.0, 60.0, 75.0, 90.0)
    out = [Angles(el, az, lel, 0.0) for el in els for az in (0.0, 90.0, 180.0, 270.0) for lel in (30.0, 50.0, 70.0)]
    return out[:n]


def _content(db: Path) -> list:
    con = sqlite3.connect(db)
    try:
        return con.execute("SELECT * FROM models ORDER BY capture, label, band").fetchall()
    finally:
        con.close()


def _best(root: Path, work: Path, repeat: int, **kw) -> tuple[float, list]:
    best, content = float("inf"), None
    for k in range(repeat):
        db = work / f"{kw.get('workers', 'dask')}_{k}_{time.monotonic_ns()}.db"
        t0 = time.perf_counter()
        ingest(root, "utia", db, mask=root / "masks", **kw)
        best = min(best, time.perf_counter() - t0)
        content = _content(db)
    return best, content


def run(ctx: Context | None = None) -> list[Section]:
    return [Section("ingest", run_ingest(ctx)), run_store(ctx or Context())]


def run_ingest(ctx: Context | None) -> list[str]:
    quick = bool(getattr(ctx, "quick", False))
    n, size, repeat = (6, (60, 80), 1) if quick else (48, (240, 320), 3)
    with tempfile.TemporaryDirectory(prefix="btf-ingest-") as tmp:
        root, work = Path(tmp) / "data", Path(tmp)
        write_rendered(root, "utia", _views(n), size=size, seed=1)
        rows = []
        t_serial, ref = _best(root, work, repeat, workers=0)
        rows.append(("in-process", t_serial))
        for workers in (1, 2):
            t, content = _best(root, work, repeat, workers=workers)
            assert content == ref, "process pool gave a different database"
            rows.append((f"process pool, {workers} worker{'s' * (workers > 1)}", t))
        from distributed import LocalCluster

        t0 = time.perf_counter()
        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
            start = time.perf_counter() - t0
            t, content = _best(root, work, repeat, scheduler=cluster.scheduler_address)
        assert content == ref, f"Dask gave a different database ({len(content)} vs {len(ref)} rows)"
        rows.append(("Dask LocalCluster, 2 worker processes", t))
        jobs = [Job(p.name, str(p), str(root / "masks" / (p.stem + ".png")), "rgb")
                for p in sorted(root.glob("*.png"))]
        t0 = time.perf_counter()
        for job in jobs:
            fit_job(job)
        t_fit = time.perf_counter() - t0
    pool1 = rows[1][1]
    lines = [f"{n} images of {size[1]}x{size[0]} px, two labels, RGB; best of {repeat}; the same "
             "models table from every executor (checked).", "",
             "| executor | time s | images/s | speed-up vs pool of 1 |", "|---|---:|---:|---:|"]
    lines += [f"| {name} | {t:.2f} | {n / t:.1f} | {pool1 / t:.2f}x |" for name, t in rows]
    rest = (t_serial - t_fit) / n * 1e3
    lines += ["", f"Fitting alone, in this process: {n / t_fit:.1f} images/s; the rest of the in-process "
              + (f"time ({rest:.1f} ms per image)" if rest > 0.5 else "time (below the timing noise)")
              + " is the single writer, batched: one SQLite commit per 64 images, WAL, synchronous=FULL.",
              "", f"Dask cluster start-up (not in the times above): {start:.1f} s. "
              "Scaling 1 -> 2 workers on a shared 2-core machine is bounded by the other load on it."]
    return lines


if __name__ == "__main__":
    for section in run():
        print("\n".join(section.markdown()))
