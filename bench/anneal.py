"""Annealed hierarchies against the anchors: every single kind at its defaults, the SAH BVH
with its two optimisers and over split pieces (bvh(split=16)), the best hand-nested specs,
and `auto`; the cost model's error on every run; re-annealing between the frames of an
animation.

    .venv/bin/python bench/anneal.py [--resolution 256] [--seconds 30] [--scenes spd:balls,scene:park]
                                     [--frames 6] [--repeat 3] [--min-seconds 1] [--head-to-head 10]
                                     [--calibrate]

Scenes: the 13 SPD default scenes, the 5 pathological scenes and scene:park, each rendered
in SPD mode at --resolution with every structure: a single kind puts the whole scene under
that kind (anneal.without_specs: no group keeps a spec of its own), the hand-nested runs
keep their groups' specs. Trace time: the best of --repeat rounds over all of a scene's
structures (more for short traces: --min-seconds), auto's included, so that none is timed
first or right after the annealing; then the best single kind and auto alternately,
--head-to-head rounds more each, since their ratio is the verdict. `auto` is annealed for
that render (auto(seconds=...), seed 0); its annealing seconds are reported apart, never
inside the trace time. Every structure of a scene must give the same ray counts (a
difference aborts the run). Where every counter of auto's render equals the best single
kind's (it kept that structure), the verdict says so: their time ratio is then the machine's
noise, and the count of scenes where auto is at least 10% faster leaves them out. Ranking:
of the pairs of single kinds on one scene whose measured times differ by more than 10%, how
many the model orders the same way. The brute-force list is left out: on these scenes it
takes hours. Predicted: the cost model's trace seconds from each render's own counts
(costmodel.current(): this machine's calibration, else the reference costs shipped with
raykernel; with --calibrate, a model fitted at the start of the run, which auto uses too),
at the machine's speed during the scene (costmodel.SpeedProbe: calibration renders timed
again in the scene's first rounds), against the measured trace seconds; the errors at the
calibration's speed are reported too.

Hand-nested: the stadium's teapot in a BVH of its own (teapot_bvh=1) under a grid and
under an octree (Haines's fix), the better kept; the park's own hierarchy (Arvo's: a coarse
grid over the park, a grid per ride, BVHs around a horse and its rider and around a tree);
ray classification at the park's top (top=1), his later variant.

Frames: the satellite over --frames frames of its orbit, annealed from scratch for each
frame against re-annealed from the previous frame's hierarchy (short schedule, a quarter of
the candidates), the cost per frame and the energy reached.
Writes the `anneal` section of BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import sys
import time
from datetime import date

import numpy as np
from _report import DETAILS, machine, replace_section, subtable

import raykernel
from raykernel.analysis import anneal, costmodel
from raykernel.scene import pathological, spd

# the summary in BENCHMARKS.md: the verdicts where auto did work of its own, these columns
SUMMARY = "Where auto's hierarchy is its own (measured trace time; every scene's verdict in the full tables):"
COLUMNS = ["scene", "best single kind", "best single / auto", "best hand / auto"]

KINDS = ("bvh", "grid", "hgrid", "octree", "hybrid", "rc", "lazyoctree")
OPTIMISED = ("bvh(optimize=rotations)", "bvh(optimize=reinsertion)", "bvh(split=16)")   # the SAH BVH's variants
RAYS = ("rays.eye", "rays.reflect", "rays.refract", "rays.shadow")
MAX_ROUNDS = 25


def work(stats):
    """The counted work of a render: two renders with equal work ran the same traversal, and
    any difference in their times is the machine's."""
    return {k: v for k, v in stats.items()
            if k.startswith(("tests.", "walk.", "rays.")) or k in ("bounds.tests", "cells.visited", "cells.leaves")}


def scenes(names):
    """The names given, else the 13 SPD default scenes, the pathological scenes and the park."""
    return names or [f"spd:{n}" for n in spd.NAMES] + [f"scene:{n}" for n in pathological.NAMES]


def hand_variants(name):
    """(label, scene, accel) of the best hand-nested specs a scene has."""
    if name.startswith("scene:stadium"):
        nested = raykernel.load(name + (",teapot_bvh=1" if ":" in name[6:] else ":teapot_bvh=1"))
        return [("hand: grid + teapot bvh", nested, "grid"), ("hand: octree + teapot bvh", nested, "octree")]
    if name.startswith("scene:park"):
        return [("hand: Arvo's (grid top)", raykernel.load(name), None),
                ("hand: Arvo's (rc top)", raykernel.load(name + ":top=1" if ":" not in name[6:] else name + ",top=1"),
                 None)]
    return []


def trace(scene, accel, options):
    """The statistics of one render (accel None: the scene's own specs)."""
    return raykernel.render(scene, **options).stats if accel is None else \
        raykernel.render(scene, accel=accel, **options).stats


