"""Scenes that move: keyframed transforms, a camera path, frames of a scene's `time` parameter.

    scene = read_json("orbit.json")             # its "animation", "motion" and camera "path" keys
    anim = scene.animation
    for t in anim.times(frames=24):
        anim.at(scene, t)                       # moves the instances and the camera in place
        render(scene)

    anim = parameter_animation("scene:satellite")    # frames made by the generator: time=t
    frame = anim.at(None, 12.0)                      # a new Scene for each time

A `Motion` is a list of keyframes (time, translation, rotation as a unit quaternion, scale);
between keys the translation and scale are interpolated linearly and the rotation by slerp;
before the first key and after the last the motion holds still. An animated instance's matrix
at time t is motion(t) @ base: its static "transform" first, then the motion's scale, rotation
and translation. A `CameraPath` interpolates each camera field (eye, look_at, up, angle)
linearly over the keys that give it; a field no key gives keeps the camera's value.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..errors import SceneError
from .model import Camera, Instance, Scene

DEFAULT_FPS = 24.0
CAMERA_FIELDS = ("eye", "look_at", "up", "angle")


def axis_angle_quaternion(axis, degrees: float) -> np.ndarray:
    """The unit quaternion (w, x, y, z) of a right-handed rotation about `axis`."""
    axis = np.asarray(axis, np.float64)
    n = np.linalg.norm(axis)
    if not n > 0.0:
        raise SceneError("a rotation axis must not be zero")
    half = math.radians(float(degrees)) / 2.0
    return np.concatenate([[math.cos(half)], math.sin(half) * axis / n])


def quaternion_matrix(q) -> np.ndarray:
    """The 3x3 rotation of the unit quaternion q = (w, x, y, z)."""
    w, x, y, z = np.asarray(q, np.float64) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def slerp(q0, q1, u: float) -> np.ndarray:
    """Spherical linear interpolation from q0 (u = 0) to q1 (u = 1), the short way round."""
    q0, q1 = np.asarray(q0, np.float64), np.asarray(q1, np.float64)
    d = float(np.dot(q0, q1))
    if d < 0.0:             # q and -q are the same rotation: take the nearer
        q1, d = -q1, -d
    if d > 0.9995:          # nearly equal: the linear blend is exact to rounding and avoids 0/0
        q = q0 + u * (q1 - q0)
        return q / np.linalg.norm(q)
    theta = math.acos(min(1.0, d))
    s = math.sin(theta)
    return (math.sin((1.0 - u) * theta) * q0 + math.sin(u * theta) * q1) / s


def _bracket(times: np.ndarray, t: float):
    """(i, j, u): the keys around t and how far t lies from i to j (clamped at the ends)."""
    if t <= times[0]:
        return 0, 0, 0.0
    if t >= times[-1]:
        return len(times) - 1, len(times) - 1, 0.0
    j = int(np.searchsorted(times, t, side="right"))
    i = j - 1
    return i, j, (t - times[i]) / (times[j] - times[i])


@dataclass
class Keyframe:
    time: float
    translate: np.ndarray = field(default_factory=lambda: np.zeros(3))
    rotate: np.ndarray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0, 0.0]))   # unit quaternion w, x, y, z
    scale: np.ndarray = field(default_factory=lambda: np.ones(3))


class Motion:
    """Keyframes of a moving instance, in increasing time."""

    def __init__(self, keys: list[Keyframe]):
        if not keys:
            raise SceneError("a motion needs at least one keyframe")
        times = np.array([k.time for k in keys], np.float64)
        if np.any(np.diff(times) <= 0.0):
            raise SceneError(f"keyframe times must increase, got {times.tolist()}")
        self.keys = keys
        self.times = times

    def matrix(self, t: float) -> np.ndarray:
        """The 4x4 motion at time t: scale, then rotate, then translate."""
        i, j, u = _bracket(self.times, t)
        a, b = self.keys[i], self.keys[j]
        m = np.eye(4)
        m[:3, :3] = quaternion_matrix(slerp(a.rotate, b.rotate, u)) * ((1 - u) * a.scale + u * b.scale)
        m[:3, 3] = (1 - u) * a.translate + u * b.translate
        return m

    @property
    def span(self) -> tuple[float, float]:
        return float(self.times[0]), float(self.times[-1])


class CameraPath:
    """Camera keys: dicts with "time" and any of eye, look_at, up (3 numbers) and angle."""

    def __init__(self, keys: list[dict]):
        if not keys:
            raise SceneError("a camera path needs at least one key")
        times = np.array([k["time"] for k in keys], np.float64)
        if np.any(np.diff(times) <= 0.0):
            raise SceneError(f"camera path times must increase, got {times.tolist()}")
        self.keys = keys
        self.times = times

    def camera(self, base: Camera, t: float) -> Camera:
        values = {}
        for name in CAMERA_FIELDS:
            given = [(k["time"], np.asarray(k[name], np.float64)) for k in self.keys if name in k]
            if not given:
                continue
            times = np.array([g[0] for g in given])
            i, j, u = _bracket(times, t)
            values[name] = (1 - u) * given[i][1] + u * given[j][1]
        kw = dict(eye=base.eye, look_at=base.look_at, up=base.up, angle=base.angle, hither=base.hither,
                  width=base.width, height=base.height, medium=base.medium)
        kw.update(values)
        if "angle" in values:
            kw["angle"] = float(values["angle"])
        try:
            return Camera(**kw)
        except SceneError as e:
            raise SceneError(f"camera path at time {t:g}: {e.message}") from None

    @property
    def span(self) -> tuple[float, float]:
        return float(self.times[0]), float(self.times[-1])


@dataclass
class Animation:
    """What moves in a scene and over which times.

    time: (start, end) of the animation; fps: frames per second of the written movie.
    motions: (instance, base matrix, Motion) of each moving instance.
    camera: the camera path (None: the camera stays), from `base_camera`.
    generate: for a parameterised scene, time -> Scene (a new scene per frame)."""

    time: tuple[float, float] = (0.0, 1.0)
    fps: float = DEFAULT_FPS
    motions: list = field(default_factory=list)
    camera: CameraPath | None = None
    base_camera: Camera | None = None
    generate: object = None
    source: str = ""

    def times(self, frames: int, time: tuple[float, float] | None = None) -> list[float]:
        """`frames` times spread evenly from the start to the end (both included)."""
        t0, t1 = self.time if time is None else time
        if frames == 1:
            return [float(t0)]
        return [float(t0 + (t1 - t0) * i / (frames - 1)) for i in range(frames)]

    def at(self, scene: Scene | None, t: float) -> Scene:
        """The scene at time t: moved in place (keyframes), or made anew (a generator)."""
        if self.generate is not None:
            return self.generate(t)
        for instance, base, motion in self.motions:
            instance.matrix = motion.matrix(t) @ base
        if self.camera is not None:
            cam = self.camera.camera(self.base_camera or scene.camera, t)
            if self.base_camera is None:
                self.base_camera = scene.camera
            scene.camera = cam
        return scene

    def motion_of(self, instance: Instance):
        """(base, Motion) of a moving instance, else None."""
        for inst, base, motion in self.motions:
            if inst is instance:
                return base, motion
        return None


def default_span(motions, camera) -> tuple[float, float]:
    """From the first key to the last of all motions and the camera path; (0, 1) without keys."""
    spans = [m.span for _, _, m in motions] + ([camera.span] if camera is not None else [])
    if not spans:
        return (0.0, 1.0)
    lo, hi = min(s[0] for s in spans), max(s[1] for s in spans)
    return (lo, hi) if hi > lo else (lo, lo + 1.0)


def parameter_animation(source: str, time: tuple[float, float] | None = None) -> Animation:
    """The animation of a generated scene ("scene:NAME[:k=v,...]") whose generator takes `time`:
    each frame is the generator's scene at time=t, the other parameters as given."""
    from . import pathological
    prefix, _, rest = source.partition(":")
    if prefix != "scene" or not rest:
        raise SceneError(f"{source}: only scene:NAME sources are generated per frame")
    name, params = pathological._split(rest)
    if "time" not in pathological.PARAMS.get(name, {}):
        raise SceneError(f"{source}: scene {name!r} has no time parameter, so it does not move; "
                         "the scenes that move: " + ", ".join(n for n, p in pathological.PARAMS.items() if "time" in p))
    params.pop("time", None)
    span = time or pathological.TIME_SPANS.get(name, (0.0, 1.0))
    return Animation(time=tuple(span), generate=_Generated(name, params), source=source)


@dataclass(frozen=True)
class _Generated:
    """time -> the generated scene at that time (a class, not a closure, so that it pickles)."""

    name: str
    params: dict

    def __call__(self, t: float) -> Scene:
        from . import pathological
        return pathological.load(self.name, **self.params, time=t)
