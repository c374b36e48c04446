"""Ray classification's walk: what a ray runs, classify it and descend its face's 5D tree to one candidate list.

    sp, s, e, keyed, key_o, key_d, ray, best_t, sink = walk_step(geo, step, a, te, ray, lo, best_t, f, sp, ws, cnt)
    s, e, key_o, key_d = classify(geo.rc_face_root, ..., a, te, ox, oy, oz, dx, dy, dz, best_t, frame_f, f, cnt)

walk_step is rc.py's WALK.step (walk.py's step contract); the list it returns
is keyed (walk.py), so the driver stops it once the next key puts the earliest
possible hit past the closest one. rc.py's docstring gives the layout.
"""

from __future__ import annotations

from ..geometry import counters as C
from ..geometry.config import njit
from .walk import F_KEY_D, F_KEY_END, F_KEY_O

__all__ = ["walk_step", "classify"]


@njit(inline="always")
def walk_step(geo, step, a, te, ray, lo, best_t, f, sp, ws, cnt):
    """walk.py's step contract: the ray's hypercube's candidates, a keyed list."""
    ox, oy, oz, dx, dy, dz, _, _, _ = ray
    s, e, key_o, key_d = classify(geo.rc_face_root, geo.rc_node_a, geo.rc_node_b, geo.rc_pass, geo.rc_split,
                                  geo.rc_vdim, geo.rc_vinfo, geo.rc_vsplit, a, te, ox, oy, oz, dx, dy, dz, best_t,
                                  ws.frame_f, f, cnt)
    return sp, s, e, True, key_o, key_d, ray, best_t, False


@njit(private=True)
def classify(rc_face_root, rc_node_a, rc_node_b, rc_pass, rc_split, rc_vdim, rc_vinfo, rc_vsplit, a, te, ox, oy, oz,
             dx, dy, dz, best_t, frame_f, f, cnt):
    """Classify the ray (direction-cube face, u, v, and its entry point at te as origin),
    descend its face's 5D tree to one hypercube and return (s, e, key_o, key_d): the
    hypercube's keyed candidate list (none: s == e), also kept in the frame for resuming.
    A lazy leaf that may still split (rc_pass >= 0) counts the ray's arrival in
    cnt[N_COUNTERS + column], the column of the cell of its virtual subtree the ray's 5D
    point falls in, where the kernel gave cnt room for it."""
    if te > best_t:
        return 0, 0, 0.0, 0.0
    rax, ray_, raz = abs(dx), abs(dy), abs(dz)
    if rax >= ray_ and rax >= raz:
        face = 0 if dx > 0.0 else 1
        key_d, key_o, u, v = rax, (ox if dx > 0.0 else -ox), dy / rax, dz / rax
    elif ray_ >= raz:
        face = 2 if dy > 0.0 else 3
        key_d, key_o, u, v = ray_, (oy if dy > 0.0 else -oy), dz / ray_, dx / ray_
    else:
        face = 4 if dz > 0.0 else 5
        key_d, key_o, u, v = raz, (oz if dz > 0.0 else -oz), dx / raz, dy / raz
    px, py, pz = ox + te * dx, oy + te * dy, oz + te * dz
    node = rc_face_root[a, face]
    while True:
        cnt[C.CELLS_VISITED] += 1
        nb = rc_node_b[node]
        if nb >= 0:
            break
        q = px if nb == -1 else (py if nb == -2 else (pz if nb == -3 else (u if nb == -4 else v)))
        node = rc_node_a[node] + (0 if q < rc_split[node] else 1)
    pj = rc_pass[node]
    if pj >= 0:
        # a lazy leaf that may split: count the arrival in its virtual cell
        col = C.N_COUNTERS + rc_vinfo[pj, 0]
        k = rc_vinfo[pj, 1]
        if col + (1 << k) <= cnt.shape[0]:
            off = rc_vinfo[pj, 2] - 1
            h = 1
            for _ in range(k):
                dim = rc_vdim[off + h]
                q = px if dim == 0 else (py if dim == 1 else (pz if dim == 2 else (u if dim == 3 else v)))
                h = 2 * h + (0 if q < rc_vsplit[off + h] else 1)
            cnt[col + h - (1 << k)] += 1
    cnt[C.CELLS_LEAVES] += 1
    if nb == 0:
        cnt[C.CELLS_EMPTY] += 1
        return 0, 0, 0.0, 0.0
    s = rc_node_a[node]
    e = s + nb
    frame_f[f, F_KEY_END], frame_f[f, F_KEY_O], frame_f[f, F_KEY_D] = e, key_o, key_d
    return s, e, key_o, key_d
