"""Animations rendered frame by frame, with structures kept between frames; resumable.

    result = animate("scene:satellite", frames=24, output="orbit")      # orbit/frame-0000.png, ...
    result = animate("ball.json", frames=48, output="ball.png")         # an animated PNG
    result = animate("ball.json", frames=48, output="ball.mp4")         # a video (raykernel[video])
    result.frames[3]["counters"]["rays.eye"], result.totals["rays.total"]

The scene is a JSON scene with an "animation" (keyframed motion, a camera path) or a generated
scene with a `time` parameter (scene:satellite). Frame i of N lies at time t0 + (t1 - t0) i /
(N - 1). Each frame is built from the one before (engine/incremental.py) unless
`incremental=False`; its image and ray counts are those of a from-scratch build either way.

Frames are written as they finish, each atomically, into OUT (a directory) or, for OUT.png
and OUT.mp4, into OUT.frames/, which is assembled into the animation at the end and then
removed. Beside them, frames.json holds each finished frame's time and counters (written
atomically after each frame): a render started again with the same options skips the frames
already written, says so, and takes their counters from there; with other options it stops
with an error instead of mixing frames of two renders.
"""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..atomicfile import atomic_write, write_text
from ..errors import OptionError, SceneError
from .imageio import save_png
from .stats import jsonable

__all__ = ["animate", "animation_of", "render_frame", "AnimationResult", "RECORD_FILE"]

RECORD_FILE = "frames.json"
SEGMENT = 8
DEFAULT_FRAMES = 24
MOVIE_SUFFIXES = (".png", ".mp4")


@dataclass
class AnimationResult:
    output: Path
    frames: list = field(default_factory=list)   # per frame: {"index", "time", "counters", "skipped"}
    totals: dict = field(default_factory=dict)   # every counter summed over the frames
    skipped: int = 0                             # frames found written by an earlier run

    def to_dict(self) -> dict:
        return {"output": str(self.output), "frames": self.frames, "totals": self.totals}


def animation_of(source, time=None):
    """(scene or None, Animation) of a scene source: a generated scene with a `time` parameter
    (a new scene per frame) or a scene whose file holds an animation."""
    from ..scene.animation import parameter_animation
    from ..scene.loading import load
    if isinstance(source, str) and source.startswith("scene:"):
        return None, parameter_animation(source, time)
    scene = load(source) if isinstance(source, (str, Path)) else source
    if scene.animation is None:
        raise SceneError(f"{scene.source or 'the scene'} does not move: give it an \"animation\", \"motion\" keys "
                         "or a camera \"path\" (docs/guide/animation.md), or use a scene with a time parameter "
                         "(scene:satellite)")
    return scene, scene.animation


def _scene_at(subject, t: float):
    """subject at time t: a scene with an animation (moved in place) or a generated Animation."""
    from ..scene.animation import Animation
    if isinstance(subject, Animation):
        return subject.at(None, t)
    return subject.animation.at(subject, t)


def render_frame(subject, t: float, hierarchy, options: dict):
    """The frame at time t: (8-bit image, its counters and info). subject: a scene with an
    animation (moved in place) or a generated Animation (which makes the scene)."""
    from .render import render
    result = render(_scene_at(subject, t), builder=hierarchy, **options)
    counters = {k: (v.item() if isinstance(v, np.generic) else v) for k, v in result.stats.items()}
    return result.to_uint8(), {"time": t, "counters": counters, "info": jsonable(result.stats.info)}


def render_segment(subject, times, indices, pending, options: dict, incremental: bool, threshold: float):
    """Yield (index, image, record) of the pending frames among `indices` (one segment, in
    order), all from one from-scratch build; a frame before them that was written already is
    built again but not traced, so the structures are those of an uninterrupted run."""
    from ..engine.incremental import Hierarchy
    hierarchy = Hierarchy(threshold, incremental=incremental)
    todo = [i for i in indices if i in pending]
    for i in indices:
        if not todo or i > todo[-1]:
            return
        if i in pending:
            yield (i, *render_frame(subject, times[i], hierarchy, options))
        elif incremental:
            hierarchy.flatten(_scene_at(subject, times[i]), options.get("accel", "bvh"), options.get("max_memory"))


