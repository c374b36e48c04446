"""RayScene's queries on Dask arrays: lazily, chunk by chunk, the numpy call's answers bit for bit.

    import dask.array as da
    origins, directions = da.from_zarr("rays.zarr", "origins"), da.from_zarr("rays.zarr", "directions")
    hits = scene.intersect(origins, directions, fields=("t", "prim_id"))   # a Hits of dask arrays: nothing cast yet
    da.to_zarr(hits.t, "t.zarr")        # each chunk of rays cast by the scheduler in use (threads, or a Cluster)

RayScene's ray and point queries come here when an argument is a dask array (`is_dask`, which
imports nothing); numpy arguments never do. Each chunk of rays (or points) is one task calling the
numpy method on that chunk, so every answer is the numpy call's, whatever the chunking; the
chunks are those of `origins` (or `points`) along their leading axes, and the other arguments
are brought to them. A query with several outputs (intersect's Hits, closest_points) makes one
task a chunk that returns a structured block, and each field is a view of it: compute the fields
together (``dask.compute(hits.t, hits.prim_id)``, ``da.store``) to cast once.

The scene is one key of the graph (`scene_task`, one name per RayScene), which Dask sends to
each worker once per computation, already built: pickling a built RayScene measured faster than
sending its triangles and building them again on every worker (bench/cast.py). A worker keeps
the first copy of a scene it meets (`worker_scene`, the last SCENES_KEPT scenes), so what a
scene builds on its first query there (the point index, the general arrays of a mesh) is
built once per worker and kept for later calls.

Argument errors (shape, dtype, a `tmin` that is not a number or an array of the rays' shape)
raise RayInputError when the query is made; a bad ray raises it when its chunk is computed,
naming the chunk and the ray by its index in the whole array.
"""

from __future__ import annotations

import threading
import uuid
import weakref
from collections import OrderedDict

import numpy as np

from .rayinput import RayInputError, check_ray_values, real_array
from .rayqueries import DTYPES, FIELD_COLUMNS, FLOAT_FIELDS, HIT_FIELDS, field_names
from .sharedscene import SharedScene

SCENES_KEPT = 4         # scenes a worker process keeps (the last ones used)

_names: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()     # RayScene -> its key in graphs
_kept: OrderedDict = OrderedDict()      # in each worker process: key -> the RayScene first met there
_kept_lock = threading.Lock()


def is_dask(*values) -> bool:
    """Whether any of the values is a Dask collection (without importing dask)."""
    return any(hasattr(type(v), "__dask_graph__") for v in values)


def _dask():
    try:
        import dask.array as da
    except ImportError:     # a dask array was given, so this is rare: dask without its array extra
        raise RayInputError("dask arrays need dask.array: pip install 'raykernel[distributed]'") from None
    return da


def scene_task(rs):
    """The RayScene as a Dask task (a Delayed) with one name for every query of this object."""
    from dask.delayed import delayed
    name = _names.get(rs)
    if name is None:
        name = _names[rs] = f"rayscene-{uuid.uuid4().hex}"
    return delayed(rs, name=name, pure=True), name


def worker_scene(rs, key: str):
    """The copy of scene `key` this process met first (kept, with what its queries built), else `rs`
    (a RayScene, or a SharedScene of this machine, opened here)."""
    if _names.get(rs) == key:
        return rs       # the user's own object (a scheduler of threads here): theirs to keep, not ours
    with _kept_lock:
        kept = _kept.get(key)
        if kept is None:
            kept = _kept[key] = rs.open() if isinstance(rs, SharedScene) else rs
            while len(_kept) > SCENES_KEPT:
                _kept.popitem(last=False)
        _kept.move_to_end(key)
    return kept


def kept_scene(key: str):
    """The scene `key` this worker process keeps (worker_scene), or None where it keeps none (a
    worker that joined or restarted since the scene was sent). Tasks that take the key alone rather
    than the scene's future leave Dask's scheduler free to send them to any worker: with the
    future, it sends them all to the one worker that holds its data (it drops the other workers'
    copies once the tasks that needed them are done)."""
    with _kept_lock:
        kept = _kept.get(key)
        if kept is not None:
            _kept.move_to_end(key)
        return kept


# ----------------------------------------------------------------- arguments