def scene_rows(name, args, model, probe, errors):
    scene = raykernel.load(name)
    options = dict(resolution=args.resolution, spd=True)
    t0 = time.perf_counter()
    found = anneal.anneal(scene, seconds=args.seconds, seed=0, options=options, model=model)
    seconds = time.perf_counter() - t0
    single = anneal.without_specs(scene)        # every group under the one kind
    runs = [(accel, single, accel) for accel in KINDS + OPTIMISED] + hand_variants(name) + [("auto", found.scene, None)]
    # rounds over every structure, the best kept: no structure is timed first or just after
    # the annealing (a first render after other work runs slow); a structure is rendered again
    # until it has had `repeat` rounds and `min_seconds` of trace time in all (short traces
    # are the noisiest), or MAX_ROUNDS rounds
    best, rounds, traced = {}, {}, {}
    raykernel.render(scene, resolution=8, spd=True)
    probe.reset()
    for round_ in range(MAX_ROUNDS):
        due = [run for run in runs if rounds.get(run[0], 0) < args.repeat or
               traced.get(run[0], 0.0) < args.min_seconds]
        if not due:
            break
        for label, s, accel in due:
            stats = trace(s, accel, options)
            rounds[label] = rounds.get(label, 0) + 1
            traced[label] = traced.get(label, 0.0) + stats["time.trace"]
            if label not in best or stats["time.trace"] < best[label]["time.trace"]:
                best[label] = stats
        if round_ < args.repeat:        # the machine's speed, in the same rounds
            probe.measure()
    speed = probe.factor()
    # head to head: the best single kind and auto alternately, `head_to_head` more rounds each,
    # since their ratio is the verdict and both traces can be short
    singles = {label: best[label]["time.trace"] for label in KINDS}
    best_single = min(singles, key=singles.get)
    pair = [run for run in runs if run[0] in (best_single, "auto")]
    for _ in range(args.head_to_head):
        for label, s, accel in pair:
            stats = trace(s, accel, options)
            if stats["time.trace"] < best[label]["time.trace"]:
                best[label] = stats
    ref = best["bvh"]
    for label, stats in best.items():
        if any(stats[k] != ref[k] for k in RAYS):
            sys.exit(f"{name}: {label} casts other rays than bvh: "
                     f"{[stats[k] for k in RAYS]} against {[ref[k] for k in RAYS]}")
    out = []
    singles = {label: best[label]["time.trace"] for label in KINDS}
    for label, _, _ in runs:
        stats = best[label]
        calibrated = model.predict(stats)
        predicted = None if calibrated is None else calibrated * speed
        measured = stats["time.trace"]
        if predicted is not None and label in KINDS:
            errors.append((name, label, predicted / measured - 1.0, calibrated / measured - 1.0))
        auto = label == "auto"
        out.append({"scene": name, "structure": label, "predicted": predicted, "measured": measured,
                    "tests_per_ray": stats["tests.per_ray"], "bounds_per_ray": stats["bounds.per_ray"],
                    "mb": stats.get("build.bytes", 0) / 2 ** 20, "rays": stats["rays.total"],
                    "anneal": seconds if auto else None, "vs_best": singles[best_single] / measured,
                    "found": found if auto else None,
                    "same_work": work(stats) == work(best[best_single]), "speed": speed})
    print(f"{name}: best single {best_single} {singles[best_single]:.4f} s; auto {out[-1]['measured']:.4f} s "
          f"({out[-1]['vs_best']:.2f}x), annealed {seconds:.1f} s", flush=True)
    return out, best_single


def summary(errors):
    """Mean absolute, worst and count within 25% of relative errors."""
    return (f"mean absolute error {100 * np.abs(errors).mean():.0f}%, worst "
            f"{100 * errors[np.argmax(np.abs(errors))]:+.0f}%, within 25%: {int(np.sum(np.abs(errors) <= 0.25))} "
            f"of {len(errors)}")


def fmt(x, spec):
    return "-" if x is None else format(x, spec)