def _totals(frames: list) -> dict:
    totals: dict = {}
    for f in frames:
        for k, v in f["counters"].items():
            if isinstance(v, (int, float)) and not isinstance(v, bool):
                totals[k] = totals.get(k, 0) + v
    per = max(1, totals.get("rays.total", 0))
    for k in [k for k in totals if k.endswith("_per_ray")]:      # ratios are recomputed, not summed
        del totals[k]
    totals["tests.per_ray"] = totals.get("tests.total", 0) / per
    totals["bounds.per_ray"] = totals.get("bounds.tests", 0) / per
    trace = totals.get("time.trace", 0.0)
    totals["time.rays_per_second"] = totals.get("rays.total", 0) / trace if trace > 0 else 0.0
    return totals


def _frames_dir(output: Path) -> tuple[Path, str | None]:
    suffix = output.suffix.lower()
    if suffix in MOVIE_SUFFIXES:
        return output.with_name(output.name + ".frames"), suffix
    if suffix:
        raise OptionError(f"{output}: an animation is written as a directory of PNG frames (no suffix), an "
                          f"animated PNG (.png) or a video (.mp4), not {suffix!r}")
    return output, None


def _frame_path(directory: Path, index: int) -> Path:
    return directory / f"frame-{index:04d}.png"


def _check_video():
    try:
        import imageio_ffmpeg
    except ImportError:
        raise OptionError("writing .mp4 needs imageio-ffmpeg: pip install 'raykernel[video]'") from None
    return imageio_ffmpeg


def _write_movie(frames_dir: Path, n: int, output: Path, kind: str, fps: float) -> None:
    from PIL import Image
    paths = [_frame_path(frames_dir, i) for i in range(n)]
    if kind == ".png":
        images = [Image.open(p) for p in paths]
        with atomic_write(output, "wb") as f:
            images[0].save(f, format="PNG", save_all=True, append_images=images[1:],
                           duration=int(round(1000.0 / fps)), loop=0)
        return
    ffmpeg = _check_video()
    first = np.asarray(Image.open(paths[0]).convert("RGB"))
    h, w = first.shape[:2]
    tmp = output.with_name(f".{output.name}.tmp.mp4")
    try:
        writer = ffmpeg.write_frames(str(tmp), (w, h), fps=fps, macro_block_size=1, quality=8,
                                     ffmpeg_log_level="error")
        writer.send(None)
        for p in paths:
            writer.send(np.ascontiguousarray(np.asarray(Image.open(p).convert("RGB"))))
        writer.close()
        tmp.replace(output)
    finally:
        tmp.unlink(missing_ok=True)


