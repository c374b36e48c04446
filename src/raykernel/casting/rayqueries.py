"""RayScene's ray queries: closest, any and all hits of batches of rays, and the general kernel behind them.

    hits = closest_hits(rs, origins, directions)     # RayScene.intersect: a Hits
    blocked = occluded(rs, origins, directions, tmax=1.0)
    ray, t, prim = intersect_all(rs, origins, directions)
    counts = count_hits(rs, origins, directions)

Each function is the body of the RayScene method of its name (`closest_hits`
is `intersect`; their docstrings are the methods'). A query checks its rays
(rayinput.check_rays), makes its output arrays (the Hits fields asked for, in
the dtype asked for, or `out`'s) and runs one kernel over chunks of CHUNK
rays on every thread (`_run`): the mesh kernel of meshcast.py for a scene of
triangles under one BVH, else `_query` here, which casts through the
general traversal (engine/traverse.py). Lazy structures refine between
passes of the rays, taken coarse to fine (coarse_to_fine). All hits run
twice, counting and then storing, and are sorted and rid of repeats here.
"""

from __future__ import annotations

import math
import time
from contextlib import nullcontext
from dataclasses import dataclass

import numpy as np

from ..geometry.compiletime import CompileClock, compile_notice
from ..aggregates.memory import check, describe_bytes
from ..aggregates.registry import COUNTER_NAMES
from ..geometry.parallel import for_ranges
from ..engine.traverse import ALL_HITS, HIT_F, HIT_I, intersect, workspace
from ..geometry import counters as C
from ..geometry.config import njit
from .hitsurface import store_no_surface, store_surface
from .rayinput import RayInputError, check_ray_values, check_rays, read_only, valid_ray

CHUNK = 1024
CLOSEST, ANY = 0, 1
HIT_FIELDS = ("t", "prim_id", "geom_id", "inst_id", "kind", "uv", "normal", "shading_normal")   # intersect's fields=
FLOAT_FIELDS = ("t", "uv", "normal", "shading_normal")
FIELD_COLUMNS = {"uv": (2,), "normal": (3,), "shading_normal": (3,)}
DTYPES = {"float64": (np.float64, np.int64), "float32": (np.float32, np.int32)}    # floats, ids
HIT_BYTES = 2 * (8 + 24 + 8) + 8     # intersect_all: a hit's t, identity and ray, sorted into copies, and the order
OUTPUTS = ("t", "kind", "geom", "idx", "inst", "uv", "gn", "sn")     # the kernels' output arrays, in call order


@dataclass
class Hits:
    """Closest hits of a batch of rays (RayScene.intersect), shaped as the rays were.

    Each field has the rays' shape: (N,) for (N, 3) origins and directions, (H, W) for an
    image of rays; the vector fields add a last axis. The float fields are float64 and the ids
    int64, or float32 and int32 with ``intersect(..., dtype="float32")``; a field not asked for
    (intersect's `fields`) is None.

    Attributes
    ----------
    t : (N,) float array
        The ray parameter of the hit, in units of the direction given; inf on a miss.
    prim_id : (N,) int array
        The primitive's index within its geometry (the face index for a mesh); -1 on a miss.
    geom_id : (N,) int array
        The geometry (mesh or primitive set) in ``RayScene.geometries``; -1 on a miss.
    inst_id : (N,) int array
        The innermost instance; -1 outside instances or on a miss.
    kind : (N,) int array
        The primitive kind (0 sphere, 1 polygon, 2 patch, 3 cone, 4 triangle); -1 on a miss.
    uv : (N, 2) float array
        Triangles: barycentric (p = (1-u-v) v0 + u v1 + v v2); spheres: (longitude / 2 pi,
        colatitude / pi) in the sphere's frame; cones: (angle around the axis / 2 pi,
        height / length); NaN otherwise.
    normal : (N, 3) float array
        The unit geometric normal in world space (by winding, or outward); NaN on a miss.
    shading_normal : (N, 3) float array
        The unit interpolated normal (vertex normals, patches), else equal to `normal`.
    origins : (N, 3) float64 array
        The rays' origins, as given (broadcast).
    directions : (N, 3) float64 array
        The rays' directions, as given (broadcast).
    """

    t: np.ndarray               # (N,) ray parameter of the hit, inf on a miss
    prim_id: np.ndarray         # (N,) index within its geometry (face index for a mesh), -1 on a miss
    geom_id: np.ndarray         # (N,) geometry (mesh or primitive set) in RayScene.geometries, -1 on a miss
    inst_id: np.ndarray         # (N,) innermost instance, -1 outside instances or on a miss
    kind: np.ndarray            # (N,) primitive kind (0 sphere, 1 polygon, 2 patch, 3 cone, 4 triangle), -1
    uv: np.ndarray              # (N, 2) triangles: barycentric (p = (1-u-v) v0 + u v1 + v v2);
    #                             spheres: (longitude / 2pi, colatitude / pi) in the sphere's frame;
    #                             cones: (angle around the axis / 2pi, height / length); NaN otherwise
    normal: np.ndarray          # (N, 3) unit geometric normal in world space (winding / outward), NaN on a miss
    shading_normal: np.ndarray  # (N, 3) unit interpolated normal (vertex normals, patches), else = normal
    origins: np.ndarray | None = None      # (N, 3) the rays, as given (broadcast)
    directions: np.ndarray | None = None

    def __len__(self) -> int:
        return len(self.t)

    @property
    def hit(self) -> np.ndarray:
        """(N,) bool array: True where the ray hit something (t is finite)."""
        return np.isfinite(self.t)

    @property
    def points(self) -> np.ndarray:
        """(N, 3) float64 array: the hit points, origin + t direction; NaN on a miss."""
        t = np.where(self.hit, self.t, np.nan)[..., None]
        return self.origins + t * self.directions


