"""The operator page's view of the database: the latest capture at each pose (read on a thread
of its own, with its own connection, so the station's loop never waits on a query), and each
capture's section and images (`tools.page.drawing`: the report's own), drawn in a worker process
so that synthesis and plotting never hold the station's interpreter, nor load in it. The worker
draws one thing at a time, what the operator chose (a section, its histograms) before the cards'
pictures; a capture's first drawing with grain and band correlation costs most (a few tenths of a
second: the correlations of its normal scores are solved for), later ones reuse that.
"""
from __future__ import annotations

import asyncio
import contextlib
import heapq
import itertools
import multiprocessing
import os
from collections import OrderedDict
from concurrent.futures import Future, ProcessPoolExecutor, ThreadPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from pathlib import Path
from typing import Any, Mapping

from radio.packets.base import iso_time
from tools.analysis.radiometry import describe
from tools.report.look import azimuth_shown
from tools.store.database import Store

CACHED = 128  # rendered captures kept (thumbnails and sections)


def pose_key(c: Any) -> str:
    """One pose of one robot: the commanded angles (measured for captures without them), to 0.1°."""
    el, az = (c.commanded if c.commanded[0] is not None else c.measured)
    return f"{c.robot}|{el:.1f}|{(az or 0.0) % 360.0:.1f}"


def card(c: Any) -> dict:
    """A capture as the page lists it."""
    return {"id": c.id, "key": pose_key(c), "robot": c.robot, "seq": c.sequence, "scene": c.scene,
            "elevation": round(c.measured[0], 2), "azimuth": azimuth_shown(c.measured[1]),
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
            shown = card(c)
            shown["space_auto"] = self.store.space_choice(c.id)  # None: the space was configured
            changed[pose_key(c)] = self.latest[pose_key(c)] = shown
        return list(changed.values())

    def close(self) -> None:
        if self.store is not None:
            self.store.close()


# -- the worker process ---------------------------------------------------------------------
# The drawings are tools.page.drawing's: it loads the synthesis, OpenCV and matplotlib, which
# the workers need and the station does not (a second and more of every station's start).


def _drawing():
    from tools.page import drawing  # the drawing libraries: loaded in the workers, never the station

    return drawing


def render(db: str, capture_id: int, fake: Any, what: str, rev: int) -> dict:
    """In the worker: one capture's drawing (`tools.page.drawing.render`)."""
    return _drawing().render(db, capture_id, fake, what, rev)


def _panel(db: str, params: dict) -> dict:
    """In the worker: the BTF panel (`tools.page.btf_panel.panel`)."""
    return _drawing().panel(db, params)


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


def _worker_start(station: int) -> None:
    """The drawing worker's start: it ends with the station (pid `station`), and leaves Ctrl-C
    (which the terminal sends its whole process group) to the station, which shuts it down."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)
    end_with_parent(station)


def _loaded() -> None:
    """Sent to a new worker so that it loads the drawing libraries before the first request."""
    _drawing()


def _warm() -> None:
    """In a new worker: the drawing libraries loaded and one plot drawn (`tools.page.drawing.warm`)."""
    _drawing().warm()


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
        self._pending: dict[tuple[int, str, int], asyncio.Future] = {}  # asked for, not drawn yet
        self._waiters: dict[tuple[int, str, int], int] = {}  # requests still waiting for each
        self._queue: list[tuple[int, int, tuple[int, str, int]]] = []  # (urgency, order, key): a heap
        self._order = itertools.count()
        self._drawing: asyncio.Task | None = None
        self._warmed: Future | None = None
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
                                             initializer=_worker_start, initargs=(os.getpid(),))
            self._warmed = self._pool.submit(_warm)
        if self._btf_pool is None:  # its own process: the panel never waits behind a capture's drawing
            self._btf_pool = ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn"),
                                                 initializer=_worker_start, initargs=(os.getpid(),))
            self._btf_pool.submit(_loaded)

    async def warm(self) -> None:
        """Returns once the drawing worker has loaded its libraries (at once if it failed to)."""
        self.start_worker()
        with contextlib.suppress(Exception):  # a worker that cannot start says so at its first drawing
            await asyncio.wrap_future(self._warmed)

    async def drawn(self, capture_id: int, what: str) -> dict:
        """A drawing (`render`): from the cache, or queued for the worker one at a time, a capture's
        section and histograms before any thumbnail (what the operator chose first, the cards after)."""
        key = (capture_id, what, self.rev)
        if key in self._cache:
            self._cache.move_to_end(key)
            return self._cache[key]
        if key not in self._pending:  # asked twice: drawn once
            self._pending[key] = asyncio.get_running_loop().create_future()
            # a page that went away leaves no failure unretrieved (asyncio would log it)
            self._pending[key].add_done_callback(lambda f: f.cancelled() or f.exception())
            heapq.heappush(self._queue, (1 if what == "thumb" else 0, next(self._order), key))
            if self._drawing is None or self._drawing.done():
                self._drawing = asyncio.ensure_future(self._draw_queued())
        self._waiters[key] = self._waiters.get(key, 0) + 1
        try:
            return await asyncio.shield(self._pending[key])
        finally:  # a page that went away (or chose another capture) no longer waits
            self._waiters[key] -= 1
            if not self._waiters[key]:
                del self._waiters[key]

    async def _draw_queued(self) -> None:
        """Draws what is queued, each at the revision in force when its turn comes: a drawing asked
        for before a mask arrived is made once, new, for every request of it under any revision; one
        that no request waits for any more (the page went on to a newer capture) is not made."""
        loop = asyncio.get_running_loop()
        while self._queue:
            key = heapq.heappop(self._queue)[2]
            if key not in self._pending:  # drawn already, when asked for under a later revision
                continue
            now = (key[0], key[1], self.rev)
            waiting = [self._pending.pop(k) for k in {key, now} if k in self._pending]
            if not (self._waiters.get(key) or self._waiters.get(now)):  # nobody waits for it any more
                for done in waiting:
                    done.cancel()
                continue
            self.start_worker()
            try:
                out = self._cache.get(now) or await loop.run_in_executor(
                    self._pool, render, self.db, now[0], self.fake, now[1], now[2])
            except BrokenProcessPool:  # the worker died (killed, out of memory): a new one next time
                self._pool = None
                failed = RuntimeError("the drawing worker stopped; reload to try again")
            except Exception as exc:  # noqa: BLE001 - a drawing that fails is said by the page's request, in one line
                failed = exc
            else:
                failed = None
                if now[2] == self.rev:  # not if a mask arrived meanwhile: asked for again, drawn again
                    self._cache[now] = out
                while len(self._cache) > CACHED:
                    self._cache.popitem(last=False)
            for done in waiting:
                if failed is None:
                    done.set_result(out)
                else:
                    done.set_exception(failed)

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
                out = await asyncio.get_running_loop().run_in_executor(self._btf_pool, _panel, self.db, params)
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