def frame_rows(frames, resolution, evaluations, model):
    """Satellite frames: anneal from scratch each frame against re-annealing from the last."""
    options = dict(resolution=resolution, spd=True)
    lines = []
    previous = None
    times = np.linspace(0.0, 600.0, frames)
    for k, t in enumerate(times):
        scene = raykernel.load(f"scene:satellite:time={t:g}")
        t0 = time.perf_counter()
        scratch = anneal.anneal(scene, seed=0, evaluations=evaluations, seconds=1e6, options=options, model=model)
        s_sec = time.perf_counter() - t0
        if previous is None:
            again, a_sec = scratch, s_sec
        else:
            start, atoms = anneal.rebind(previous.state, previous.atoms, scene)
            t0 = time.perf_counter()
            again = anneal.anneal(scene, seed=0, evaluations=max(8, evaluations // 4), seconds=1e6, start=start,
                                  atoms=atoms, short=True, options=options, model=model)
            a_sec = time.perf_counter() - t0
        previous = again
        lines.append(f"| {k} | {t:g} | {scratch.evaluations} | {s_sec:.1f} | {scratch.energy * 1e3:.2f} "
                     f"| {again.evaluations} | {a_sec:.1f} | {again.energy * 1e3:.2f} |")
    return lines


def main():
    parser = argparse.ArgumentParser()
    parser.add_argument("--resolution", type=int, default=256)
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--scenes", help="comma-separated scene names (default: the 19)")
    parser.add_argument("--frames", type=int, default=6)
    parser.add_argument("--frame-evaluations", type=int, default=200)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--head-to-head", type=int, default=10,
                        help="then render the best single kind and auto alternately this many rounds more")
    parser.add_argument("--min-seconds", type=float, default=0.0,
                        help="render each structure again until its trace times add up to this (at most "
                             f"{MAX_ROUNDS} rounds)")
    parser.add_argument("--calibrate", action="store_true",
                        help="fit the cost model on this machine first (raykernel calibrate, some 8 minutes) and "
                             "price every run and auto with it: the machine's speed drifts between runs")
    args = parser.parse_args()
    if args.calibrate:
        t0 = time.perf_counter()
        model = costmodel.calibrate()
        calibrated = f"fitted at the start of this run ({time.perf_counter() - t0:.0f} s)"
    else:
        model = costmodel.current()
        calibrated = "this machine's" if costmodel.load_default() else "the reference costs"
    probe = costmodel.SpeedProbe(model)
    names = args.scenes.split(",") if args.scenes else None
    table, errors, verdicts = [], [], []
    stadium = {}
    for name in scenes(names):
        rows, best_single = scene_rows(name, args, model, probe, errors)
        table += rows
        auto = rows[-1]
        hand = [r for r in rows if r["structure"].startswith("hand")]
        verdicts.append((name, best_single, auto, min((r["measured"] for r in hand), default=None)))
        if name.startswith("scene:stadium"):
            stadium[name] = (min(hand, key=lambda r: r["tests_per_ray"]), auto)
    if names is None:       # the stadium at ratio 600 is its default; and at 10^6
        name = "scene:stadium:ratio=1e6"
        rows, best_single = scene_rows(name, args, model, probe, errors)
        table += rows
        hand = [r for r in rows if r["structure"].startswith("hand")]
        verdicts.append((name, best_single, rows[-1], min(r["measured"] for r in hand)))
        stadium[name] = (min(hand, key=lambda r: r["tests_per_ray"]), rows[-1])
    lines = ["| scene | structure | predicted s | measured s | model error | tests/ray | bounds/ray | MB "
             "| anneal s | best single / this |", "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for r in table:
        err = None if r["predicted"] is None else r["predicted"] / r["measured"] - 1.0
        lines.append(f"| {r['scene']} | {r['structure']} | {fmt(r['predicted'], '.4f')} | {r['measured']:.4f} "
                     f"| {fmt(None if err is None else 100 * err, '+.0f')}% | {r['tests_per_ray']:.2f} "
                     f"| {r['bounds_per_ray']:.2f} | {r['mb']:.1f} | {fmt(r['anneal'], '.1f')} "
                     f"| {r['vs_best']:.2f}x |")
    found_trees = [f"**{r['scene']}**, auto found (predicted {r['found'].energy:.4f} s against "
                   f"{r['found'].best_single[1]:.4f} s for {r['found'].best_single[0]}):\n\n```\n{r['found'].after}\n```"
                   for r in table if r["found"] is not None and r["scene"].startswith("scene:")]
    errs = np.array([e for _, _, e, _ in errors])
    raw = np.array([e for _, _, _, e in errors])
    by_kind = {}
    for _, kind, e, _ in errors:
        by_kind.setdefault(kind, []).append(e)
    # ranking: pairs of single kinds on one scene whose measured times differ by more than 10%
    pairs = agree = 0
    singles = [r for r in table if r["structure"] in KINDS and r["predicted"] is not None]
    for a in singles:
        for b in singles:
            if a["scene"] == b["scene"] and a["measured"] > 1.1 * b["measured"]:
                pairs += 1
                agree += a["predicted"] > b["predicted"]
    model_lines = ["| kind | runs | mean abs error | worst |", "|---|---:|---:|---:|"]
    for kind, es in by_kind.items():
        es = np.array(es)
        model_lines.append(f"| {kind} | {len(es)} | {100 * np.abs(es).mean():.0f}% "
                           f"| {100 * es[np.argmax(np.abs(es))]:+.0f}% |")
    verdict_lines = ["| scene | rays (each structure) | best single kind | best single / auto | auto's work "
                     "| best hand / auto | machine speed |", "|---|---:|---|---:|---|---:|---:|"]
    for name, single, auto, hand in verdicts:
        own = f"the same as {single}" if auto["same_work"] else "its own"
        verdict_lines.append(f"| {name} | {auto['rays']:,} | {single} | {auto['vs_best']:.2f}x | {own} "
                             f"| {fmt(None if hand is None else hand / auto['measured'], '.2f')}"
                             f"{'' if hand is None else 'x'} | {auto['speed']:.3f} |")
    faster = [n for n, _, a, _ in verdicts if a["vs_best"] >= 1.1 and not a["same_work"]]
    slower = [n for n, _, a, _ in verdicts if a["vs_best"] < 1 / 1.05]
    verdict = (f"Auto at least 10% faster than the best single kind, with work of its own: {len(faster)} "
               f"of {len(verdicts)} ({', '.join(faster) or 'none'}); slower than 1.05x: {len(slower)} "
               f"({', '.join(slower) or 'none'}). Where auto's work is the same as the best single kind's "
               "(every counter equal: it kept that structure), the ratio is the machine's noise.")
    stadium_lines = ["| scene | hand-nested (fewest tests per ray) | tests per ray | bounds per ray | auto: tests "
                     "per ray | bounds per ray | auto tests / hand's |", "|---|---|---:|---:|---:|---:|---:|"]
    for name, (hand, auto) in stadium.items():
        stadium_lines.append(f"| {name} | {hand['structure']} | {hand['tests_per_ray']:.2f} "
                             f"| {hand['bounds_per_ray']:.2f} | {auto['tests_per_ray']:.2f} "
                             f"| {auto['bounds_per_ray']:.2f} | {auto['tests_per_ray'] / hand['tests_per_ray']:.2f}x |")
    frames = frame_rows(args.frames, max(64, args.resolution // 4), args.frame_evaluations, model) \
        if args.frames else []
    text = "\n".join([
        "## Annealed hierarchies (`auto`) against the anchors",
        "",
        f"Command: `.venv/bin/python bench/anneal.py --resolution {args.resolution} --seconds {args.seconds:g} "
        f"--frames {args.frames} --repeat {args.repeat} --min-seconds {args.min_seconds:g} "
        f"--head-to-head {args.head_to_head}{' --calibrate' if args.calibrate else ''}` "
        f"({date.today().isoformat()}). Machine: {machine()}. "
        f"Cost model: {calibrated} ({len(model.calibration)} calibration renders).",
        "",
        SUMMARY,
        "",
        *subtable(verdict_lines, COLUMNS, {"auto's work": ["its own"]}),
        "",
        verdict,
        "",
        DETAILS,
        "",
        f"SPD mode, {args.resolution}x{args.resolution}, every structure of a scene casts the same rays "
        f"(checked). Trace seconds: the best of at least {args.repeat} rounds, more (up to {MAX_ROUNDS}) until a "
        f"structure's traces add up to {args.min_seconds:g} s, then {args.head_to_head} rounds more of the best "
        "single kind and auto, alternately; anneal seconds apart (seed 0).",
        "",
        "Verdicts (measured trace time):",
        "",
        *verdict_lines,
        "",
        "The stadium, ray/primitive tests per ray (N_IT) and bound tests per ray, against the hand-nested "
        "teapot BVH:",
        "",
        *stadium_lines,
        "",
        f"The cost model on every single-kind run above ({len(errs)} runs), at the machine's speed during the "
        f"scene (the verdicts' last column: the geometric mean, over {len(probe.anchors)} of the calibration's "
        f"renders timed again in the scene's first {args.repeat} rounds, of their time now over their time in "
        "the calibration): "
        f"{summary(errs)}. At the calibration's speed (the fitted costs alone): {summary(raw)}.",
        "",
        *model_lines,
        "",
        f"Ranking: of the {pairs} pairs of single kinds on one scene whose measured times differ by more "
        f"than 10%, the model orders {agree} the same way.",
        "",
        *([f"Re-annealing between frames: the satellite, {args.frames} frames over 600 s of its orbit, at "
           f"{max(64, args.resolution // 4)} pixels; from scratch ({args.frame_evaluations} candidates) against "
           "from the previous frame's hierarchy (a short schedule, a quarter of the candidates); energy in "
           "predicted ms.", "",
           "| frame | time s | scratch: candidates | seconds | energy | re-annealed: candidates | seconds "
           "| energy |", "|---:|---:|---:|---:|---:|---:|---:|---:|", *frames, ""] if frames else []),
        "Every run:",
        "",
        *lines,
        "",
        *found_trees,
    ])
    replace_section("anneal", text)
    print(text)


if __name__ == "__main__":
    main()
