"""Arvo's sparse transforms: instance maps classified when the scene is built, rays mapped
with only the multiplies each class needs.

    cls = transform_class(world_to_local_3x4)      # IDENTITY, TRANSLATION, SCALE or AFFINE
    ox, oy, oz, dx, dy, dz = map_ray(geo.inst_to_local, geo.inst_class, instance, ox, oy, oz, dx, dy, dz, cnt)
    compose_map(geo.inst_to_local, geo.inst_class, True, instance, frame_f, f, g, cnt)   # frame g's world-to-local map

Each class leaves out only terms that are exact zeros and ones, so the numbers
are those of the full product. cnt[TRANSFORMS + class] counts the rays mapped,
cnt[TRANSFORM_MULTIPLIES] the multiplies done (TRANSFORM_MULTIPLIES per ray and
class: mapping the ray and composing its frame's map).
"""

import numpy as np

from ..aggregates.walk import F_MAP
from ..geometry import counters as C
from ..geometry.config import njit

IDENTITY, TRANSLATION, SCALE, AFFINE = range(4)      # instance map classes (Arvo's sparse transforms)
TRANSFORM_MULTIPLIES = (0, 0, 18, 54)   # multiplies per ray entering an instance, per class: mapping origin and
#                                        direction (0, 0, 6, 18) and composing the frame's map (0, 0, 12, 36)


def transform_class(m: np.ndarray) -> int:
    """The class of a 3x4 affine map: IDENTITY, TRANSLATION (identity linear part), SCALE
    (diagonal linear part: a scale, maybe a mirror, and a translation) or AFFINE. Exact
    comparisons: a map that is the identity only within rounding is mapped in full."""
    linear, shift = m[:, :3], m[:, 3]
    if np.array_equal(linear, np.eye(3)):
        return TRANSLATION if np.any(shift != 0.0) else IDENTITY
    if np.count_nonzero(linear - np.diag(np.diag(linear))) == 0:
        return SCALE
    return AFFINE


@njit(private=True)
def map_ray(inst_to_local, inst_class, idx, ox, oy, oz, dx, dy, dz, cnt):
    """The ray in instance idx's space, with only the multiplies its map's class needs (Arvo's
    sparse transforms); the same numbers as the full product, since the terms left out are
    exact zeros and ones."""
    m = inst_to_local[idx]
    cls = inst_class[idx]
    cnt[C.TRANSFORMS + cls] += 1
    if cls == IDENTITY:
        return ox, oy, oz, dx, dy, dz
    if cls == TRANSLATION:
        return ox + m[3], oy + m[7], oz + m[11], dx, dy, dz
    if cls == SCALE:
        cnt[C.TRANSFORM_MULTIPLIES] += 6
        return m[0] * ox + m[3], m[5] * oy + m[7], m[10] * oz + m[11], m[0] * dx, m[5] * dy, m[10] * dz
    cnt[C.TRANSFORM_MULTIPLIES] += 18
    return (m[0] * ox + m[1] * oy + m[2] * oz + m[3], m[4] * ox + m[5] * oy + m[6] * oz + m[7],
            m[8] * ox + m[9] * oy + m[10] * oz + m[11],
            m[0] * dx + m[1] * dy + m[2] * dz, m[4] * dx + m[5] * dy + m[6] * dz, m[8] * dx + m[9] * dy + m[10] * dz)


@njit(private=True)
def compose_map(inst_to_local, inst_class, instance, idx, frame_f, f, g, cnt):
    """Frame g's world-to-local map: instance idx's map after frame f's, or frame f's; with only
    the multiplies the class needs, and the same numbers as the full product."""
    cls = inst_class[idx] if instance else IDENTITY
    if cls == TRANSLATION:
        m = inst_to_local[idx]
        for r in range(3):
            for c in range(4):
                frame_f[g, F_MAP + 4 * r + c] = frame_f[f, F_MAP + 4 * r + c] + (m[4 * r + 3] if c == 3 else 0.0)
    elif cls == SCALE:
        m = inst_to_local[idx]
        cnt[C.TRANSFORM_MULTIPLIES] += 12
        for r in range(3):
            for c in range(4):
                frame_f[g, F_MAP + 4 * r + c] = (m[4 * r + 3] if c == 3 else 0.0) + \
                    m[5 * r] * frame_f[f, F_MAP + 4 * r + c]
    elif cls != IDENTITY:
        m = inst_to_local[idx]
        cnt[C.TRANSFORM_MULTIPLIES] += 36
        for r in range(3):
            for c in range(4):
                acc = m[4 * r + 3] if c == 3 else 0.0
                for k in range(3):
                    acc += m[4 * r + k] * frame_f[f, F_MAP + 4 * k + c]
                frame_f[g, F_MAP + 4 * r + c] = acc
    else:
        for k in range(12):
            frame_f[g, F_MAP + k] = frame_f[f, F_MAP + k]