def animate(source, frames: int | None = None, time=None, fps: float | None = None, output=None,
            incremental: bool = True, rebuild_threshold: float = 1.5, segment: int = SEGMENT, stats_json=None,
            progress=None, cluster=None, log=None, **options) -> AnimationResult:
    """Render the frames of an animated scene (see the module docstring) and write them.

    frames: how many, spread evenly over the time range, both ends included (default 24); time: (t0, t1)
    (default: the animation's); fps: frames per second of the movie (default: the scene's, 24).
    output: a directory, OUT.png or OUT.mp4 (default: the scene's name as a directory).
    incremental: build each frame from the last (False: every frame from scratch).
    segment: frames built from one from-scratch build (the first of each run of `segment`),
    and the unit of work on a cluster: a frame's counters then do not depend on which process
    rendered it, nor on where an interrupted run stopped.
    stats_json: write each frame's counters and their sums there.
    progress: callable(done, total) in frames; log: callable(line) for what it skips.
    cluster: a cluster.Cluster to render the frames on, one task per frame.
    options: those of render() (accel, resolution, spd, threads, ...)."""
    scene, anim = animation_of(source, time)
    span = tuple(float(x) for x in (time if time is not None else anim.time))
    if len(span) != 2 or not span[1] >= span[0]:
        raise OptionError(f"time must be (start, end) with end >= start, got {time!r}")
    fps = float(fps if fps is not None else anim.fps)
    if not fps > 0.0:
        raise OptionError(f"fps must be > 0, got {fps!r}")
    if frames is None:
        frames = DEFAULT_FRAMES
    if isinstance(frames, bool) or not isinstance(frames, int) or frames < 1:
        raise OptionError(f"frames must be a positive integer, got {frames!r}")
    if isinstance(segment, bool) or not isinstance(segment, int) or segment < 1:
        raise OptionError(f"segment must be a positive integer, got {segment!r}")
    name = str(source) if isinstance(source, (str, Path)) else (scene.source or "animation")
    if output is None:
        output = Path(name.split(":")[1] if name.startswith(("scene:", "spd:", "example:")) else Path(name).stem)
    output = Path(output)
    frames_dir, movie = _frames_dir(output)
    if movie == ".mp4":
        _check_video()
    if not output.parent.is_dir():
        raise OptionError(f"{output}: directory {output.parent} does not exist")
    if stats_json is not None and not Path(stats_json).parent.is_dir():
        raise OptionError(f"{stats_json}: directory {Path(stats_json).parent} does not exist")
    times = anim.times(frames, span)
    from .render import render_options
    probe = scene if scene is not None else anim.at(None, times[0])
    render_options(probe, **options)      # bad options fail now
    identity = jsonable({"source": name, "times": times, "options": options, "incremental": incremental,
                       "rebuild_threshold": rebuild_threshold, "segment": segment})

    frames_dir.mkdir(exist_ok=True)
    records_path = frames_dir / RECORD_FILE
    records: dict = {}
    if records_path.exists():
        try:
            saved = json.loads(records_path.read_text())
        except (OSError, ValueError) as e:
            raise SceneError(f"cannot read the record of an earlier run: {e}; remove it to start again",
                             path=str(records_path)) from None
        if saved.get("identity") != identity:
            raise OptionError(f"{frames_dir} holds frames of another render (other scene, times or options); "
                              "remove them or write elsewhere")
        records = {int(k): v for k, v in saved.get("frames", {}).items() if _frame_path(frames_dir, int(k)).exists()}
    result = AnimationResult(output=output, skipped=len(records))
    if records and log is not None:
        log(f"resuming: {len(records)} of {frames} frames already in {frames_dir}, skipped")
    pending = [i for i in range(frames) if i not in records]

    def finished(i: int, image, record) -> None:
        save_png(image, _frame_path(frames_dir, i))
        records[i] = record
        write_text(records_path, json.dumps({"identity": identity, "frames": {str(k): records[k]
                                                                              for k in sorted(records)}}))
        if progress is not None:
            progress(len(records), frames)

    if progress is not None:
        progress(len(records), frames)
    subject = anim if scene is None else scene
    segments = [list(range(s, min(frames, s + segment))) for s in range(0, frames, segment)]
    segments = [seg for seg in segments if any(i not in records for i in seg)]
    work = (subject, times, pending, options, incremental, rebuild_threshold)
    if cluster is None:
        for seg in segments:
            for i, image, record in render_segment(subject, times, seg, set(pending), options, incremental,
                                                   rebuild_threshold):
                finished(i, image, record)
    else:
        cluster.animate(segments, work, finished)       # each segment a task on the cluster

    result.frames = [{"index": i, **records[i], "skipped": i not in pending} for i in range(frames)]
    result.totals = _totals(result.frames)
    if stats_json is not None:
        write_text(stats_json, json.dumps(jsonable(result.to_dict()), indent=1) + "\n")
    if movie is not None:
        _write_movie(frames_dir, frames, output, movie, fps)
        shutil.rmtree(frames_dir)
    return result
