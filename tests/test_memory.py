"""The memory budget: every build and lazy refinement stops with one clear error instead of
taking the machine's memory or failing inside a builder."""

import subprocess
import sys

import numpy as np
import pytest

import raykernel
from raykernel.aggregates.memory import MemoryBudgetError, memory_limit, parse_size, physical_memory
from raykernel.cli import main
from raykernel.engine.flatten import flatten
from raykernel.errors import OptionError


@pytest.mark.parametrize("text,expected", [("512M", 512 << 20), ("8G", 8 << 30), ("1.5g", int(1.5 * (1 << 30))),
                                           ("123456", 123456), ("64k", 64 << 10), ("2GiB", 2 << 30),
                                           (" 1T ", 1 << 40)])
def test_sizes(text, expected):
    assert parse_size(text) == expected


@pytest.mark.parametrize("text", ["", "0", "-1G", "G", "8X", "1e9", "lots"])
def test_bad_sizes_name_the_option(text):
    with pytest.raises(OptionError, match="max-memory"):
        parse_size(text)


def test_default_is_a_safe_share_of_the_machine():
    assert 0 < memory_limit() <= physical_memory()
    assert memory_limit(12345) == 12345 and memory_limit("1M") == 1 << 20
    with pytest.raises(OptionError):
        memory_limit(-5)


@pytest.fixture(scope="module")
def balls():
    return raykernel.load("spd:balls:2")


@pytest.mark.parametrize("spec,what,hint,budget", [
    ("octree(depth=24, budget=0, leaf=1)", "octree", "depth", "48M"),
    ("hybrid(depth=24, budget=0, leaf=1, rule60=off)", "octree", "depth", "48M"),
    ("rc(lazy=off, budget_mb=100000, leaf=1)", "ray classification", "budget_mb", "4M"),
    ("grid(density=1000, max_res=4096)", "grid", "density", "1M"),
])
def test_builds_stop_at_the_budget(balls, spec, what, hint, budget):
    with pytest.raises(MemoryBudgetError) as err:
        flatten(balls, spec, max_memory=budget)
    message = str(err.value)
    assert what in message and hint in message and "--max-memory" in message
    assert f"{budget[:-1]}.0 MiB" in message


def test_the_same_builds_pass_with_room(balls):
    geo, build = flatten(balls, "rc(lazy=off, budget_mb=4)", max_memory="1G")
    assert build["build.nodes"] > 6


def test_lazy_refinement_stops_at_the_budget(balls):
    with pytest.raises(MemoryBudgetError, match="lazy octree"):
        raykernel.render(balls, accel="lazyoctree(depth=24, budget=0)", resolution=64, spd=True,
                         max_memory="2M")


def test_lazy_rc_stops_at_the_budget(balls):
    with pytest.raises(MemoryBudgetError, match="lazy ray classification"):
        raykernel.render(balls, accel="rc(budget_mb=100000, leaf=1)", resolution=64, spd=True, max_memory="1M")


def test_rayscene_takes_the_budget(balls):
    with pytest.raises(MemoryBudgetError):
        raykernel.RayScene(balls, accel="octree(depth=24, budget=0, leaf=1)", max_memory="48M")


def test_cli_prints_one_line(tmp_path, capsys):
    out = tmp_path / "o.png"
    code = main(["render", "spd:balls:2", "--accel", "octree(depth=24,budget=0,leaf=1)", "--max-memory", "48M",
                 "-o", str(out), "--resolution", "8"])
    assert code == 2
    err = capsys.readouterr().err.strip()
    assert "octree" in err and "needs" in err and "Traceback" not in err
    assert not out.exists()


def test_cli_bad_size(tmp_path, capsys):
    assert main(["render", "spd:balls:1", "--max-memory", "lots", "-o", str(tmp_path / "o.png")]) == 2
    assert "max-memory" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.parametrize("spec", ["octree(depth=24,budget=0,leaf=1)", "rc(lazy=off,budget_mb=100000)"])
def test_under_an_address_space_limit(tmp_path, spec):
    """Under an 8 GB address-space limit the default budget (half of it) stops the build with the
    error, not a MemoryError traceback from inside the builder."""
    code = ("import resource, sys; resource.setrlimit(resource.RLIMIT_AS, (8 << 30, 8 << 30)); "
            "from raykernel.cli import main; sys.exit(main(sys.argv[1:]))")
    run = subprocess.run([sys.executable, "-c", code, "render", "spd:balls", "--accel", spec, "--resolution", "16",
                          "-o", str(tmp_path / "o.png")], capture_output=True, text=True, timeout=1800)
    assert run.returncode == 2, run.stderr[-2000:]
    assert "memory budget" in run.stderr and "Traceback" not in run.stderr
    assert np.all([line.strip() for line in run.stderr.strip().splitlines()][-1:])