# ----------------------------------------------------------------- kernel

@njit
def _query(geo, origins, directions, tmin, tmax, mode, chunk, t_out, kind_out, idx_out, inst_out,
           surface_out, offsets, all_t, all_i, counters, c0, c1):
    """Closest (mode 0), any (mode 1) or all hits (ALL_HITS) of every ray.
    Closest/any fill t/kind/idx/inst, and with surface_out (None, or (uv, gn, sn)) the
    surfaces, a chunk's after its walk (_surfaces): without them numba compiles no surface
    code (it drops the branch for None), and the walk is compiled once for both.
    All hits: with len(offsets) == 0 only counts them into idx_out; else
    writes ray r's hits to rows offsets[r] .. offsets[r + 1] of all_t/all_i.
    Chunks c0..c1-1 of `chunk` rays, counting into counters[c]."""
    n = origins.shape[0]
    store = offsets.shape[0] > 0
    hits_f, hits_i = np.empty((chunk, HIT_F)), np.empty((chunk, HIT_I), np.int64)
    for c in range(c0, c1):
        r0 = c * chunk
        r1 = min(n, (c + 1) * chunk)
        cap = np.int64(0)       # not the literal 0: numba would compile workspace again for it
        if mode == ALL_HITS and store:
            for r in range(r0, r1):
                cap = max(cap, offsets[r + 1] - offsets[r])
        ws = workspace(cap)
        cnt = np.zeros(counters.shape[1], np.int64)     # columns past N_COUNTERS: lazy octree passes
        _cast(geo, origins, directions, tmin, tmax, mode, t_out, kind_out, idx_out, inst_out, offsets, all_t, all_i,
              r0, r1, ws, cnt, hits_f, hits_i)
        if surface_out is not None and mode != ALL_HITS:
            _surfaces(geo, origins, directions, hits_f, hits_i, r0, r1, surface_out)
        for k in range(counters.shape[1]):
            counters[c, k] = cnt[k]


