"""Building a model database from an image dataset, in parallel, resumable.

Every image is fitted with the robot's own FrameFitter per (label, band) by a worker: a
local process pool by default, or a Dask distributed cluster. Results come back to one
writer in file-name order, so the database is the same whatever the executor and however
many workers ran. Each image is one capture of the "robot" `dataset:<absolute folder>`,
keyed by its file name (`source`); images already stored are skipped, so an interrupted
run continues where it stopped. With `keep_going`, an image that cannot be fitted (damaged,
unreadable, the wrong size for its mask) is skipped and named in the report instead.
"""
from __future__ import annotations

import collections
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Callable, Iterator

from tools.data.datasets import Angles, DatasetImage, Layout, scan
from tools.data.images import ImageError, fit_image, read_mask
from tools.store.database import Store
from tools.store.rows import DATASET_PREFIX

if TYPE_CHECKING:  # numpy and the fitter load with the first image, not with the command line
    from concurrent.futures import Executor

    import numpy as np

    from btf.dependence import Dependence
    from btf.fit.fitter import FittedModel
    from tools.store.database import Store

# Images per database commit, and the longest a fitted image waits for its commit.
BATCH_IMAGES = 64
BATCH_SECONDS = 1.0
# Feature spaces an ingest may store: pca needs a per-image basis the database does not hold.
INGEST_SPACES = ("rgb", "hsv", "gray", "raw")
NADIR = 90.0


class IngestError(ValueError):
    """A dataset, mask or executor problem; the message names it."""


@dataclass(frozen=True, slots=True)
class Job:
    """One image to fit: everything a worker needs, picklable."""

    name: str
    path: str
    mask: str | None
    space: str | None  # None: each image's own (gray for one band, rgb for colour, raw for other counts)
    dependence: bool = True  # measure grain and band correlation (btf.fit.dependence)
    names: tuple[str, ...] | None = None  # raw bands by name (None: B0..Bn-1)


@dataclass(frozen=True, slots=True)
class Fitted:
    name: str
    band_names: tuple[str, ...]
    results: dict[tuple[int, int], FittedModel]
    mask: np.ndarray | None  # the labels used, when they came from a per-image mask
    dependence: dict[int, Dependence] | None = None
    levels: int = 256
    space: str = "rgb"


@dataclass(frozen=True, slots=True)
class Damaged:
    """An image that could not be fitted, and why (with keep_going)."""

    name: str
    reason: str


@dataclass(frozen=True, slots=True)
class IngestReport:
    robot: str
    total: int
    skipped: int
    stored: int
    damaged: tuple[Damaged, ...] = ()


def dataset_robot(root: str | Path) -> str:
    """The robot id under which a dataset's captures are stored."""
    return f"{DATASET_PREFIX}{Path(root).resolve()}"


def fit_job(job: Job) -> Fitted:
    """Fit one image (runs in a worker). Raises IngestError naming the file."""
    try:
        fitted = fit_image(job.path, job.mask, job.space, dependence=job.dependence)
    except ValueError as exc:  # ImageError too
        raise IngestError(str(exc)) from None
    bands = tuple(fitted.feats.band_names)
    if job.names is not None:
        if fitted.feats.space.value != "raw" or len(job.names) != len(bands):
            raise IngestError(f"{job.path}: {len(job.names)} band names for its {len(bands)} "
                              f"{fitted.feats.space.value} bands ({', '.join(bands)}); band names are for raw bands")
        bands = job.names
    return Fitted(job.name, bands, fitted.results,
                  fitted.labels if job.mask else None, fitted.dependence, fitted.feats.levels,
                  fitted.feats.space.value)


def fit_or_damaged(job: Job) -> Fitted | Damaged:
    """fit_job, with a file that cannot be fitted returned as Damaged instead of raised."""
    try:
        return fit_job(job)
    except IngestError as exc:
        return Damaged(job.name, str(exc))


def _mask_for(image: DatasetImage, mask: Path | None) -> str | None:
    if mask is None:
        return None
    if mask.is_dir():  # one mask per image, same stem
        per_image = mask / (Path(image.name).stem + ".png")
        if not per_image.is_file():
            raise IngestError(f"mask {per_image}: no such file (masks folder has none for {image.name})")
        return str(per_image)
    return str(mask)


def _ordered(executor: Executor, fn: Callable[[Job], Fitted], jobs: list[Job],
             window: int) -> Iterator[Fitted]:
    """Results in job order with at most `window` jobs in flight (bounded memory)."""
    pending: collections.deque = collections.deque()
    it = iter(jobs)
    for job in it:
        pending.append(executor.submit(fn, job))
        if len(pending) >= window:
            break
    while pending:
        result = pending.popleft().result()
        nxt = next(it, None)
        if nxt is not None:
            pending.append(executor.submit(fn, nxt))
        yield result


def _executor(workers: int, scheduler: str | None):
    """(executor, closer, worker count) for a process pool or a Dask cluster."""
    if scheduler is None:
        from concurrent.futures import ProcessPoolExecutor

        pool = ProcessPoolExecutor(max_workers=workers)
        return pool, lambda: pool.shutdown(cancel_futures=True), workers
    from distributed import Client

    try:
        client = Client(scheduler, timeout="10s")
    except (OSError, TimeoutError, ValueError) as exc:
        raise IngestError(f"scheduler {scheduler}: cannot connect ({exc})") from None
    n = max(1, sum(w.get("nthreads", 1) for w in client.scheduler_info().get("workers", {}).values()))
    return client.get_executor(pure=False), client.close, n


