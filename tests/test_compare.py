"""raykernel compare / sweep / calibrate: counters, the ray-count check, outputs, the cost model."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

import raykernel
from raykernel.analysis import compare as cm
from raykernel.analysis import costmodel
from raykernel.cli import main

SCENES = ["spd:balls:1", "spd:tetra:1"]
ACCELS = ["list", "grid", "bvh"]
TIMING = set(cm.TIMING_KEYS)


@pytest.fixture(scope="module")
def compared(tmp_path_factory):
    d = tmp_path_factory.mktemp("cmp")
    rc = main(["compare", *SCENES, *sum((["--accel", a] for a in ACCELS), []), "--spd", "--resolution", "8",
               "--threads", "1", "--json", str(d / "c.json"), "--csv", str(d / "c.csv"),
               "--report", str(d / "c.html")])
    return rc, d


def test_compare_exit_status_and_files(compared):
    rc, d = compared
    assert rc == 0
    for name in ("c.json", "c.csv", "c.html"):
        assert (d / name).stat().st_size > 0
    assert not list(d.glob(".*.tmp"))


def test_json_counters_equal_single_renders(compared):
    _, d = compared
    data = json.loads((d / "c.json").read_text())
    assert data["command"].startswith("raykernel compare")
    for key in ("cpu", "cores", "threads", "python", "numpy", "numba", "raykernel"):
        assert key in data["machine"]
    assert len(data["runs"]) == len(SCENES) * len(ACCELS)
    for run in data["runs"]:
        single = raykernel.render(raykernel.load(run["scene"]), accel=run["accel"], resolution=8, spd=True,
                                  threads=1).stats
        expect = {k: v for k, v in single.items() if k not in TIMING}
        got = {k: v for k, v in run["counters"].items() if k not in TIMING}
        assert got == pytest.approx(expect), (run["scene"], run["accel"])


def test_csv_one_row_per_run(compared):
    _, d = compared
    rows = list(csv.DictReader((d / "c.csv").open()))
    assert len(rows) == len(SCENES) * len(ACCELS)
    assert {(r["scene"], r["accel"]) for r in rows} == {(s, a) for s in SCENES for a in ACCELS}
    assert all(int(r["rays.eye"]) == 81 for r in rows)     # 9x9 corner rays at resolution 8


def test_disagreement_fires_for_broken_structure(monkeypatch, tmp_path, capsys):
    real = cm.render

    def broken(scene, accel="bvh", **kw):
        result = real(scene, accel=accel, **kw)
        if accel == "grid":
            result.stats["rays.shadow"] += 1
        return result

    monkeypatch.setattr(cm, "render", broken)
    rc = main(["compare", "spd:balls:1", "--accel", "bvh", "--accel", "grid", "--resolution", "8",
               "--threads", "1", "--json", str(tmp_path / "c.json")])
    assert rc == 3
    err = capsys.readouterr().err
    assert "CORRECTNESS FAILURE" in err
    assert "spd:balls:1" in err and "grid" in err and "bvh" in err and "rays.shadow" in err
    data = json.loads((tmp_path / "c.json").read_text())
    assert data["disagreements"][0]["accel"] == "grid"
    assert list(data["disagreements"][0]["counters"]) == ["rays.shadow"]


def test_agreeing_structures_have_no_disagreement():
    cmp = cm.compare(["spd:balls:1"], ["list", "bvh"], resolution=6, threads=1, model=None, warm_up=False)
    assert cmp.disagreements == []
    assert [r.accel for r in cmp.runs] == ["list", "bvh"]


def test_unknown_accel_is_a_clear_error(capsys):
    assert main(["compare", "spd:balls:1", "--accel", "nosuch", "--resolution", "4"]) == 2
    assert "nosuch" in capsys.readouterr().err


def test_sweep_template_expansion():
    got = cm.expand("scene:stadium:ratio={ratio},teapot_prims={n}", {"ratio": ["1", "10"], "n": ["100"]})
    assert got == [("scene:stadium:ratio=1,teapot_prims=100", {"ratio": "1", "n": "100"}),
                   ("scene:stadium:ratio=10,teapot_prims=100", {"ratio": "10", "n": "100"})]
    with pytest.raises(raykernel.OptionError):
        cm.expand("spd:balls:{sf}", {})
    with pytest.raises(raykernel.OptionError):
        cm.expand("spd:balls:1", {"sf": ["1"]})


def test_stadium_template_loads():
    scene = cm._load_scene("scene:stadium:ratio=10,stadium_prims=500,teapot_prims=100")
    assert scene.count_primitives() > 0
    assert "ratio=10" in scene.source


def test_sweep_writes_plot_and_csv(tmp_path):
    png, out = tmp_path / "sweep.png", tmp_path / "sweep.csv"
    rc = main(["sweep", "spd:balls:{sf}", "--param", "sf=1,2", "--accel", "grid", "--accel", "bvh",
               "--resolution", "8", "--threads", "1", "--plot", str(png), "--csv", str(out),
               "--json", str(tmp_path / "sweep.json")])
    assert rc == 0
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    from PIL import Image
    im = np.asarray(Image.open(png).convert("L"))
    assert im.min() < im.max()
    rows = list(csv.DictReader(out.open()))
    assert [(r["sf"], r["accel"]) for r in rows] == [("1", "grid"), ("1", "bvh"), ("2", "grid"), ("2", "bvh")]
    assert rows[2]["scene"] == "spd:balls:2"
    data = json.loads((tmp_path / "sweep.json").read_text())
    assert data["params"] == {"sf": ["1", "2"]}


# --- cost model -------------------------------------------------------------------------------

def test_fit_recovers_known_costs():
    rng = np.random.default_rng(5)
    true = {"render": 2e-3, "ray.shaded": 3e-7, "ray.shadow": 1e-7, "test.sphere": 2e-8, "test.polygon": 3e-8,
            "step.grid": 1.5e-8, "bound.grid": 0.0, "step.bvh": 4e-9, "bound.bvh": 6e-9}
    rows, times = [], []
    for i in range(60):
        kind = ("grid", "bvh")[i % 2]
        r = {"render": 1.0, "ray.shaded": rng.uniform(1e4, 1e6), "ray.shadow": rng.uniform(1e4, 2e6),
             "test.sphere": rng.uniform(0, 5e7), "test.polygon": rng.uniform(0, 5e7),
             f"step.{kind}": rng.uniform(1e5, 5e7), f"bound.{kind}": rng.uniform(1e5, 5e7)}
        rows.append(r)
        times.append(sum(v * true.get(k, 0.0) for k, v in r.items()))
    got = costmodel.fit(rows, times, ridge=1e-12)
    for name, cost in true.items():
        assert got.get(name, 0.0) == pytest.approx(cost, rel=1e-3, abs=1e-12), name


def test_split_fit_prices_refinement_from_its_own_time():
    # references refined move with the steps here, so one fit cannot tell their costs apart; with
    # the refinement's share of the time known both come out exact, and renders whose refinement
    # outlasted their trace (a compile inside) are left out
    rng = np.random.default_rng(7)
    true = {"render": 1e-3, "ray.shaded": 2e-7, "step.octree": 2e-8, "test.sphere": 1e-8,
            "refine.pass": 5e-5, "refine.octree.subdivision": 8e-6, "refine.octree.ref": 1e-7}
    rows, times, refine = [], [], []
    for _ in range(40):
        steps = rng.uniform(1e5, 1e7)
        r = {"render": 1.0, "ray.shaded": rng.uniform(1e4, 1e6), "step.octree": steps,
             "test.sphere": rng.uniform(1e5, 1e7), "refine.pass": rng.uniform(50, 300),
             "refine.octree.subdivision": rng.uniform(1e2, 1e4), "refine.octree.ref": 0.1 * steps}
        rows.append(r)
        refine.append(sum(v * true[k] for k, v in r.items() if k.startswith("refine.")))
        times.append(sum(v * true[k] for k, v in r.items()))
    rows.append(dict(rows[0]))                   # a compile inside its refinement: left out
    times.append(times[0])
    refine.append(times[0] + 5.0)
    got = costmodel.fit_split(rows, times, refine, ridge=1e-12)
    for name, cost in true.items():
        assert got.get(name, 0.0) == pytest.approx(cost, rel=1e-3), name
    assert costmodel.unscaled("refine.rc.ref") and costmodel.unscaled("render")
    assert not costmodel.unscaled("step.rc")


def test_fit_keeps_costs_non_negative():
    rows = [{"a": 1.0, "b": 1.0}, {"a": 2.0, "b": 1.0}, {"a": 3.0, "b": 1.0}]
    got = costmodel.fit(rows, [1.0, 1.9, 2.8])
    assert all(v >= 0 for v in got.values())


def test_predictions_positive_and_round_trip(tmp_path):
    result = raykernel.render(raykernel.load("spd:balls:1"), accel="grid(density=3)", resolution=8, threads=1)
    model = costmodel.CostModel(costs={"render": 1e-4, "ray.shaded": 1e-7, "ray.shadow": 5e-8, "test.sphere": 1e-8,
                                       "test.polygon": 1e-8, "step.grid": 1e-8, "bound.grid": 1e-8}, threads=1)
    p = model.predict(result.stats)
    assert p is not None and p > 0
    bvh_stats = raykernel.render(raykernel.load("spd:balls:1"), accel="bvh", resolution=8, threads=1).stats
    assert model.predict(bvh_stats) is None                     # the bvh walk was not calibrated
    assert model.predict(bvh_stats, partial=True) > 0
    model.save(tmp_path / "cal.json")
    again = costmodel.CostModel.load(tmp_path / "cal.json")
    assert again.predict(result.stats) == pytest.approx(model.predict(result.stats))


def test_an_older_machine_calibration_falls_back_to_the_reference(tmp_path, monkeypatch):
    """A calibration file of another version prices other features: current() warns and uses the
    reference costs; loading it by name is a clear error."""
    old = tmp_path / "raykernel" / "calibration-old.json"
    old.parent.mkdir()
    old.write_text(json.dumps({"version": costmodel.VERSION - 1, "costs": {"render": 1.0}, "threads": 2}))
    monkeypatch.setattr(costmodel, "default_path", lambda: old)
    with pytest.warns(RuntimeWarning, match="older raykernel"):
        model = costmodel.current()
    assert model.costs == costmodel.CostModel.load(costmodel.REFERENCE_PATH).costs
    with pytest.raises(raykernel.errors.OptionError, match="run `raykernel calibrate` again"):
        costmodel.CostModel.load(old)


def test_the_speed_probe_times_calibration_renders_again():
    """Per kind, the anchors are the calibration runs nearest ANCHOR_SECONDS; the factor is the
    geometric mean of each anchor's best time now over its time in the calibration; a scene the
    calibration rendered under one kind (ONE_KIND) is rendered so again."""
    park = "scene:park:rides=1,horses=2,trees=4,mountain_level=1"
    runs = [{"scene": "spd:balls:1", "accel": "grid", "resolution": 8, "trace": t} for t in (1e-5, 0.08, 3.0)]
    runs += [{"scene": park + costmodel.ONE_KIND, "accel": "bvh", "resolution": 8, "trace": 2e-3},
             {"scene": "spd:tetra:1", "accel": "bvh", "resolution": 8, "trace": 0.0}]       # never an anchor
    model = costmodel.CostModel(costs={}, threads=1, calibration=runs)
    probe = costmodel.SpeedProbe(model, per_kind=2, threads=1)
    assert [(a["accel"], a["trace"]) for a in probe.anchors] == [("grid", 0.08), ("grid", 3.0), ("bvh", 2e-3)]
    assert probe.factor() == 1.0 and probe.ratios() == []
    probe.measure()
    first = list(probe.best)
    probe.measure()
    assert all(0 < b <= f for b, f in zip(probe.best, first))
    ratios = [b / a["trace"] for b, a in zip(probe.best, probe.anchors)]
    assert probe.ratios() == ratios
    assert probe.factor() == pytest.approx(float(np.prod(ratios)) ** (1 / 3))
    # the park's anchor was rendered wholly under the bvh: one aggregate, no group's own
    one_kind = probe._scene(park + costmodel.ONE_KIND)
    assert not costmodel._names_structures(one_kind.root)
    assert costmodel._names_structures(raykernel.load(park).root)
    probe.reset()
    assert probe.factor() == 1.0


def test_calibrate_small(tmp_path):
    model = costmodel.calibrate(kinds=["bvh"], scenes=("spd:balls:1", "spd:tetra:1"), resolutions=(8, 12),
                                threads=1, repeats=1)
    scene = raykernel.load("spd:balls:1")
    assert model.covers(raykernel.render(scene, accel="bvh", resolution=4, threads=1).stats)
    assert not model.covers(raykernel.render(scene, accel="grid", resolution=4, threads=1).stats)
    assert all(v >= 0 for v in model.costs.values())
    assert len(model.calibration) == 4
    assert all(r["predicted"] > 0 for r in model.calibration)


def test_compare_shows_predictions_with_a_calibration(tmp_path):
    model = costmodel.CostModel(costs={"render": 1e-4, "ray.shaded": 1e-7, "ray.shadow": 5e-8,
                                       "test.sphere.wide": 1e-8, "test.polygon.wide": 1e-8, "step.wide": 1e-8,
                                       "bound.wide": 1e-8}, threads=1)
    model.save(tmp_path / "cal.json")
    cmp = cm.compare(["spd:balls:1"], ["bvh", "list"], resolution=6, threads=1, model=str(tmp_path / "cal.json"),
                     warm_up=False)
    assert cmp.runs[0].predicted > 0 and cmp.runs[1].predicted is None
    rows = list(cm.table_rows(cmp))
    assert rows[1][2][[h for h, _, _ in cm.COLUMNS].index("predicted s")] == "-"