@njit(private=True)     # one call per chunk: the rays' calls into intersect count no references
def _cast(geo, origins, directions, tmin, tmax, mode, t_out, kind_out, idx_out, inst_out, offsets, all_t, all_i,
          r0, r1, ws, cnt, hits_f, hits_i):
    """Rays r0..r1-1 of _query but their surfaces, with the chunk's workspace and counters; ray
    r0 + i's closest or any hit record (workspace hit_f, hit_i) into hits_f[i], hits_i[i]
    (kind -1: a miss, -2: a ray not cast)."""
    hit_f, hit_i = ws.hit_f, ws.hit_i
    store = offsets.shape[0] > 0
    per_lo, per_hi = tmin.shape[0] > 1, tmax.shape[0] > 1     # else one bound for every ray
    for r in range(r0, r1):
        lo, hi = tmin[r if per_lo else 0], tmax[r if per_hi else 0]
        ox, oy, oz = origins[r, 0], origins[r, 1], origins[r, 2]
        dx, dy, dz = directions[r, 0], directions[r, 1], directions[r, 2]
        if not valid_ray(ox, oy, oz, dx, dy, dz):
            hits_i[r - r0, 0] = -2
            continue            # not cast: RayScene names it (rayinput.py)
        cnt[C.RAYS_CAST] += 1
        if mode == ALL_HITS:
            hit_i[0] = 0
        # one call for every mode: numba inlines the whole walk at each call
        found = intersect(geo, ox, oy, oz, dx, dy, dz, lo, hi, mode, ws, cnt)
        if mode == ALL_HITS:
            k = hit_i[0]
            if store:
                base = offsets[r]
                for j in range(min(k, offsets[r + 1] - base)):
                    all_t[base + j] = hit_f[HIT_F + j]
                    all_i[base + j, 0] = hit_i[HIT_I + 3 * j]
                    all_i[base + j, 1] = hit_i[HIT_I + 3 * j + 1]
                    all_i[base + j, 2] = hit_i[HIT_I + 3 * j + 2]
            else:
                idx_out[r] = k
            continue
        if not found:
            hits_i[r - r0, 0] = -1
            t_out[r] = np.inf
            if idx_out.shape[0]:        # (outputs not asked for have no rows)
                idx_out[r] = -1
            if kind_out.shape[0]:
                kind_out[r] = -1
            if inst_out.shape[0]:
                inst_out[r] = -1
            continue
        for k in range(HIT_F):
            hits_f[r - r0, k] = hit_f[k]
        for k in range(HIT_I):
            hits_i[r - r0, k] = hit_i[k]
        t = hit_f[0]
        kind = hit_i[0]
        idx = hit_i[1]
        t_out[r] = t
        if kind_out.shape[0]:           # (outputs not asked for have no rows)
            kind_out[r] = kind
        if idx_out.shape[0]:
            idx_out[r] = idx
        if inst_out.shape[0]:
            inst_out[r] = hit_i[2]


@njit(private=True)     # one call per chunk, after its walk: compiled once, apart from the walk
def _surfaces(geo, origins, directions, hits_f, hits_i, r0, r1, surface_out):
    """The surfaces of rays r0..r1-1 from the hit records _cast left: NaN for a miss."""
    uv_out, gn_out, sn_out = surface_out
    for r in range(r0, r1):
        kind = hits_i[r - r0, 0]
        if kind == -2:
            continue            # not cast
        if kind == -1:
            store_no_surface(r, uv_out, gn_out, sn_out)
            continue
        t = hits_f[r - r0, 0]
        store_surface(geo, r, kind, hits_i[r - r0, 1], origins[r, 0] + t * directions[r, 0],
                      origins[r, 1] + t * directions[r, 1], origins[r, 2] + t * directions[r, 2],
                      hits_f[r - r0, 1:13], uv_out, gn_out, sn_out, hits_i[r - r0, 3])


def field_names(fields) -> tuple:
    """intersect's fields= as names of HIT_FIELDS in their order, t among them."""
    names = (fields,) if isinstance(fields, str) else tuple(fields)
    for name in names:
        if name not in HIT_FIELDS:
            raise RayInputError(f"fields: no Hits field {name!r}; fields: {', '.join(HIT_FIELDS)}")
    return tuple(f for f in HIT_FIELDS if f == "t" or f in names)


def _out_array(out, name: str, shape: tuple, dtype) -> np.ndarray:
    """out.<name> as a flat view to fill, if it has the shape and dtype this call writes."""
    arr = getattr(out, name)
    if arr is None:
        raise RayInputError(f"out.{name} is None (out was made without it): pass the same fields")
    if not isinstance(arr, np.ndarray) or arr.shape != shape or arr.dtype != dtype or not arr.flags.c_contiguous \
            or not arr.flags.writeable:
        got = f"{arr.dtype} {arr.shape}" if isinstance(arr, np.ndarray) else type(arr).__name__
        raise RayInputError(f"out.{name} must be a writable contiguous {np.dtype(dtype)} array of shape {shape} "
                            f"for these rays, got {got}")
    return arr.reshape((-1,) + FIELD_COLUMNS.get(name, ()))     # a view: the array is contiguous