def ingest(root: str | Path, layout: str | Layout, db: str | Path, *, mask: str | Path | None = None,
           space: str | None = None, workers: int | None = None, scheduler: str | None = None,
           table: str | Path | None = None, default_elevation: float = NADIR,
           on_total: Callable[[int], None] | None = None,
           on_image: Callable[[str], None] | None = None, keep_going: bool = False,
           dependence: bool = True, band_names: tuple[str, ...] | None = None) -> IngestReport:
    """Fit and store every not-yet-stored image of the dataset at `root`.

    `workers=0` fits in this process; otherwise a process pool of `workers` (default: the
    CPU count), or the Dask cluster at `scheduler` (e.g. tcp://host:8786). An image that
    cannot be fitted stops the run (IngestError), or with `keep_going` is skipped and
    listed in the report's `damaged`. Each region's grain and band correlation is measured
    and stored with its models unless `dependence` is False. `space` None fits each image in
    its own bands (gray for one band, rgb for colour); `band_names` names raw bands.
    """
    if space is not None and space not in INGEST_SPACES:
        raise IngestError(f"feature space {space!r}: ingest stores one of {', '.join(INGEST_SPACES)}")
    if not 0.0 <= default_elevation <= 90.0:
        raise IngestError(f"default elevation {default_elevation:g} outside 0..90 degrees")
    images = scan(root, layout, table)
    mask_path = None if mask is None else Path(mask)
    if mask_path is not None and not mask_path.exists():
        raise IngestError(f"mask {mask_path}: no such file or folder")
    robot = dataset_robot(root)
    with Store.open(db) as store:
        done = store.sources(robot)
        todo = [im for im in images if im.name not in done]
        jobs, unmasked = [], []
        for im in todo:
            try:
                jobs.append(Job(im.name, str(im.path), _mask_for(im, mask_path), space, dependence, band_names))
            except IngestError as exc:  # no mask of its own in the masks folder
                if not keep_going:
                    raise
                unmasked.append(Damaged(im.name, str(exc)))
        if mask_path is not None and mask_path.is_file() and jobs:
            try:
                store.add_mask(robot, read_mask(mask_path), robot)
            except ImageError as exc:
                raise IngestError(str(exc)) from None
        stored, damaged = 0, list(unmasked)
        if jobs:
            by_name = {im.name: im for im in todo}
            # connects before any work is shown
            results, close = _run(jobs, workers, scheduler, fit_or_damaged if keep_going else fit_job)
            try:
                if on_total:
                    on_total(len(jobs))
                for chunk in _batches(results, BATCH_IMAGES, BATCH_SECONDS):
                    # One commit per batch: an interrupted run redoes at most one batch.
                    with store.batch():
                        for fitted in chunk:
                            if isinstance(fitted, Damaged):
                                damaged.append(fitted)
                            else:
                                stored += _store(store, robot, by_name[fitted.name], fitted,
                                                 Path(root).name, default_elevation)
                    if on_image:
                        for fitted in chunk:
                            on_image(fitted.name)
            finally:
                close()
        elif on_total:
            on_total(0)
    return IngestReport(robot, len(images), len(images) - len(todo), stored, tuple(damaged))


def _batches(results: Iterator[Fitted], size: int, seconds: float) -> Iterator[list[Fitted]]:
    """Consecutive results in lists of at most `size`, cut early once `seconds` have passed."""
    chunk: list[Fitted] = []
    t0 = time.monotonic()
    try:
        for r in results:
            chunk.append(r)
            if len(chunk) >= size or time.monotonic() - t0 >= seconds:
                yield chunk
                chunk, t0 = [], time.monotonic()
    except Exception:
        if chunk:  # keep what was fitted before the failure; a resumed run skips it
            yield chunk
        raise
    if chunk:
        yield chunk


def _run(jobs: list[Job], workers: int | None, scheduler: str | None,
         fit: Callable[[Job], Fitted | Damaged] = fit_job) -> tuple[Iterator, Callable[[], object]]:
    """(results of `fit` in job order, closer of the executor)."""
    if scheduler is None and workers == 0:
        return map(fit, jobs), lambda: None
    n = workers or os.cpu_count() or 1
    if n < 0:
        raise IngestError(f"workers must be >= 0, got {n}")
    executor, close, n = _executor(n, scheduler)
    return _ordered(executor, fit, jobs, window=4 * n), close


def _store(store: Store, robot: str, image: DatasetImage, fitted: Fitted, scene: str,
           default_elevation: float) -> bool:
    """Stores one fitted image; False when its capture was already there."""
    a = image.angles or Angles(default_elevation, 0.0)
    seq = store.next_sequence(robot)
    # the file's modification time, so the database does not depend on when it was built
    mtime = image.path.stat().st_mtime
    light = (a.light_elevation, a.light_azimuth) if a.has_light else None
    if not store.add_capture(robot, seq, mtime, None, (a.elevation, a.azimuth), fitted.space, fitted.band_names,
                             fitted.results, scene=scene, illumination=light, source=image.name,
                             dependence=fitted.dependence, levels=fitted.levels):
        return False
    if fitted.mask is not None:
        store.add_mask(f"{robot}/{seq}", fitted.mask, robot)
    return True
