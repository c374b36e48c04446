"""Work images of a comparison: each run's layer, one scale, ratios and winners, on the command line."""

from __future__ import annotations

import io

import numpy as np
import pytest
from PIL import Image

from raykernel.analysis import compare as cm
from raykernel.analysis.workimages import TIE, WorkImages, figure_png, work_images
from raykernel.errors import OptionError

ACCELS = ["list", "grid", "bvh"]


@pytest.fixture(scope="module")
def cmp():
    return cm.compare(["spd:balls:1", "scene:stadium:ratio=50"], ACCELS, resolution=12, threads=1, model=None,
                      warm_up=False, command="test", work="tests.total")


def test_each_run_keeps_its_layer_and_it_sums_to_the_counter(cmp):
    assert cmp.work == "tests.total" and not cmp.disagreements
    for run in cmp.runs:
        assert run.work.shape == (12, 12)
        assert int(run.work.sum()) == run.stats["tests.total"], (run.scene, run.accel)
    by = {(r.scene, r.accel): r.work for r in cmp.runs}
    # the list tests every object for every ray: more than any structure at every sample
    for scene in cmp.scenes():
        assert (by[scene, "list"] >= by[scene, "bvh"]).all() and (by[scene, "list"] >= by[scene, "grid"]).all()


def test_shared_scale_ratios_and_winners_against_a_per_sample_loop(cmp):
    w = work_images(cmp, "scene:stadium:ratio=50")
    assert w.accels == ACCELS and w.baseline == "list"
    values = [w.layers[a] for a in ACCELS]
    assert w.scale() == (min(float(v.min()) for v in values), max(float(v.max()) for v in values))
    winner = w.winner
    won = dict.fromkeys(ACCELS, 0)
    ties = 0
    for y in range(12):
        for x in range(12):
            counts = [int(v[y, x]) for v in values]
            low = min(counts)
            if counts.count(low) > 1:
                assert winner[y, x] == TIE
                ties += 1
            else:
                assert ACCELS[winner[y, x]] == ACCELS[counts.index(low)]
                won[ACCELS[counts.index(low)]] += 1
            for a, c in zip(ACCELS, counts):
                expect = np.log2((c + 1) / (counts[0] + 1))
                assert w.ratio(a)[y, x] == pytest.approx(expect, abs=1e-12)
    shares = w.shares
    assert shares["tie"] == pytest.approx(ties / 144)
    for a in ACCELS:
        assert shares[a] == pytest.approx(won[a] / 144)
    assert sum(shares.values()) == pytest.approx(1.0)
    assert np.all(w.ratio("list") == 0.0)


def test_ties_and_zero_work_by_hand():
    w = WorkImages("s", "tests.total", {"a": np.array([[0, 4], [2, 7]]), "b": np.array([[0, 1], [2, 9]]),
                                        "c": np.array([[3, 5], [1, 7]])}, baseline="a")
    assert w.winner.tolist() == [[TIE, 1], [2, TIE]]
    assert w.shares == {"a": 0.0, "b": 0.25, "c": 0.25, "tie": 0.5}
    assert w.ratio("b")[0, 0] == 0.0 and w.ratio("c")[0, 0] == 2.0     # (3 + 1) / (0 + 1) stays finite
    assert w.ratio("b")[0, 1] == pytest.approx(np.log2(2 / 5))


def test_figure_is_a_picture_with_every_panel(cmp, tmp_path):
    w = work_images(cmp, "spd:balls:1", baseline="bvh")
    for scale in ("log", "linear"):
        image = Image.open(io.BytesIO(figure_png(w, scale)))
        assert image.size[0] > 600 and image.size[1] > 300
        assert len(np.unique(np.asarray(image.convert("RGB")).reshape(-1, 3), axis=0)) > 50
    with pytest.raises(OptionError, match="scale"):
        figure_png(w, "cubic")


def test_bad_requests_are_named(cmp):
    with pytest.raises(OptionError, match="no scene 'spd:gears'"):
        work_images(cmp, "spd:gears")
    with pytest.raises(OptionError, match="baseline 'octree'"):
        work_images(cmp, "spd:balls:1", baseline="octree")
    plain = cm.compare(["spd:balls:1"], ["bvh"], resolution=4, threads=1, model=None, warm_up=False, command="t")
    with pytest.raises(OptionError, match="no work layers"):
        work_images(plain, "spd:balls:1")
    with pytest.raises(OptionError, match="no work layer 'tests.bogus'"):
        cm.compare(["spd:balls:1"], ["bvh"], resolution=4, model=None, warm_up=False, command="t", work="tests.bogus")
    with pytest.raises(OptionError, match="no work layer 'tests.total.level3'"):
        cm.compare(["spd:balls:1"], ["bvh"], resolution=4, model=None, warm_up=False, command="t",
                   work="tests.total.level3")


def test_command_line(tmp_path, capsys):
    from raykernel.cli import main
    report = tmp_path / "r.html"
    assert main(["compare", "spd:balls:1", "--accel", "list", "--accel", "bvh", "--resolution", "8",
                 "--threads", "1", "--work", "bounds.tests", "--work-images", str(tmp_path),
                 "--report", str(report)]) == 0
    figure = tmp_path / "spd_balls_1.bounds.tests.png"
    assert Image.open(figure).size[0] > 300
    assert str(figure) in capsys.readouterr().out
    assert "class='work'" in report.read_text()
    assert main(["compare", "spd:balls:1", "--accel", "bvh", "--resolution", "8",
                 "--work-images", str(tmp_path / "none")]) == 2
    assert "is not a folder" in capsys.readouterr().err
