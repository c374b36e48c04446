"""Full SPD renders: raykernel against POV-Ray 3.7 on the same work, seconds and ray counts side by side.

    .venv/bin/python bench/renders.py [--scenes balls,gears] [--threads 2] [--repeat 2]

For each SPD generator at its default size, written as NFF and as a POV-Ray
3.7 scene by raykernel's own generator and converter (bench/.cache), renders
the .nff with `raykernel render --spd --resolution 512` (the SPD procedure:
513x513 corner rays averaged to 512x512, depth 5) and its .pov with
`povray +W512 +H512 -D -A +WT<threads>` (Debian's povray 3.7; -A: one ray
per pixel, no antialiasing), each as a fresh process, alternating, best of
--repeat runs. Both sides' ray counts are printed beside the times (ours:
rays.eye, rays.shadow, rays.reflect, rays.refract; POV-Ray's: Pixels,
Shadow Ray Tests, Reflected Rays, Refracted + Transmitted Rays from its
statistics), so the work can be seen to be the same. Two ratios: the wall clock of the
fresh processes, and the work alone: POV-Ray's parse + bounding + trace
seconds (its own statistics) against our time.parse + time.preprocess +
time.trace (loading the cached kernels is start-up, time.load, beside them).
Before timing, the package's bytecode is compiled (`compileall`, as pip does
when it installs a package), since an editable checkout run with
PYTHONDONTWRITEBYTECODE would otherwise compile every module's source in
every process. Writes the `renders` section of BENCHMARKS.md.

    .venv/bin/python bench/renders.py --antialiased balls,gears,teapot,tetra

writes instead the separate, labelled `renders_aa` section: POV-Ray with
`+A0.0 +AM1 +R3` (every pixel supersampled with a 3x3 grid, plus its first
ray per pixel) against raykernel's own antialiasing, `--aa jitter --samples 9
--cutoff 0` (9 jittered rays per pixel, every ray cast to depth 5). The two
samplers differ (a grid against jittered strata, and POV-Ray's extra first
ray), so both sides' ray counts are printed; it is not the SPD procedure.

    .venv/bin/python bench/renders.py --work-layers balls,teapot,tetra

writes the `work_layers` section: the same SPD renders with and without `--work` (the cost of
work layers).
"""

from __future__ import annotations

import argparse
import json
import re
import shutil
import subprocess
import sys
import tempfile
import time
from datetime import date
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import DETAILS, ROOT, machine, replace_section, spd_file, subtable  # noqa: E402

from raykernel.scene import spd  # noqa: E402

# the renders section's summary in BENCHMARKS.md: the full table's times and ratios
SUMMARY = ("Seconds of the whole process (wall) and of the work alone (raykernel's parse, preprocess and trace; "
           "POV-Ray's parse, bounding and trace); ratios POV-Ray / raykernel, above 1: raykernel is faster. "
           "The ray counts of both sides are in the full table.")
COLUMNS = ["scene", "raykernel s", "POV-Ray s", "wall", "raykernel work s", "POV-Ray work s", "work"]

RAYKERNEL = [sys.executable, "-m", "raykernel.cli"]


def povray_version() -> str:
    out = subprocess.run(["povray", "--version"], capture_output=True, text=True)
    for line in (out.stdout + out.stderr).splitlines():
        if line.startswith("POV-Ray"):
            return line.strip()
    return "povray (version unknown)"


def compile_bytecode() -> None:
    """The package's modules compiled to bytecode, as pip does when it installs a package."""
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(ROOT / "src" / "raykernel")], check=True)


def timed(cmd, cwd) -> tuple[float, str]:
    """Wall seconds of a fresh process, and what it printed (stdout and stderr)."""
    start = time.perf_counter()
    out = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if out.returncode != 0:
        sys.exit(f"{' '.join(map(str, cmd))} failed ({out.returncode}):\n{out.stderr[-2000:]}")
    return seconds, out.stdout + out.stderr


_SECONDS = re.compile(r"\(([0-9.]+) seconds\)")


