"""The operator page's view of the database: the latest capture at each pose (read on a thread
of its own, with its own connection, so the station's loop never waits on a query), and each
capture's section and images (`tools.report.look`, `tools.report.capture_views`: the report's own), drawn in a
worker process so that synthesis and plotting never hold the station's interpreter.
"""
from __future__ import annotations

import asyncio
import multiprocessing
import os
from collections import OrderedDict
from concurrent.futures import ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any, Mapping

from radio.packets.base import iso_time
from tools.analysis.radiometry import describe
from tools.page.btf_panel import panel
from tools.report.capture_views import Frames, png, views
from tools.report.look import capture_section
from tools.store.database import Store

CACHED = 128  # rendered captures kept (thumbnails and sections)
SHOWN_FIRST = "correlated", "independent", "measured"  # a card's picture: the likest to the surface


def pose_key(c: Any) -> str:
    """One pose of one robot: the commanded angles (measured for captures without them), to 0.1°."""
    el, az = (c.commanded if c.commanded[0] is not None else c.measured)
    return f"{c.robot}|{el:.1f}|{(az or 0.0) % 360.0:.1f}"


def card(c: Any) -> dict:
    """A capture as the page lists it."""
    return {"id": c.id, "key": pose_key(c), "robot": c.robot, "seq": c.sequence, "scene": c.scene,
            "elevation": round(c.measured[0], 2), "azimuth": round(c.measured[1], 2),
            "commanded": None if c.commanded[0] is None else [c.commanded[0], c.commanded[1]],
            "time": iso_time(c.time), "space": c.space, "camera": describe(c.camera),
            "unlocked": bool(c.camera is not None and c.camera.unlocked)}


class CaptureIndex:
    """The latest capture per pose; `refresh()` reads what was stored since the last call.
    Touched on the reader thread only (its Store is that thread's)."""

    def __init__(self, db: str) -> None:
        self.db, self.store, self.last_id = db, None, 0
        self.latest: dict[str, dict] = {}
        self.count = 0

    def refresh(self) -> list[dict]:
        """The cards that changed (a new latest capture at their pose)."""
        if self.store is None:
            self.store = Store.open(self.db, create=False)
        changed = {}
        for c in sorted(self.store.captures_after(self.last_id), key=lambda c: c.id):
            self.last_id, self.count = c.id, self.count + 1
            changed[pose_key(c)] = self.latest[pose_key(c)] = card(c)
        return list(changed.values())

    def close(self) -> None:
        if self.store is not None:
            self.store.close()


# -- the worker process ---------------------------------------------------------------------
_worker_store: dict[str, Any] = {}


def render(db: str, capture_id: int, fake: Any, what: str, rev: int) -> dict:
    """In the worker: `what` "thumb" ({"png"}: the card's picture) or "section" ({"html",
    "images": {name: png}}) of one capture; {"missing": text} when there is nothing to draw."""
    import numpy as np


    store = _worker_store.get(db)
    if store is None:
        store = _worker_store[db] = Store.open(db, create=False)
    cap = store.capture_by_id(capture_id)
    if cap is None:
        return {"missing": f"no capture {capture_id} in the database"}
    rng = np.random.default_rng(capture_id)  # the same drawing every time
    if what == "thumb":  # the synthesis, or the measured frame when there is none
        v = views(store, cap, rng, None, histograms=False)
        if not v.images:
            v = views(store, cap, rng, Frames(fake), histograms=False)
        name = next((k for k in SHOWN_FIRST if k in v.images), None)
        return {"png": png(v.images[name])} if name else {"missing": v.problem or "nothing to draw"}
    v = views(store, cap, rng, Frames(fake))
    html = capture_section(v, lambda k: f"capture/{capture_id}/{k}.png?r={rev}")
    return {"html": html, "images": {k: png(img) for k, img in v.images.items()}}


def end_with_parent(parent: int | None = None) -> None:
    """In a child process of the station: SIGTERM when the station dies, even by SIGKILL
    (Linux's PR_SET_PDEATHSIG), so no drawing worker or demo robot outlives it. `parent`: the
    station's pid, for a child that starts slowly (a spawned worker): if the station died before
    this ran, no signal would come, so the child ends now."""
    import ctypes
    import signal

    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError):
        return  # not Linux: the station's own exit path ends them
    if parent is not None and os.getppid() != parent:
        os.kill(os.getpid(), signal.SIGTERM)


