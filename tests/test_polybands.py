"""Bins for the crossings test (geometry/polybands.py): a point's test walks only its band's
edges and answers exactly what the walk over every corner answers."""

from __future__ import annotations

import math

import numpy as np
import pytest
import reference as ref

from raykernel import Scene, render
from raykernel.engine.flatten import flatten
from raykernel.geometry import counters as C
from raykernel.geometry import polybands
from raykernel.geometry.primitives import hit_polygon, point_in_polygon


def _star(n: int, scale: float = 1.0, center=(0.0, 0.0)) -> np.ndarray:
    a = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    r = np.where(np.arange(n) % 2 == 0, 1.0, 0.45) * scale
    return np.stack([center[0] + r * np.cos(a), center[1] + r * np.sin(a), np.zeros(n)], axis=1)


def _comb(teeth: int) -> np.ndarray:
    """A comb: a bar along x with square teeth along y, many horizontal edges, corners on
    shared heights (the bands' boundaries fall on some of them)."""
    pts = [(0.0, 0.0), (2.0 * teeth, 0.0)]
    for k in reversed(range(teeth)):
        x = 2.0 * k
        pts += [(x + 1.0, 1.0), (x + 1.0, 3.0), (x, 3.0), (x, 1.0)]
    return np.array([(x, y, 0.0) for x, y in pts])


def _shapes():
    rng = np.random.default_rng(11)
    yield "star", _star(40)
    yield "star-tiny", _star(64, 1e-6, (3e-6, -2e-6))
    yield "star-huge", _star(24, 1e7, (4e7, 1e7))
    yield "star-many", _star(3000)                      # more corners than MAX_BANDS bands can split
    yield "comb", _comb(12)
    yield "self-crossing", np.column_stack([rng.uniform(-1, 1, 30), rng.uniform(-1, 1, 30), np.zeros(30)])
    repeated = np.repeat(_star(18), 2, axis=0)        # every corner twice: zero-length edges
    yield "repeated corners", repeated


def _in_plane(poly: np.ndarray, axis: int) -> np.ndarray:
    """The polygon (given in z = 0) moved into a plane that drops `axis`, tilted a little."""
    p = poly[:, [0, 1, 2]]
    p = {2: p, 0: p[:, [2, 0, 1]], 1: p[:, [1, 2, 0]]}[axis]
    return p + 1e-3 * np.roll(p, 1, axis=1)


def _table(poly, axis):
    band, band_f, band_i = polybands.build(poly, np.array([0]), np.array([len(poly)]), np.array([axis]))
    return band[0], band_f, band_i


def _points(poly, axis, rng):
    iu, iv, _, _ = polybands.plane_coordinates(axis, 0.0, 0.0, 0.0)
    u, v = poly[:, iu], poly[:, iv]
    lo, hi = v.min(), v.max()
    span = max(hi - lo, u.max() - u.min())
    pu = np.concatenate([rng.uniform(u.min() - 0.1 * span, u.max() + 0.1 * span, 400), u, (u + np.roll(u, 1)) / 2, u])
    pv = np.concatenate([rng.uniform(lo - 0.1 * span, hi + 0.1 * span, 400), v, (v + np.roll(v, 1)) / 2,
                         np.full(len(u), lo)])
    return iu, iv, pu, pv


@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("name,shape", list(_shapes()), ids=[n for n, _ in _shapes()])
def test_the_bins_answer_as_the_walk_over_every_corner(name, shape, axis):
    """Random points, every corner, every edge's midpoint, points on the lowest height and on
    the bands' boundaries: the same answer; the edges walked at most the corners, none outside
    the polygon's heights."""
    poly = _in_plane(shape, axis)
    band, band_f, band_i = _table(poly, axis)
    assert band >= 0
    rng = np.random.default_rng(5)
    iu, iv, pu, pv = _points(poly, axis, rng)
    bounds = band_f[band + 3: band + 4 + int(band_f[band])]
    pu = np.concatenate([pu, rng.uniform(pu.min(), pu.max(), len(bounds))])
    pv = np.concatenate([pv, bounds])
    n = len(poly)
    inside_count = 0
    for u0, v0 in zip(pu, pv):
        p = np.zeros(3)
        p[iu], p[iv], p[axis] = u0, v0, 0.0
        want = point_in_polygon(poly, 0, n, axis, p[0], p[1], p[2])
        got, walked = polybands.point_in_bands(poly, 0, n, iu, iv, u0, v0, band_f, band_i, band)
        assert got == want, (u0, v0)
        assert 0 <= walked <= n
        if not (poly[:, iv].min() <= v0 < poly[:, iv].max()):
            assert walked == 0
        inside_count += want
    assert 0 < inside_count < len(pu)