def povray_stats(text: str) -> dict:
    """Ray counts and phase seconds from POV-Ray's statistics (printed on stderr)."""
    out = {"pixels": 0, "shadow": 0, "reflect": 0, "refract": 0, "parse": 0.0, "bounding": 0.0, "trace": 0.0}
    for line in text.splitlines():
        words = line.split()
        if line.startswith("Pixels:"):
            out["pixels"] = int(words[1])
        elif line.startswith("Shadow Ray Tests:"):
            out["shadow"] = int(words[3])
        elif line.startswith("Reflected Rays:"):
            out["reflect"] = int(words[2])
        elif line.startswith(("Refracted Rays:", "Transmitted Rays:")):
            out["refract"] += int(words[2])     # POV-Ray counts rays through ior 1 apart, as transmitted
        for phase, label in (("parse", "Parse Time:"), ("bounding", "Bounding Time:"), ("trace", "Trace Time:")):
            if line.strip().startswith(label):
                m = _SECONDS.search(line)
                out[phase] = float(m.group(1)) if m else 0.0
    return out


def povray_rays(text: str) -> int:
    """POV-Ray's camera rays: each pixel's first ray ("Pixels:") and its supersamples ("Samples:")."""
    for line in text.splitlines():
        words = line.split()
        if line.startswith("Pixels:") and "Samples:" in words:
            return int(words[1]) + int(words[words.index("Samples:") + 1])
    return 0


def spd_files(names: str, tmp: str):
    """(stem, .nff, .pov) of each named SPD scene at its default size, written by raykernel's
    generator and its POV-Ray converter (bench/.cache)."""
    for name in names.split(","):
        size = spd.default_size(name)
        yield f"{name}-sf{size}", spd_file(name, size, ".nff"), spd_file(name, size, ".pov")