def _limited(args, limit=3 << 30):
    """The command line under an address-space limit, in a process of its own."""
    code = (f"import resource, sys; resource.setrlimit(resource.RLIMIT_AS, ({limit}, {limit})); "
            "from raykernel.cli import main; sys.exit(main(sys.argv[1:]))")
    return subprocess.run([sys.executable, "-c", code] + args, capture_output=True, text=True, timeout=900)


@pytest.mark.parametrize("args,what", [
    (["--resolution", "16384"], "16384x16384 render"),
    (["--resolution", "4096", "--work", "w.npz"], "work layers"),
    (["--resolution", "8000", "--aa", "adaptive", "--aa-depth", "4"], "8000x8000 render"),
    (["--resolution", "16384", "--max-memory", "1T"], "out of memory"),
    (["--resolution", "100000"], "resolution must be"),
    (["--aa", "jitter", "--samples", "1000000"], "samples must be"),
])
def test_huge_renders_give_one_line_under_an_address_space_limit(tmp_path, args, what):
    out = tmp_path / "big.png"
    run = _limited(["render", "spd:tetra:2", "-o", str(out)] + [str(tmp_path / a) if a.endswith(".npz") else a
                                                               for a in args])
    assert run.returncode == 2, run.stderr[-2000:]
    last = run.stderr.strip().splitlines()[-1]
    assert last.startswith("raykernel: error:") and what in last and "Traceback" not in run.stderr
    assert not out.exists() and list(tmp_path.iterdir()) == []


def test_the_budget_holds_the_image(balls):
    from raykernel.rendering.render import render
    with pytest.raises(MemoryBudgetError, match="400x400 render"):
        render(balls, accel="list", resolution=400, max_memory="10M")
    assert render(balls, accel="list", resolution=40, max_memory="10M").image.shape == (40, 40, 3)


@pytest.mark.parametrize("query", ["intersect", "occluded", "count_hits", "intersect_all"])
def test_huge_ray_batches_stop_before_allocating(balls, query):
    from raykernel import RayScene
    scene = RayScene(balls, max_memory="64M")
    n = 10 ** 9     # views of one ray: nothing is allocated until the query copies them
    o = np.broadcast_to(np.array([0.0, 0.0, 5.0]), (n, 3))
    d = np.broadcast_to(np.array([0.0, 0.0, -1.0]), (n, 3))
    with pytest.raises(MemoryBudgetError, match=f"RayScene.{query} of 1,000,000,000 rays"):
        getattr(scene, query)(o, d)
    assert np.all(np.isfinite(scene.intersect(o[:5], d[:5]).t))       # and the scene still answers


def test_intersect_all_checks_the_hits_before_keeping_them():
    from raykernel import RayScene
    centers = np.zeros((2000, 3))
    centers[:, 2] = np.arange(2000) * 3.0      # a ray along z meets all 2,000 spheres
    scene = RayScene.from_spheres(centers, np.ones(2000))
    scene._limit = 4 << 20
    o = np.tile([0.0, 0.0, -10.0], (100, 1))
    d = np.tile([0.0, 0.0, 1.0], (100, 1))
    with pytest.raises(MemoryBudgetError, match="intersect_all"):
        scene.intersect_all(o, d)
    scene._limit = 1 << 30
    ray, t, prim = scene.intersect_all(o, d)
    assert len(ray) == 200_000


def test_a_huge_ray_batch_under_an_address_space_limit_is_one_line():
    code = ("import resource, sys; resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30)); "
            "import numpy as np; from raykernel import RayScene; from raykernel.errors import RayKernelError; "
            "scene = RayScene.from_spheres(np.zeros((1, 3)), np.ones(1)); "
            "o = np.broadcast_to(np.array([0.0, 0.0, 5.0]), (400_000_000, 3)); "
            "d = np.broadcast_to(np.array([0.0, 0.0, -1.0]), (400_000_000, 3))\n"
            "try:\n    scene.intersect(o, d)\nexcept RayKernelError as e:\n    print(type(e).__name__, e)")
    run = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=600)
    assert run.returncode == 0 and "Traceback" not in run.stderr, run.stderr[-2000:]
    assert run.stdout.startswith("MemoryBudgetError RayScene.intersect of 400,000,000 rays")
    assert len(run.stdout.strip().splitlines()) == 1