def coarse_to_fine(n: int) -> np.ndarray:
    """Ray indices 0..n-1 coarse to fine: 0, then the odd multiples of 2^k for k from high to
    low (with n = 8: 0, 4, 2, 6, 1, 3, 5, 7), so that every prefix samples the whole array."""
    parts = [np.zeros(min(n, 1), np.int64)]
    step = 1 << max(0, (n - 1).bit_length())
    while step > 1:
        parts.append(np.arange(step // 2, n, step, dtype=np.int64))
        step //= 2
    return np.concatenate(parts)


def _turn(rs):
    """The lock while a query may refine lazy structures; nothing to wait for otherwise."""
    return rs._lock if rs._lazy is not None else nullcontext()


def _run(rs, mode, o, d, lo, hi, out: dict, offsets=None, all_t=None, all_i=None, threads=None,
         compile_only=False) -> dict:
    """One query kernel over all rays, filling the arrays of `out` (t, kind, geom, idx, inst, uv,
    gn, sn; those not wanted have no rows) in place; returns the query's statistics. Closest
    and any hits: the mesh kernel writes identities as the user sees them (geom, index within
    it), the general one kind and global index in idx (see RayScene._identify). All hits: idx holds
    the counts, or with offsets the hits go to all_t / all_i as (kind, global index, instance).
    compile_only: the mesh kernel called for no chunk (compile_query)."""
    n = len(o)
    o, d, lo, hi = read_only(o), read_only(d), read_only(lo), read_only(hi)
    t, kind, geom, idx, inst, uv, gn, sn = (out[k] for k in OUTPUTS)
    with_surface = len(uv) > 0 or len(gn) > 0 or len(sn) > 0
    surface = (uv, gn, sn) if with_surface else None     # None: numba compiles no surface code
    offsets = np.zeros(0, np.int64) if offsets is None else offsets
    all_t = np.zeros(0) if all_t is None else all_t
    all_i = np.zeros((0, 3), np.int64) if all_i is None else all_i
    counters = np.zeros((max(1, (n + CHUNK - 1) // CHUNK), C.N_COUNTERS), np.int64)
    kernel = rs._mesh.kernel if rs._mesh is not None else _query
    name = f"meshcast.{kernel.__name__}" if rs._mesh is not None else "rayqueries._query"
    about = ("several seconds" if rs._mesh is not None
             else "tens of seconds, longer for other structures than one BVH")
    notice = compile_notice(name, f"raykernel: compiling the ray-casting kernels (first use after install, "
                                  f"{about}; cached for later processes)")
    with _turn(rs), CompileClock(notice=notice) as clock:
        start = time.perf_counter()         # (after waiting for the lock)
        if (n or compile_only) and rs._mesh is not None:
            mesh = rs._mesh

            def cast(c0, c1):
                kernel(*mesh, o, d, lo, hi, np.int64(mode), CHUNK, t, kind, geom, idx, inst, surface, offsets, all_t,
                       all_i, counters, c0, c1)
            if compile_only:
                cast(0, 0)
            else:
                for_ranges(cast, len(counters), threads, kernel=kernel)
        elif n and rs._lazy is not None:
            # the rays coarse to fine (every 2^k-th first), in passes from a few rays up to PASS_CHUNKS
            # chunks (lazyset.pass_ranges); the lazy structures refine after each; passes shorter
            # than a chunk add into the first chunk's row. Results go back to the rays' own order.
            order = coarse_to_fine(n)
            ins = [read_only(np.broadcast_to(a, (n,) + a.shape[1:])[order]) for a in (o, d, lo, hi)]
            outs = [np.empty_like(a) for a in (t, kind, idx, inst, uv, gn, sn)]
            p_offsets, p_all_t, p_all_i = offsets, all_t, all_i
            if len(offsets):
                counts = np.diff(offsets)
                p_offsets = np.zeros(n + 1, np.int64)
                np.cumsum(counts[order], out=p_offsets[1:])
                p_all_t, p_all_i = np.empty_like(all_t), np.empty_like(all_i)
            for a, b in rs._lazy.ranges(n, CHUNK):
                rows = np.zeros(((b - a + CHUNK - 1) // CHUNK, C.N_COUNTERS + rs._lazy.columns), np.int64)
                p_t, p_kind, p_idx, p_inst, p_uv, p_gn, p_sn = (x[a:b] for x in outs)
                args = (rs.geo, *(x[a:b] for x in ins), np.int64(mode), CHUNK, p_t, p_kind, p_idx, p_inst,
                        (p_uv, p_gn, p_sn) if with_surface else None,
                        p_offsets[a:b + 1] if len(offsets) else offsets, p_all_t, p_all_i, rows)
                for_ranges(lambda c0, c1, args=args: _query(*args, c0, c1), len(rows), threads, kernel=_query)
                counters[a // CHUNK:a // CHUNK + len(rows)] += rows[:, :C.N_COUNTERS]
                rs.geo = rs._lazy.refine(rs.geo, rows[:, C.N_COUNTERS:])
            for mine, theirs in zip((t, kind, idx, inst, uv, gn, sn), outs):
                if len(mine):       # only what was asked for
                    mine[order] = theirs
            if len(offsets):
                # ray order[k]'s hits lie at p_offsets[k]..p_offsets[k + 1]
                start = np.empty(n, np.int64)
                start[order] = p_offsets[:-1]
                src = np.repeat(start - offsets[:-1], counts) + np.arange(offsets[-1])
                all_t[:] = p_all_t[src]
                all_i[:] = p_all_i[src]
            rs._lazy.update_stats(rs.build_stats, rs.geo)
        elif n:
            for_ranges(lambda c0, c1: _query(rs.geo, o, d, lo, hi, np.int64(mode), CHUNK, t, kind, idx, inst,
                                             surface, offsets, all_t, all_i, counters, c0, c1),
                       len(counters), threads, kernel=_query)
    seconds = time.perf_counter() - start - clock.seconds - clock.loading
    totals = counters.sum(axis=0)
    if totals[C.RAYS_CAST] != n:        # the kernels left out rays that are not finite or do not move
        check_ray_values(o, d)
        raise RuntimeError(f"the kernels cast {totals[C.RAYS_CAST]} of {n} rays, all of them valid")
    totals = totals.tolist()
    stats = {name: totals[k] for k, name in COUNTER_NAMES.items() if totals[k]}
    stats["rays.cast"] = n
    stats["time.trace"] = seconds
    stats["time.compile"] = clock.seconds
    stats["time.load"] = clock.loading
    return stats


def _budget(rs, what: str, per_ray: int, hint: str = "cast fewer rays at a time"):
    """check_rays' budget: MemoryBudgetError unless the structures, the rays' copies and
    `per_ray` bytes of outputs a ray fit in the memory budget (max_memory)."""
    def fits(n: int, copied: int) -> None:
        need = n * (per_ray + C.N_COUNTERS * 8 // CHUNK + 1) + copied
        if need > (1 << 24):        # small batches are not worth summing the structures for
            held = rs.stats["bytes"]
            check(held + need, rs._limit, f"RayScene.{what} of {n:,} rays ({describe_bytes(need)} of outputs "
                  f"and copies, beside {describe_bytes(held)} of structures)", hint)
    return fits


def _output_bytes(rs, fields=None, dtype="float64") -> int:
    """The bytes a ray's outputs take: the fields asked for, and the general kernel's identities."""
    fdt, idt = DTYPES.get(dtype, DTYPES["float64"])
    per = sum(np.dtype(fdt if name in FLOAT_FIELDS else idt).itemsize * math.prod(FIELD_COLUMNS.get(name, ()))
              for name in (HIT_FIELDS if fields is None else field_names(fields)))
    return per + (0 if rs._mesh is not None else 16)


def _outputs(rs, shape: tuple, fields=None, dtype="float64", out=None) -> tuple[dict, dict]:
    """(the kernel's output arrays by OUTPUTS name, the Hits fields asked for by name): the
    fields' arrays come from `out` (a Hits) or are new; what nobody asked for has no rows.
    The general kernel writes kind and global index (int64) for _identify, apart."""
    fields = HIT_FIELDS if fields is None else field_names(fields)
    if dtype not in DTYPES:
        raise RayInputError(f"dtype must be one of {', '.join(DTYPES)}, got {dtype!r}")
    fdt, idt = DTYPES[dtype]
    if out is not None and not isinstance(out, Hits):
        raise RayInputError(f"out must be the Hits of an earlier intersect call, got {type(out).__name__}")
    n = math.prod(shape)
    hits = {}
    for name in fields:
        dt = fdt if name in FLOAT_FIELDS else idt
        columns = FIELD_COLUMNS.get(name, ())
        hits[name] = np.empty((n,) + columns, dt) if out is None else _out_array(out, name, shape + columns, dt)
    none_i = np.empty(0, idt)
    arrays = dict(t=hits["t"], kind=hits.get("kind", none_i), geom=hits.get("geom_id", none_i),
                  idx=hits.get("prim_id", none_i), inst=hits.get("inst_id", none_i),
                  uv=hits.get("uv", np.empty((0, 2), fdt)), gn=hits.get("normal", np.empty((0, 3), fdt)),
                  sn=hits.get("shading_normal", np.empty((0, 3), fdt)))
    if rs._mesh is None:
        identify = "prim_id" in hits or "geom_id" in hits
        arrays["kind"] = np.empty(n, np.int64) if identify or "kind" in hits else np.empty(0, np.int64)
        arrays["idx"] = np.empty(n, np.int64) if identify else np.empty(0, np.int64)
        arrays["geom"] = np.empty(0, np.int64)
    return arrays, hits


def closest_hits(rs, origins, directions, tmin=0.0, tmax=np.inf, threads: int | None = None, fields=None,
                 dtype: str = "float64", out: Hits | None = None) -> Hits:
    """RayScene.intersect: the closest hit of every ray in [tmin, tmax] (its docstring says the rest)."""
    per_ray = 0 if out is not None else _output_bytes(rs, fields, dtype)
    o, d, lo, hi, shape = check_rays(origins, directions, tmin, tmax,
                                     _budget(rs, "intersect", per_ray, "cast fewer rays at a time, or fill the "
                                             "arrays of an earlier call (out=)"))
    arrays, hits = _outputs(rs, shape, fields, dtype, out)
    stats = _run(rs, CLOSEST, o, d, lo, hi, arrays, threads=threads)
    if rs._mesh is None:
        if "prim_id" in hits or "geom_id" in hits:
            geom, prim = rs._identify(arrays["kind"], arrays["idx"])
            for name, value in (("prim_id", prim), ("geom_id", geom)):
                if name in hits:
                    hits[name][...] = value
        if "kind" in hits:
            hits["kind"][...] = arrays["kind"]
    rs.last_stats = stats
    if out is not None:
        out.origins, out.directions = o.reshape(shape + (3,)), d.reshape(shape + (3,))
        return out
    return Hits(**{name: (hits[name].reshape(shape + FIELD_COLUMNS.get(name, ())) if name in hits else None)
                   for name in HIT_FIELDS}, origins=o.reshape(shape + (3,)), directions=d.reshape(shape + (3,)))


def compile_query(rs, fields=("t",)) -> None:
    """Compile (or load) the mesh kernel of rs (a RayScene, or anything with its _mesh and
    _lazy) for a closest-hit query of `fields` in float64, casting no ray: its arguments typed
    as any such query's (occluded's too, and those of every field set without surface fields)."""
    o, d, lo, hi, shape = check_rays(np.zeros((0, 3)), np.zeros((0, 3)))
    arrays, _ = _outputs(rs, shape, fields)
    _run(rs, CLOSEST, o, d, lo, hi, arrays, compile_only=True)


def occluded(rs, origins, directions, tmin=0.0, tmax=np.inf, threads: int | None = None) -> np.ndarray:
    """RayScene.occluded: True where the ray meets anything in [tmin, tmax]."""
    o, d, lo, hi, shape = check_rays(origins, directions, tmin, tmax, _budget(rs, "occluded", 9))
    arrays, _ = _outputs(rs, (len(o),), ("t",))
    rs.last_stats = _run(rs, ANY, o, d, lo, hi, arrays, threads=threads)
    return np.isfinite(arrays["t"]).reshape(shape)


def _counts(rs, n: int) -> dict:
    """Output arrays for an all-hits run: t and the counts (idx) only."""
    arrays, _ = _outputs(rs, (n,), ("t",))
    arrays["idx"] = np.empty(n, np.int64)
    return arrays


def _all(rs, o, d, lo, hi, threads=None):
    """Every hit of the checked rays: (ray, t, (geom_id, prim_id, inst_id), counts, stats), sorted by
    ray, t and identity, each primitive once a ray."""
    with _turn(rs):      # both runs, with no other query refining in between
        mark = rs._lazy.checkpoint() if rs._lazy is not None else None
        arrays = _counts(rs, len(o))
        stats = _run(rs, ALL_HITS, o, d, lo, hi, arrays, threads=threads)
        counts = arrays["idx"]
        if mark is not None:
            rs.geo = rs._lazy.restore(mark, rs.geo)   # the second run must meet the same trees
        offsets = np.zeros(len(o) + 1, np.int64)
        np.cumsum(counts, out=offsets[1:])
        # each hit: t, (kind, index, instance), its ray, and the sort's order and copies
        _budget(rs, "intersect_all", 0)(len(o), int(offsets[-1]) * HIT_BYTES)
        all_t = np.empty(offsets[-1])
        all_i = np.empty((offsets[-1], 3), np.int64)
        stats2 = _run(rs, ALL_HITS, o, d, lo, hi, _counts(rs, len(o)), offsets=offsets, all_t=all_t,
                      all_i=all_i, threads=threads)
    for k, v in stats2.items():
        stats[k] = stats.get(k, 0) + v
    stats["rays.cast"] = len(o)
    ray = np.repeat(np.arange(len(o), dtype=np.int64), counts)
    # identities as the user sees them: (geometry, index within it, instance)
    all_i[:, 0], all_i[:, 1] = rs._identify(all_i[:, 0], all_i[:, 1])
    order = np.lexsort((all_i[:, 2], all_i[:, 1], all_i[:, 0], all_t, ray))
    ray, all_t, all_i = ray[order], all_t[order], all_i[order]
    if rs._may_repeat and len(ray) > 1:
        # the same primitive met again in a later grid cell: same ray, t and identity; with
        # inclusive edges also the neighbours of an edge or vertex the ray passes through (same
        # geometry and instance at the same t): the first, the smallest prim_id, stays
        differ = all_i[1:] != all_i[:-1]      # geometry, prim_id, instance
        if rs.edges == "inclusive":
            differ[:, 1] = False
        keep = np.ones(len(ray), bool)
        keep[1:] = (ray[1:] != ray[:-1]) | (all_t[1:] != all_t[:-1]) | np.any(differ, axis=1)
        ray, all_t, all_i = ray[keep], all_t[keep], all_i[keep]
    return ray, all_t, all_i, counts, stats


def intersect_all(rs, origins, directions, tmin=0.0, tmax=np.inf, ids: bool = False, threads: int | None = None):
    """RayScene.intersect_all: every primitive each ray meets in [tmin, tmax], once."""
    o, d, lo, hi, _ = check_rays(origins, directions, tmin, tmax, _budget(rs, "intersect_all", 48))
    ray, t, ident, _, stats = _all(rs, o, d, lo, hi, threads)
    rs.last_stats = stats
    if ids:
        return ray, t, ident[:, 1].copy(), ident[:, 0].copy(), ident[:, 2].copy()
    return ray, t, ident[:, 1].copy()


def count_hits(rs, origins, directions, tmin=0.0, tmax=np.inf, threads: int | None = None) -> np.ndarray:
    """RayScene.count_hits: the number of primitives each ray meets in [tmin, tmax]."""
    o, d, lo, hi, shape = check_rays(origins, directions, tmin, tmax, _budget(rs, "count_hits", 48))
    if rs._may_repeat:
        ray, _, _, _, stats = _all(rs, o, d, lo, hi, threads)
        counts = np.bincount(ray, minlength=len(o)).astype(np.int64)
    else:
        arrays = _counts(rs, len(o))
        stats = _run(rs, ALL_HITS, o, d, lo, hi, arrays, threads=threads)
        counts = arrays["idx"]
    rs.last_stats = stats
    return counts.reshape(shape)