def _warm() -> None:
    """Load the worker's libraries before the first request needs them."""


def btf_query(query: Mapping[str, str]) -> dict:
    """The BTF panel's parameters from the address's query (text), checked (ValueError: which one)."""
    out: dict[str, Any] = {k: query.get(k) or None for k in ("robot", "scene", "space")}
    if query.get("scene") == "":
        out["scene"] = ""  # a robot's captures without a scene name
    for name in ("label", "band"):
        v = query.get(name) or ""
        if v and (not v.isdigit() or len(v) > 6):
            raise ValueError(f"{name} must be a small non-negative integer, got {v[:20]!r}")
        out[name] = int(v) if v else None
    return out


class PageData:
    """The page's reads and drawings, off the station's loop: `cards()`, `refresh()` and
    `drawn(capture_id, what)` are awaited on the loop."""

    def __init__(self, db: str, fake: Any = None) -> None:
        self.db, self.fake = str(db), fake
        self.index = CaptureIndex(self.db)
        self._reader = ThreadPoolExecutor(1, thread_name_prefix="page-reader")
        self._pool: ProcessPoolExecutor | None = None
        self._btf_pool: ProcessPoolExecutor | None = None
        self._cache: OrderedDict[tuple[int, str, int], dict] = OrderedDict()
        self.rev = 0  # bumped when a mask arrives: drawings made before it may lack it
        self._btf: dict[tuple, dict] = {}  # the BTF panel's last answer

    async def refresh(self) -> list[dict]:
        return await asyncio.get_running_loop().run_in_executor(self._reader, self.index.refresh)

    def cards(self) -> list[dict]:
        return sorted(self.index.latest.values(), key=lambda c: (-c["elevation"], c["azimuth"], c["robot"]))

    def mask_arrived(self) -> None:
        self.rev += 1
        self._cache.clear()

    def start_worker(self) -> None:
        if self._pool is None:
            self._pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"),
                                             initializer=end_with_parent, initargs=(os.getpid(),))
            self._pool.submit(_warm)
        if self._btf_pool is None:  # its own process: the panel never waits behind a capture's drawing
            self._btf_pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"),
                                                 initializer=end_with_parent, initargs=(os.getpid(),))
            self._btf_pool.submit(_warm)

    async def drawn(self, capture_id: int, what: str) -> dict:
        key = (capture_id, what, self.rev)
        if key in self._cache:
            self._cache.move_to_end(key)
            return self._cache[key]
        self.start_worker()
        loop = asyncio.get_running_loop()
        try:
            out = await loop.run_in_executor(self._pool, render, self.db, capture_id, self.fake, what, self.rev)
        except BrokenProcessPool:  # the worker died (killed, out of memory): a new one next time
            self._pool = None
            raise RuntimeError("the drawing worker stopped; reload to try again") from None
        self._cache[key] = out
        while len(self._cache) > CACHED:
            self._cache.popitem(last=False)
        return out

    async def btf(self, query: Mapping[str, str]) -> tuple[int, dict]:
        """(HTTP status, JSON) of the BTF panel (`tools.page.btf_panel`), computed in a worker and
        kept until the next capture is stored."""
        try:
            params = btf_query(query)
        except ValueError as exc:
            return 400, {"error": str(exc)}
        key = ("btf", self.index.last_id, *sorted(params.items()))
        if key not in self._btf:
            self.start_worker()
            try:
                out = await asyncio.get_running_loop().run_in_executor(self._btf_pool, panel, self.db, params)
            except BrokenProcessPool:
                self._btf_pool = None
                return 503, {"error": "the drawing worker stopped; it restarts with the next request"}
            except Exception as exc:  # a BTF the worker cannot compute: said, never a traceback
                return 500, {"error": f"{type(exc).__name__}: {exc}".splitlines()[0]}
            self._btf = {key: out}  # the latest capture's only: older ones are stale
        return 200, self._btf[key]

    def close(self) -> None:
        self._reader.submit(self.index.close).result()
        self._reader.shutdown()
        for pool in (self._pool, self._btf_pool):
            if pool is not None:
                pool.shutdown(wait=True, cancel_futures=True)


def static_dir() -> Path:
    return Path(__file__).with_name("static")