def _vectors(value, name: str, like=None):
    """A dask array (..., 3) of reals, its last axis one chunk; a numpy (3,) vector stays numpy
    (broadcast in every chunk); another numpy array becomes a dask array chunked as `like`."""
    da = _dask()
    if not is_dask(value):
        arr = real_array(value, name)
        if arr.shape == (3,):
            return arr
        if like is None or arr.shape != like.shape:
            raise RayInputError(f"{name} must be a dask array or one (3,) vector beside a dask array, got a numpy "
                                f"array of shape {arr.shape}")
        return da.from_array(arr, chunks=like.chunks)
    if not isinstance(value, da.Array):
        raise RayInputError(f"{name} must be an array, got {type(value).__name__}")
    if value.dtype == object or not (np.issubdtype(value.dtype, np.floating) or np.issubdtype(value.dtype, np.integer)):
        raise RayInputError(f"{name} must be an array of real numbers, got dtype {value.dtype}")
    if value.ndim < 2 or value.shape[-1] != 3:
        raise RayInputError(f"{name} must have shape (..., 3) with a leading axis to chunk, e.g. (N, 3), got "
                            f"{value.shape}")
    return value.rechunk({value.ndim - 1: 3}) if len(value.chunks[-1]) > 1 else value


def _interval(value, name: str, lead):
    """tmin or tmax: a number as it is, an array (numpy or dask) of the rays' shape chunked as they are."""
    if not is_dask(value) and np.ndim(value) == 0:
        number = real_array(value, name).item()
        if number != number:
            raise RayInputError(f"{name} is NaN")
        return float(number)
    da = _dask()
    arr = value if is_dask(value) else da.from_array(real_array(value, name), chunks=-1)
    if arr.shape != lead.shape:
        raise RayInputError(f"{name} must be a number or have shape {lead.shape}, got {arr.shape}")
    return arr.rechunk(lead.chunks)


def _rays(origins, directions):
    """(o, d, lead): the checked rays, one of them possibly a numpy (3,) vector, and a dask array of
    the rays' leading shape and chunks (the first vector's last column) that the others align to."""
    if is_dask(origins) or not is_dask(directions):
        o = _vectors(origins, "origins")
        d = _vectors(directions, "directions", like=o if is_dask(o) else None)
    else:       # numpy origins take the chunks of dask directions
        d = _vectors(directions, "directions")
        o = _vectors(origins, "origins", like=d)
    if isinstance(o, np.ndarray) and isinstance(d, np.ndarray):
        raise RayInputError("origins or directions must be a dask array here")
    if not isinstance(o, np.ndarray) and not isinstance(d, np.ndarray):
        if o.shape != d.shape:
            raise RayInputError(f"origins and directions differ in shape: {o.shape} vs {d.shape}")
        d = d.rechunk(o.chunks)
    first = o if not isinstance(o, np.ndarray) else d
    return o, d, first[..., 0]


def _moved(x):
    """A (..., 3) dask array with its last axis first: map_blocks aligns arguments from the right,
    so the rays' leading axes then meet those of tmin, tmax and the answer."""
    return _dask().moveaxis(x, -1, 0) if not isinstance(x, np.ndarray) else x


def _start(block_info) -> int:
    """The index of a block's first ray in the flat order of the whole array."""
    info = block_info[None]
    loc, shape = info["array-location"], info["shape"]
    return int(np.ravel_multi_index([a for a, _ in loc], shape)) if shape else 0


# ----------------------------------------------------------------- the tasks

def _rays_block(query, o, d, lo, hi, *, scene, key, kwargs, fields, record, block_info=None):
    """One chunk of a ray query: the numpy method on its rays; a bad ray named by its index in the whole."""
    rs = worker_scene(scene, key)
    o = np.moveaxis(o, 0, -1) if o.ndim > 1 else o      # back to (..., 3): the chunk's own memory
    d = np.moveaxis(d, 0, -1) if d.ndim > 1 else d
    shape = np.broadcast_shapes(o.shape[:-1], d.shape[:-1])
    try:
        answer = getattr(rs, query)(o, d, lo, hi, **kwargs)
    except RayInputError as e:
        start = _start(block_info)
        where = f"chunk {block_info[None]['chunk-location']} (rays from {start:,})"
        try:
            check_ray_values(np.broadcast_to(o, shape + (3,)).reshape(-1, 3),
                             np.broadcast_to(d, shape + (3,)).reshape(-1, 3), start)
        except RayInputError as named:
            raise RayInputError(f"{where}: {named}") from None
        raise RayInputError(f"{where}: {e}") from None
    if fields is None:
        return answer
    out = np.empty(shape, record)
    for name in fields:
        out[name] = getattr(answer, name)
    return out


def _points_block(query, p, *, scene, key, kwargs, fields, record, block_info=None):
    """One chunk of a point query."""
    rs = worker_scene(scene, key)
    p = np.moveaxis(p, 0, -1)
    try:
        answer = getattr(rs, query)(p, **kwargs)
    except RayInputError as e:
        raise RayInputError(f"chunk {block_info[None]['chunk-location']} (points from {_start(block_info):,}): "
                            f"{e}") from None
    if fields is None:
        return answer
    out = np.empty(p.shape[:-1], record)
    for name in fields:
        out[name] = getattr(answer, name)
    return out


