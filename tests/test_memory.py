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
