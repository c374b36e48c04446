"""Heckbert's minimal ray tracer, exactly: `--shading heckbert` against a plain-Python
transcription of the program printed in "Ray Tracing News" 2(1)."""

import math

import numpy as np
import pytest
from PIL import Image

from raykernel.cli import main
from raykernel.errors import OptionError
from raykernel.rendering.render import render
from raykernel.scene.loading import load
from raykernel.scene.model import Camera, Material, Scene

# the program's table: centre, colour, radius, kd, ks, kt, kl, ir
SPHERES = [
    ((0.0, 6.0, 0.5), (1.0, 1.0, 1.0), 0.9, 0.05, 0.2, 0.85, 0.0, 1.7),
    ((-1.0, 8.0, -0.5), (1.0, 0.5, 0.2), 1.0, 0.7, 0.3, 0.0, 0.05, 1.2),
    ((1.0, 8.0, -0.5), (0.1, 0.8, 0.8), 1.0, 0.3, 0.7, 0.0, 0.0, 1.2),
    ((3.0, -6.0, 15.0), (1.0, 0.8, 1.0), 7.0, 0.0, 0.0, 0.0, 0.6, 1.5),
    ((-3.0, -3.0, 12.0), (0.8, 1.0, 1.0), 5.0, 0.0, 0.0, 0.0, 0.5, 1.5),
]
AMBIENT = (0.02, 0.02, 0.02)
BLACK = (0.0, 0.0, 0.0)


def dot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def comb(a, A, B):          # the program's vcomb: a A + B
    return (B[0] + a * A[0], B[1] + a * A[1], B[2] + a * A[2])


def unit(A):
    return comb(1.0 / math.sqrt(dot(A, A)), A, BLACK)


def nearest(P, D, spheres):
    """The program's intersect: spheres from last to first, the nearest root >= 1e-7."""
    best, tmin = None, 1e30
    for s in reversed(range(len(spheres))):
        cen, rad = spheres[s][0], spheres[s][2]
        U = comb(-1.0, P, cen)
        b = dot(D, U)
        u = b * b - dot(U, U) + rad * rad
        u = math.sqrt(u) if u > 0 else 1e31
        u = b - u if b - u > 1e-7 else b + u
        if u >= 1e-7 and u < tmin:
            best, tmin = s, u
    return best, tmin


def trace(level, P, D, spheres):
    if level == 0:
        return BLACK
    level -= 1
    s, t = nearest(P, D, spheres)
    if s is None:
        return AMBIENT
    cen, scol, _, kd, ks, kt, kl, ir = spheres[s]
    color = AMBIENT
    eta = ir
    P = comb(t, D, P)
    N = unit(comb(-1.0, P, cen))        # the program's N: centre - P
    d = -dot(D, N)
    if d < 0:
        N, eta, d = comb(-1.0, N, BLACK), 1.0 / eta, -d
    for li in reversed(range(len(spheres))):
        l_cen, l_col, l_kl = spheres[li][0], spheres[li][1], spheres[li][6]
        U = unit(comb(-1.0, P, l_cen))
        e = l_kl * dot(N, U)
        if e > 0 and nearest(P, U, spheres)[0] == li:
            color = comb(e, l_col, color)
    color = (color[0] * scol[0], color[1] * scol[1], color[2] * scol[2])
    e = 1 - eta * eta * (1 - d * d)
    refracted = trace(level, P, comb(eta, D, comb(eta * d - math.sqrt(e), N, BLACK)), spheres) if e > 0 else BLACK
    reflected = trace(level, P, comb(2 * d, N, D), spheres)
    return comb(kt, refracted, comb(ks, reflected, comb(kd, color, comb(kl, scol, BLACK))))


def program_picture(n, spheres=SPHERES):
    """What the printed program prints for an n x n image (255 x value, not clamped)."""
    out = np.zeros((n, n, 3))
    for yx in range(n * n):
        U = (yx % n - n // 2, (n // 2) / math.tan(25 / 114.5915590261), n // 2 - yx // n)
        out[yx // n, yx % n] = comb(255.0, trace(3, BLACK, unit(U), spheres), BLACK)
    return out


def test_the_command_line_writes_the_programs_picture(tmp_path):
    out = tmp_path / "heckbert.png"
    assert main(["render", "example:heckbert", "--resolution", "32", "-o", str(out)]) == 0
    ours = np.asarray(Image.open(out).convert("RGB")).astype(float)
    expected = np.clip(program_picture(32), 0, 255)
    assert np.abs(ours - expected).max() <= 1.0
    # the luminous spheres are seen, not only their light: the picture has pixels far above the others
    assert expected.max() > 100


@pytest.mark.slow      # Heckbert's kernel with the general driver: compiled for this test alone
@pytest.mark.parametrize("accel", ["list", "grid", "octree"])
def test_the_model_does_not_depend_on_the_structure(accel):
    scene = load("example:heckbert")
    result = render(scene, accel=accel, resolution=24, max_depth=3, shading="heckbert")
    assert np.allclose(result.image * 255, program_picture(24), atol=1e-6)


def test_the_emitters_show_in_a_view_of_them_and_light_what_they_face():
    # looking back at the two luminous spheres: each shows its own kl x colour and nothing else
    scene = load("example:heckbert")
    scene.camera = Camera(eye=(0, 0, 0), look_at=(3, -6, 15), up=(0, 0, 1), angle=10.0, width=9, height=9)
    image = render(scene, resolution=9, max_depth=3, shading="heckbert").image
    glow = 0.6 * np.array([1.0, 0.8, 1.0])
    assert np.allclose(image[4, 4], glow)


def test_an_odd_size_uses_the_programs_integer_halves():
    n = 7
    scene = load("example:heckbert")
    image = render(scene, resolution=n, max_depth=3, shading="heckbert").image
    assert np.allclose(image * 255, program_picture(n), atol=1e-6)


def test_a_sphere_between_a_point_and_an_emitter_shadows_it():
    # a lamp above, a small sphere under it, a big sphere as the floor: the floor has the small
    # sphere's shadow, and the picture is still the program's, pixel for pixel
    spheres = [((0.0, 8.0, -101.0), (0.9, 0.9, 0.9), 100.0, 0.8, 0.1, 0.0, 0.0, 1.0),
               ((0.0, 8.0, 0.2), (1.0, 0.3, 0.3), 0.5, 0.6, 0.3, 0.0, 0.0, 1.0),
               ((0.5, 9.0, 6.0), (1.0, 1.0, 0.9), 2.0, 0.0, 0.0, 0.0, 0.9, 1.0)]
    scene = Scene(camera=Camera(eye=(0, 0, 0), look_at=(0, 1, 0), up=(0, 0, 1), angle=25.0), background=AMBIENT)
    for center, color, radius, kd, ks, kt, kl, ior in spheres:
        m = scene.add_material(Material(color=color, kd=kd, ks=ks, t=kt, kl=kl, ior=ior))
        scene.root.spheres.add(center, radius, m)
    result = render(scene, resolution=32, max_depth=3, shading="heckbert")
    assert result.stats["rays.shadow_blocked"] > 0
    assert result.stats["rays.shadow"] > result.stats["rays.shadow_blocked"]
    assert np.allclose(result.image * 255, program_picture(32, spheres), atol=1e-6)


def test_spd_mode_refuses_other_shading():
    scene = load("example:heckbert")
    with pytest.raises(OptionError, match="SPD mode"):
        render(scene, resolution=8, spd=True, shading="heckbert")
    with pytest.raises(OptionError, match="unknown shading"):
        render(scene, resolution=8, shading="phong")
