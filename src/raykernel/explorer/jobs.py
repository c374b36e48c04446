"""Renders for the explorer, off the page's thread: one Renderer a browser tab, the newest request wins.

    r = Renderer(scene, "scene:stadium")
    generation = r.submit(settings(["octree", "bvh"]))   # returns at once; a newer submit cancels it
    r.wait(generation)                                    # tests: until it is shown in full, or failed
    version, exploration, error, status = r.snapshot()   # what the page draws now

    warm = Warmup(scene, ["octree", "bvh"])               # compiles the kernels now, in a thread
    tabs = Sessions(scene, "scene:stadium", settings(["octree", "bvh"]), ready=warm.done)
    sid = tabs.issue()                    # a page load's id (signed: a forged one is refused)
    tabs.get(sid)                         # its Renderer, made (and its first render begun) on first use

One worker thread renders each request twice: at 1/COARSE of its resolution first, then in full,
publishing each as it completes (the page polls `snapshot` and redraws when `version` moves). A
newer request makes the render in progress stop at its next look: before each chunk of tiles
(model.CHUNK) or of samples (model.SAMPLE_CHUNK), well within a second at the resolutions the
explorer draws. A structure's build and a kernel's first compile are not interrupted, so the
server warms the kernels (Warmup: a 2x2 render of each structure, its per-sample trace, its
timing and one explained sample) as it starts, and a request waits, cancellably, until that is
done rather than compile beside it. A bad request (a spec, a camera, a budget) is its error
message, shown in the page; the worker goes on to the next.

Each page load gets a session id, signed with the server's secret, and its own Renderer the
first time it asks: at most MAX_SESSIONS at once, the least recently used closed to make room
(a tab still polling is used every POLL_MS), each with 1/MAX_SESSIONS of the memory budget so
that together they hold it. A closed session's tab is told to reload; an id the server did not
sign finds nothing.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
import threading
from collections import OrderedDict, deque

from ..aggregates.memory import memory_limit
from ..errors import OptionError, RayKernelError
from .model import COARSE, Cancelled, Settings, explore_scene, settings

SMALLEST_COARSE = 8     # no coarse pass below this resolution: the full one is as quick
MAX_SESSIONS = 4        # browser tabs rendering at once
WARM_RESOLUTION = 2     # the warm-up's render: 2x2 samples


class Renderer:
    def __init__(self, scene, label: str, max_memory=None, timed: bool = True, ready=None):
        self.scene, self.label, self.max_memory, self.timed = scene, label, max_memory, timed
        self.ready = ready          # a threading.Event set once the kernels are warm (None: now)
        self.generation = 0         # of the newest request
        self.version = 0            # moves each time something new is shown
        self.exploration = None     # what is shown: the newest complete render
        self.error = None           # (generation, message) of the newest failed request
        self.status = "idle"
        self._wanted = None
        self._done = {}             # generation -> "full", "failed" or "cancelled"
        self._closed = False
        self._cond = threading.Condition()
        self._thread = threading.Thread(target=self._loop, name="raykernel-explore-render", daemon=True)
        self._thread.start()

    def submit(self, s: Settings) -> int:
        with self._cond:
            if self._wanted is not None:        # replaced before it started
                self._done[self._wanted[0]] = "cancelled"
            self.generation += 1
            self._wanted = (self.generation, s)
            self.error = None
            self.status = f"request {self.generation} waiting"
            self._cond.notify_all()
            return self.generation

    def reject(self, message: str) -> None:
        """A request the page could not make (a bad spec or number): shown as the error; the
        render in progress goes on."""
        with self._cond:
            self.error = (None, message)
            self.version += 1

    def close(self) -> None:
        """Stop the render in progress and the worker."""
        with self._cond:
            self.generation += 1
            self._closed = True
            self._cond.notify_all()

    def snapshot(self):
        with self._cond:
            return self.version, self.exploration, self.error, self.status

    def outcome(self, generation: int):
        with self._cond:
            return self._done.get(generation)

    def wait(self, generation: int, timeout: float | None = None) -> str | None:
        """"full", "failed" or "cancelled" once request `generation` is settled (None: timed out)."""
        with self._cond:
            self._cond.wait_for(lambda: generation in self._done, timeout)
            return self._done.get(generation)

    def _current(self, generation: int) -> bool:
        return self.generation == generation

    def _loop(self) -> None:
        while True:
            with self._cond:
                self._cond.wait_for(lambda: self._wanted is not None or self._closed)
                if self._closed:
                    return
                generation, s = self._wanted
                self._wanted = None
            self._settle(generation, self._render(generation, s))

    def _render(self, generation: int, s: Settings) -> str:
        cancelled = lambda: not self._current(generation)      # noqa: E731
        stages = [("coarse", s.resolution // COARSE)] if s.resolution // COARSE >= SMALLEST_COARSE else []
        if self.ready is not None and not self.ready.is_set():
            self._set_status(generation, f"request {generation}: waiting for the kernels to warm up")
            while not self.ready.wait(0.05):        # a compile cannot be stopped: wait, cancellably
                if cancelled():
                    return "cancelled"
        try:
            for stage, res in stages + [("full", s.resolution)]:
                self._set_status(generation, f"request {generation}: rendering {stage} ({res}x{res})")
                ex = explore_scene(self.scene, s, self.label, res, cancelled, self.max_memory,
                                   self.timed and stage == "full")
                ex.stage = stage
                with self._cond:
                    if not self._current(generation):
                        return "cancelled"
                    self.exploration, self.error = ex, None
                    self.version += 1
            return "full"
        except Cancelled:
            return "cancelled"
        except (RayKernelError, ValueError) as e:
            with self._cond:
                if self._current(generation):
                    self.error = (generation, f"{type(e).__name__}: {e}")
                    self.version += 1
            return "failed"

    def _set_status(self, generation: int, text: str) -> None:
        with self._cond:
            if self._current(generation):
                self.status = text

    def _settle(self, generation: int, how: str) -> None:
        with self._cond:
            self._done[generation] = how
            if self._current(generation):
                self.status = {"full": "done", "failed": "failed", "cancelled": "cancelled"}[how]
            self._cond.notify_all()


class Warmup:
    """The explorer's kernels compiled (or loaded from numba's cache) for each structure, in a
    thread: a WARM_RESOLUTION render with its per-sample trace and tile times, and one explained
    sample. `done` is set when it ends; `status` says where it is; `warmed` lists the structures
    done (a structure that fails is left to its request, which shows the error)."""

    def __init__(self, scene, accels, max_memory=None, timed: bool = True):
        self.scene, self.accels, self.max_memory, self.timed = scene, list(accels), max_memory, timed
        self.done = threading.Event()
        self.warmed = []
        self.status = "kernels: warming up"
        self._thread = threading.Thread(target=self._run, name="raykernel-explore-warmup", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        from ..rendering.explain import explain
        try:
            for k, accel in enumerate(self.accels):
                self.status = (f"kernels: warming up {accel} ({k + 1} of {len(self.accels)}); "
                               "a request waits for this, as a compile cannot be stopped")
                try:
                    explore_scene(self.scene, settings([accel], WARM_RESOLUTION), "warm-up", None, None,
                                  self.max_memory, self.timed)
                    explain(self.scene, 0, 0, accel=accel, resolution=WARM_RESOLUTION, max_memory=self.max_memory)
                    self.warmed.append(accel)
                except (RayKernelError, ValueError):
                    pass
            self.status = "kernels: ready"
        finally:
            self.done.set()


class Sessions:
    """One Renderer a browser tab (the module's docstring)."""

    def __init__(self, scene, label: str, s: Settings, max_memory=None, timed: bool = True, ready=None,
                 limit: int = MAX_SESSIONS):
        self.scene, self.label, self.settings, self.timed, self.ready, self.limit = scene, label, s, timed, ready, limit
        self.total = memory_limit(max_memory)
        self.share = self.total // limit            # each session's budget: together they hold the total
        self._secret = secrets.token_bytes(32)
        self._live = OrderedDict()                  # id -> Renderer, least recently used first
        self._closed = deque(maxlen=1024)           # ids closed to make room: their tabs are told so
        self._lock = threading.Lock()

    def issue(self) -> str:
        """A new session id, signed: the server keeps nothing until it is used."""
        nonce = secrets.token_urlsafe(12)
        return f"{nonce}.{self._sign(nonce)}"

    def _sign(self, nonce: str) -> str:
        return hmac.new(self._secret, nonce.encode(), hashlib.sha256).hexdigest()[:32]

    def valid(self, sid) -> bool:
        if not isinstance(sid, str) or sid.count(".") != 1:
            return False
        nonce, mac = sid.split(".")
        return hmac.compare_digest(mac, self._sign(nonce))

    def get(self, sid) -> Renderer:
        """The Renderer of session `sid`, made on its first use (its first request: the settings the
        server opened with); OptionError for an id this server did not sign, or one closed."""
        if not self.valid(sid):
            raise OptionError("this page's session is not one this server began: reload the page")
        with self._lock:
            if sid in self._live:
                self._live.move_to_end(sid)
                return self._live[sid]
            if sid in self._closed:
                raise OptionError(f"this tab's session was closed to make room for a newer tab (at most "
                                  f"{self.limit} at once): reload the page")
            while len(self._live) >= self.limit:
                idle = [k for k, r in self._live.items() if r.snapshot()[3] in ("idle", "done", "failed", "cancelled")]
                old = idle[0] if idle else next(iter(self._live))       # the oldest idle one, else the oldest
                self._live.pop(old).close()
                self._closed.append(old)
            r = Renderer(self.scene, self.label, self.share, self.timed, self.ready)
            self._live[sid] = r
        r.submit(self.settings)
        return r

    def live(self) -> dict:
        with self._lock:
            return dict(self._live)

    def newest(self) -> Renderer | None:
        """The Renderer of the session used last (tests: the one tab a browser opened)."""
        with self._lock:
            return next(reversed(self._live.values()), None)

    def close(self) -> None:
        with self._lock:
            for r in self._live.values():
                r.close()
            self._closed.extend(self._live)
            self._live.clear()