def _record(names, columns, float_type, int_type, floats) -> np.dtype:
    return np.dtype([(n, float_type if n in floats else int_type, columns.get(n, ())) for n in names])


def ray_query(rs, query: str, origins, directions, tmin, tmax, dtype, **kwargs):
    """RayScene.<query> (occluded, count_hits) on dask arrays: a dask array of `dtype`, lazily."""
    da = _dask()
    o, d, lead = _rays(origins, directions)
    lo, hi = _interval(tmin, "tmin", lead), _interval(tmax, "tmax", lead)
    scene, key = scene_task(rs)
    return da.map_blocks(_rays_block, query, _moved(o), _moved(d), lo, hi, scene=scene, key=key, kwargs=kwargs,
                         fields=None, record=None, dtype=np.dtype(dtype), drop_axis=0, chunks=lead.chunks,
                         meta=np.empty((0,) * lead.ndim, dtype), name=f"{query}-{_token(key, o, d, lo, hi, kwargs)}")


def intersect(rs, origins, directions, tmin, tmax, threads, fields, dtype, out):
    """RayScene.intersect on dask arrays: a Hits whose fields are dask arrays (None where not asked)."""
    from .rayqueries import Hits
    da = _dask()
    if out is not None:
        raise RayInputError("out= takes the numpy arrays of an earlier call; on dask arrays every answer is new")
    if dtype not in DTYPES:
        raise RayInputError(f"dtype must be one of {', '.join(DTYPES)}, got {dtype!r}")
    names = HIT_FIELDS if fields is None else field_names(fields)
    record = _record(names, FIELD_COLUMNS, *DTYPES[dtype], FLOAT_FIELDS)
    o, d, lead = _rays(origins, directions)
    lo, hi = _interval(tmin, "tmin", lead), _interval(tmax, "tmax", lead)
    scene, key = scene_task(rs)
    kwargs = {"threads": threads, "fields": names, "dtype": dtype}
    parts = da.map_blocks(_rays_block, "intersect", _moved(o), _moved(d), lo, hi, scene=scene, key=key,
                          kwargs=kwargs, fields=names, record=record, dtype=record, drop_axis=0, chunks=lead.chunks,
                          meta=np.empty((0,) * lead.ndim, record), name=f"hits-{_token(key, o, d, lo, hi, kwargs)}")
    full = lambda x: x if not isinstance(x, np.ndarray) else da.broadcast_to(x, lead.shape + (3,),  # noqa: E731
                                                                            chunks=lead.chunks + ((3,),))
    return Hits(**{name: parts[name] if name in names else None for name in HIT_FIELDS},
                origins=full(o), directions=full(d))


def point_query(rs, query: str, points, dtype, **kwargs):
    """RayScene.<query> (contains, distance) on a dask array of points: a dask array of `dtype`."""
    da = _dask()
    p = _vectors(points, "points")
    scene, key = scene_task(rs)
    return da.map_blocks(_points_block, query, _moved(p), scene=scene, key=key, kwargs=kwargs, fields=None,
                         record=None, dtype=np.dtype(dtype), drop_axis=0, meta=np.empty((0,) * (p.ndim - 1), dtype),
                         chunks=p.chunks[:-1], name=f"{query}-{_token(key, p, kwargs)}")


def closest_points(rs, points, threads):
    """RayScene.closest_points on a dask array of points: a ClosestPoints of dask arrays."""
    from .proximity import ClosestPoints
    da = _dask()
    p = _vectors(points, "points")
    names = ("points", "distance", "prim_id", "geom_id", "kind", "normal")
    record = _record(names, {"points": (3,), "normal": (3,)}, np.float64, np.int64, ("points", "distance", "normal"))
    scene, key = scene_task(rs)
    kwargs = {"threads": threads}
    parts = da.map_blocks(_points_block, "closest_points", _moved(p), scene=scene, key=key, kwargs=kwargs,
                          fields=names, record=record, dtype=record, drop_axis=0,
                          meta=np.empty((0,) * (p.ndim - 1), record),
                          chunks=p.chunks[:-1], name=f"closest-{_token(key, p, kwargs)}")
    return ClosestPoints(**{name: parts[name] for name in names})


def _token(*parts) -> str:
    """A name for a query's tasks from what it depends on (dask arrays by name, the scene by key)."""
    from dask.base import tokenize
    return tokenize(*[getattr(p, "name", p) if is_dask(p) else p for p in parts])