def test_small_and_flat_polygons_get_no_bins():
    small = _star(14)
    flat = np.array([[float(k), 0.0, 0.0] for k in range(20)])     # no height in its plane
    verts = np.vstack([small, flat])
    band, band_f, band_i = polybands.build(verts, np.array([0, 14]), np.array([14, 20]), np.array([2, 2]))
    assert band.tolist() == [-1, -1] and len(band_f) == 0 and len(band_i) == 0


def _walked_by_bins(poly, band_f, band_i, band, iu, iv, u0, v0):
    """Edges the point's band lists, found by searching the stored boundaries one by one."""
    b = int(band_f[band])
    bounds = band_f[band + 3: band + 4 + b]
    if not bounds[0] <= v0 < bounds[-1]:
        return 0
    k = max(i for i in range(b) if bounds[i] <= v0)
    q = int(band_f[band + 2])
    return int(band_i[q + k + 1] - band_i[q + k])


@pytest.mark.parametrize("scale", [1e-6, 1.0, 1e7])
def test_a_polygon_test_counts_the_edges_its_band_walks(scale):
    """hit_polygon's polygon.corners: its band's edges where the ray meets the plane in range,
    none elsewhere; its hits the brute-force reference's."""
    poly = _star(48, scale)
    scene = Scene()
    scene.root.polygons.add(poly)
    geo, _ = flatten(scene, "list")
    assert geo.poly_band[0] >= 0
    rng = np.random.default_rng(2)
    origins = np.column_stack([rng.uniform(-2, 2, 300), rng.uniform(-2, 2, 300), np.full(300, 3.0)]) * scale
    aims = np.column_stack([rng.uniform(-1.2, 1.2, 300), rng.uniform(-1.2, 1.2, 300), np.zeros(300)]) * scale
    directions = aims - origins
    want = ref.hit_polygon(poly, origins, directions)
    iu, iv, _, _ = polybands.plane_coordinates(int(geo.poly_axis[0]), 0.0, 0.0, 0.0)
    walked = 0
    for r in range(len(origins)):
        cnt = np.zeros(C.N_COUNTERS, np.int64)
        args = (geo.poly_normal, geo.poly_start, geo.poly_count, geo.poly_axis, geo.poly_band, geo.poly_verts,
                geo.poly_band_f, geo.poly_band_i, 0)
        t = hit_polygon(*args, *origins[r], *directions[r], 0.0, np.inf, cnt)
        assert np.isfinite(t) == np.isfinite(want[r])
        point = origins[r] + (-origins[r][2] / directions[r][2]) * directions[r]
        expected = _walked_by_bins(poly, geo.poly_band_f, geo.poly_band_i, geo.poly_band[0], iu, iv,
                                   point[iu], point[iv])
        assert cnt[C.POLYGON_CORNERS] == expected
        walked += expected
        away = np.zeros(C.N_COUNTERS, np.int64)
        assert hit_polygon(*args, *origins[r], *(-directions[r]), 0.0, np.inf, away) == np.inf
        assert away[C.POLYGON_CORNERS] == 0
    assert 0 < walked < 48 * len(origins) / 3      # the bins walk a fraction of the corners


def test_a_render_with_bins_is_the_render_of_the_walk_over_every_corner():
    """SPD gears (faces of up to 144 corners): the same image and counts as with no bins, fewer
    corners walked."""
    from raykernel.scene import spd
    from raykernel.scene.nff import parse_nff
    scene = parse_nff(spd.generate("gears", 1))
    with_bins = render(scene, resolution=48, spd=True)
    original = polybands.MIN_CORNERS
    try:
        polybands.MIN_CORNERS = 10 ** 9         # read when flatten builds the tables
        without = render(scene, resolution=48, spd=True)
    finally:
        polybands.MIN_CORNERS = original
    assert np.array_equal(with_bins.image, without.image)
    a, b = with_bins.stats, without.stats
    assert a["polygon.corners"] < b["polygon.corners"] / 3
    for name in ("tests.polygon", "hits.polygon", "rays.eye", "rays.shadow", "rays.reflect", "rays.refract"):
        assert a[name] == b[name], name
