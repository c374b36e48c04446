"""Renders for the explorer, off the page's thread: the newest request wins.

    r = Renderer(scene, "scene:stadium")
    generation = r.submit(settings(["octree", "bvh"]))   # returns at once; a newer submit cancels it
    r.wait(generation)                                    # tests: until it is shown in full, or failed
    version, exploration, error, status = r.snapshot()   # what the page draws now

One worker thread renders each request twice: at 1/COARSE of its resolution first, then in full,
publishing each as it completes (the page polls `snapshot` and redraws when `version` moves). A
newer request makes the render in progress stop at its next look (model.CHUNK tiles or a few
dozen samples: well within a second at the resolutions the explorer draws; a structure's build
or a kernel's first compile is not interrupted). A bad request (a spec, a camera, a budget) is
its error message, shown in the page; the worker goes on to the next.
"""

from __future__ import annotations

import threading

from ..errors import RayKernelError
from .model import COARSE, Cancelled, Settings, explore_scene

SMALLEST_COARSE = 8     # no coarse pass below this resolution: the full one is as quick


class Renderer:
    def __init__(self, scene, label: str, max_memory=None, timed: bool = True):
        self.scene, self.label, self.max_memory, self.timed = scene, label, max_memory, timed
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