def antialiased(args) -> None:
    """The labelled antialiased comparison (the renders_aa section)."""
    rows = []
    compile_bytecode()
    with tempfile.TemporaryDirectory() as tmp:
        timed(RAYKERNEL + ["render", "spd:balls:1", "--resolution", "8", "--aa", "jitter", "--samples", "9",
                           "-o", f"{tmp}/warm.png"], tmp)
        for stem, nff, pov in spd_files(args.antialiased, tmp):
            rk_cmd = RAYKERNEL + ["render", str(nff), "--resolution", "512", "--aa", "jitter", "--samples", "9",
                                  "--cutoff", "0", "--max-depth", "5", "--threads", str(args.threads),
                                  "-o", f"{tmp}/{stem}.png", "--stats-json", f"{tmp}/{stem}.json"]
            pov_cmd = ["povray", f"+I{pov}", f"+O{tmp}/{stem}-pov.png", "+W512", "+H512", "-D", "+A0.0", "+AM1",
                       "+R3", f"+WT{args.threads}"]
            rk, pv = [], []
            for _ in range(args.repeat):
                rk.append(timed(rk_cmd, tmp)[0])
                stats = json.loads(Path(f"{tmp}/{stem}.json").read_text())["counters"]
                seconds, text = timed(pov_cmd, tmp)
                pv.append(seconds)
            ps = povray_stats(text)
            rows.append((stem, stats, ps, povray_rays(text), min(rk), min(pv)))
            print(f"{stem}: raykernel {min(rk):.2f} s, povray {min(pv):.2f} s; eye {stats['rays.eye']:,} / "
                  f"{povray_rays(text):,}", flush=True)
    lines = [
        "## SPD scenes antialiased (raykernel vs POV-Ray, labelled: not the same sampler)",
        "",
        f"Machine: {machine()}; {povray_version()}.",
        "",
        f"Command: `.venv/bin/python bench/renders.py --antialiased {args.antialiased} --threads {args.threads} "
        f"--repeat {args.repeat}` ({date.today().isoformat()})",
        "",
        f"512x512, depth 5, fresh processes on {args.threads} threads, best of {args.repeat}. raykernel: "
        f"`raykernel render X.nff --resolution 512 --aa jitter --samples 9 --cutoff 0 --max-depth 5` (9 jittered "
        f"rays per pixel, every ray cast). POV-Ray: `povray +IX.pov +W512 +H512 -D +A0.0 +AM1 +R3` (every pixel "
        "supersampled on a 3x3 grid, after its first ray). Eye rays: ours / POV-Ray's pixels plus samples (its first "
        "ray per pixel and its supersamples, so about 1.1 times ours). wall = POV-Ray seconds / raykernel seconds of the whole process; "
        "above 1: raykernel is faster.",
        "",
        "| scene | eye rays | shadow rays | reflected | refracted | raykernel s | POV-Ray s | wall |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for stem, o, p, rays, rk, pv in rows:
        lines.append(f"| {stem} | {o['rays.eye']:,} / {rays:,} | {o['rays.shadow']:,} / {p['shadow']:,} | "
                     f"{o['rays.reflect']:,} / {p['reflect']:,} | {o['rays.refract']:,} / {p['refract']:,} | "
                     f"{rk:.2f} | {pv:.2f} | {pv / rk:.2f} |")
    replace_section("renders_aa", "\n".join(lines))
    print(f"wrote the renders_aa section of {ROOT / 'BENCHMARKS.md'}")


def work_layers(args) -> None:
    """The cost of work layers (the work_layers section): each scene rendered as in the renders
    section, with and without `--work`, alternating, best of --repeat."""
    rows = []
    compile_bytecode()
    with tempfile.TemporaryDirectory() as tmp:
        for extra in ([], ["--work", f"{tmp}/warm.npz"]):     # both kernels compiled before timing
            timed(RAYKERNEL + ["render", "spd:balls:1", "--spd", "--resolution", "8", "-o", f"{tmp}/warm.png"] + extra,
                  tmp)
        for stem, nff, _ in spd_files(args.work_layers, tmp):
            base = RAYKERNEL + ["render", str(nff), "--spd", "--resolution", "512", "--threads", str(args.threads),
                                "-o", f"{tmp}/{stem}.png", "--stats-json", f"{tmp}/{stem}.json"]
            sides = {"plain": base, "work": base + ["--work", f"{tmp}/{stem}.npz"]}
            best = {k: (float("inf"), float("inf")) for k in sides}
            rays = {}
            for _ in range(args.repeat):
                for side, cmd in sides.items():
                    wall = timed(cmd, tmp)[0]
                    stats = json.loads(Path(f"{tmp}/{stem}.json").read_text())["counters"]
                    best[side] = (min(best[side][0], wall), min(best[side][1], stats["time.trace"]))
                    rays[side] = stats["rays.total"]
            if rays["plain"] != rays["work"]:
                sys.exit(f"{stem}: the renders cast different rays: {rays}")
            rows.append((stem, rays["plain"], best["plain"], best["work"]))
            print(f"{stem}: rays {rays['plain']:,}; trace {best['plain'][1]:.3f} s plain, {best['work'][1]:.3f} s "
                  f"with layers", flush=True)
    lines = [
        "## The cost of work layers",
        "",
        f"Machine: {machine()}.",
        "",
        f"Command: `.venv/bin/python bench/renders.py --work-layers {args.work_layers} --threads {args.threads} "
        f"--repeat {args.repeat}` ({date.today().isoformat()})",
        "",
        f"`raykernel render X.nff --spd --resolution 512 --threads {args.threads}`, without and with `--work X.npz`, "
        f"fresh processes, alternating, best of {args.repeat}; both cast the same rays (rays.total, printed). trace: "
        "time.trace of the statistics; wall: the whole process, the compressed .npz written included. cost = with "
        "/ without (1.00: free). Whether a render without layers is as fast as before the layers existed is "
        "bench/against.py's table (the same renders against an earlier revision).",
        "",
        "| scene | rays | trace s | trace s with layers | cost (trace) | wall s | wall s with layers | cost (wall) |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for stem, rays, (pw, pt), (ww, wt) in rows:
        lines.append(f"| {stem} | {rays:,} | {pt:.3f} | {wt:.3f} | {wt / pt:.2f} | {pw:.2f} | {ww:.2f} | {ww / pw:.2f} |")
    replace_section("work_layers", "\n".join(lines))
    print(f"wrote the work_layers section of {ROOT / 'BENCHMARKS.md'}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default=",".join(spd.NAMES))
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--antialiased", help="comma-separated SPD names: only the labelled antialiased comparison")
    ap.add_argument("--work-layers", metavar="SCENES", help="comma-separated SPD names: only the cost of work "
                    "layers (no POV-Ray)")
    args = ap.parse_args()
    if args.work_layers:
        work_layers(args)
        return
    if shutil.which("povray") is None:
        sys.exit("povray is not installed (Debian: apt-get install povray)")
    if args.antialiased:
        antialiased(args)
        return
    rows = []
    compile_bytecode()
    with tempfile.TemporaryDirectory() as tmp:
        # warm the kernel cache once, so no render below pays for compilation
        timed(RAYKERNEL + ["render", "spd:balls:1", "--resolution", "8", "-o", f"{tmp}/warm.png"], tmp)
        for stem, nff, pov in spd_files(args.scenes, tmp):
            rk_cmd = RAYKERNEL + ["render", str(nff), "--spd", "--resolution", "512", "--threads",
                                  str(args.threads), "-o", f"{tmp}/{stem}.png", "--stats-json", f"{tmp}/{stem}.json"]
            pov_cmd = ["povray", f"+I{pov}", f"+O{tmp}/{stem}-pov.png", "+W512", "+H512", "-D", "-A",
                       f"+WT{args.threads}"]
            rk, pv, work, pwork, load = [], [], [], [], []
            for _ in range(args.repeat):
                rk.append(timed(rk_cmd, tmp)[0])
                stats = json.loads(Path(f"{tmp}/{stem}.json").read_text())["counters"]
                work.append(stats["time.parse"] + stats["time.preprocess"] + stats["time.trace"])
                load.append(stats["time.load"])
                seconds, text = timed(pov_cmd, tmp)
                pv.append(seconds)
                ps = povray_stats(text)
                pwork.append(ps["parse"] + ps["bounding"] + ps["trace"])
            ours = {k: stats[f"rays.{k}"] for k in ("eye", "shadow", "reflect", "refract")}
            rows.append(dict(scene=stem, raykernel=min(rk), work=min(work), povray=min(pv), pov_work=min(pwork),
                             load=min(load), ours=ours, theirs=ps))
            print(f"{stem}: raykernel {min(rk):.2f} s (work {min(work):.2f} s), povray {min(pv):.2f} s "
                  f"(work {min(pwork):.2f} s); eye {ours['eye']:,} / {ps['pixels']:,}, shadow {ours['shadow']:,} / "
                  f"{ps['shadow']:,}, reflect {ours['reflect']:,} / {ps['reflect']:,}, refract "
                  f"{ours['refract']:,} / {ps['refract']:,}", flush=True)
    table = [
        "| scene | eye rays | shadow rays | reflected | refracted | raykernel s | POV-Ray s | wall | load s | "
        "raykernel work s | POV-Ray work s | work |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        o, p = r["ours"], r["theirs"]
        table.append(f"| {r['scene']} | {o['eye']:,} / {p['pixels']:,} | {o['shadow']:,} / {p['shadow']:,} | "
                     f"{o['reflect']:,} / {p['reflect']:,} | {o['refract']:,} / {p['refract']:,} | "
                     f"{r['raykernel']:.2f} | {r['povray']:.2f} | {r['povray'] / r['raykernel']:.2f} | "
                     f"{r['load']:.2f} | {r['work']:.2f} | {r['pov_work']:.2f} | {r['pov_work'] / r['work']:.2f} |")
    if rows:
        total = {k: sum(r[k] for r in rows) for k in ("raykernel", "povray", "work", "pov_work", "load")}
        table.append(f"| all | | | | | {total['raykernel']:.2f} | {total['povray']:.2f} | "
                     f"{total['povray'] / total['raykernel']:.2f} | {total['load']:.2f} | {total['work']:.2f} | "
                     f"{total['pov_work']:.2f} | {total['pov_work'] / total['work']:.2f} |")
    lines = [
        "## SPD renders (raykernel vs POV-Ray)",
        "",
        f"Machine: {machine()}; {povray_version()}.",
        "",
        f"Command: `.venv/bin/python bench/renders.py --threads {args.threads} --repeat {args.repeat}` "
        f"({date.today().isoformat()})",
        "",
        SUMMARY,
        "",
        *subtable(table, COLUMNS),
        "",
        DETAILS,
        "",
        "Each SPD generator at its default size, 512x512, depth 5, both renderers as fresh processes on "
        f"{args.threads} threads, best of {args.repeat}. raykernel: `raykernel render X.nff --spd --resolution "
        f"512 --threads {args.threads}` (513x513 corner rays averaged, the SPD procedure; its wall clock includes "
        "Python start-up, loading the cached kernels, parsing and building; its bytecode compiled beforehand, as "
        "pip does on install). POV-Ray: `povray +IX.pov +W512 "
        f"+H512 -D -A +WT{args.threads}` (-A: one ray per pixel). Rays: ours / POV-Ray's (eye rays against "
        "its pixels; its shadow ray tests, reflected rays, and refracted plus transmitted rays from its statistics). wall = POV-Ray "
        "seconds / raykernel seconds of the whole process; work = POV-Ray's parse + bounding + trace seconds / "
        "our parse + preprocess + trace seconds. load: our seconds loading the cached kernels (start-up, in the "
        "wall clock, not in the work). Above 1: raykernel is faster.",
        "",
        *table,
    ]
    replace_section("renders", "\n".join(lines))
    print(f"wrote the renders section of {ROOT / 'BENCHMARKS.md'}")


if __name__ == "__main__":
    main()
