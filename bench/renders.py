"""Full SPD renders: raykernel against POV-Ray 3.7, wall-clock seconds side by side.

    .venv/bin/python bench/renders.py [--scenes balls,gears] [--threads 2]

For each SPD generator at its default size, renders ../shared/scenes/spd's
.nff with `raykernel render --spd --resolution 512` (the SPD procedure:
513x513 corner rays, depth 5) and its .pov with
`povray +W512 +H512 -D +A0.0 +WT2` (Debian's povray 3.7; +A0.0 supersamples
every pixel), each as a fresh process, alternating, best of --repeat runs.
raykernel's wall clock includes Python start-up, loading the cached
kernels, parsing and building; its trace seconds are shown beside it, and
so is the time of the same render called from a running Python process
(`raykernel.render(raykernel.load(nff), ...)`: loading, building, tracing).
Writes the `renders` section of BENCHMARKS.md.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import ROOT, SHARED_SPD, machine, replace_section  # noqa: E402

import raykernel  # noqa: E402
from raykernel.scene import spd

RAYKERNEL = [sys.executable, "-m", "raykernel.cli"]


def povray_version() -> str:
    out = subprocess.run(["povray", "--version"], capture_output=True, text=True)
    for line in (out.stdout + out.stderr).splitlines():
        if line.startswith("POV-Ray"):
            return line.strip()
    return "povray (version unknown)"


def timed(cmd, cwd) -> tuple[float, str]:
    start = time.perf_counter()
    out = subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)
    seconds = time.perf_counter() - start
    if out.returncode != 0:
        sys.exit(f"{' '.join(map(str, cmd))} failed ({out.returncode}):\n{out.stderr[-2000:]}")
    return seconds, out.stdout


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--scenes", default=",".join(spd.NAMES))
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    if shutil.which("povray") is None:
        sys.exit("povray is not installed (Debian: apt-get install povray)")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        # warm the kernel cache once, so no render below pays for compilation
        timed(RAYKERNEL + ["render", "spd:balls:1", "--resolution", "8", "-o", f"{tmp}/warm.png"], tmp)
        for name in args.scenes.split(","):
            stem = f"{name}-sf{spd.default_size(name)}"
            nff, pov = SHARED_SPD / f"{stem}.nff", SHARED_SPD / f"{stem}.pov"
            if not (nff.exists() and pov.exists()):
                print(f"skipping {name}: {stem}.nff/.pov not in {SHARED_SPD}")
                continue
            # the sombrero's .pov reads its height field from the current directory
            for extra in SHARED_SPD.glob("*.tga"):
                shutil.copy(extra, tmp)
            rk_cmd = RAYKERNEL + ["render", str(nff), "--spd", "--resolution", "512", "--threads",
                                  str(args.threads), "-o", f"{tmp}/{stem}.png", "--stats-json", f"{tmp}/{stem}.json"]
            pov_cmd = ["povray", f"+I{pov}", f"+O{tmp}/{stem}-pov.png", "+W512", "+H512", "-D", "+A0.0",
                       f"+WT{args.threads}"]
            rk, pv, trace, inproc = [], [], [], []
            for _ in range(args.repeat):
                rk.append(timed(rk_cmd, tmp)[0])
                trace.append(json.loads(Path(f"{tmp}/{stem}.json").read_text())["counters"]["time.trace"])
                pv.append(timed(pov_cmd, tmp)[0])
                start = time.perf_counter()
                raykernel.render(raykernel.load(str(nff)), spd=True, resolution=512, threads=args.threads)
                inproc.append(time.perf_counter() - start)
            rows.append(dict(scene=stem, raykernel=min(rk), trace=min(trace), inproc=min(inproc), povray=min(pv)))
            print(f"{stem}: raykernel {min(rk):.2f} s (trace {min(trace):.2f} s, in-process {min(inproc):.2f} s), "
                  f"povray {min(pv):.2f} s, ratio {min(pv) / min(rk):.2f}")
    lines = [
        "## SPD renders (raykernel vs POV-Ray)",
        "",
        f"Machine: {machine()}; {povray_version()}.",
        "",
        f"Command: `.venv/bin/python bench/renders.py --threads {args.threads} --repeat {args.repeat}`",
        "",
        "Each SPD generator at its default size, 512x512, depth 5, both renderers as fresh processes, best of "
        f"{args.repeat}. raykernel: `raykernel render X.nff --spd --resolution 512 --threads {args.threads}` "
        "(513x513 corner rays averaged, the SPD procedure; wall clock includes start-up, loading the cached "
        f"kernels, parsing and building). POV-Ray: `povray +IX.pov +W512 +H512 -D +A0.0 +WT{args.threads}` "
        "(+A0.0 antialiases every pixel). speed-up = POV-Ray seconds / raykernel seconds.",
        "",
        "In-process: the same render called in a running Python session (`raykernel.render(raykernel.load(nff), "
        "spd=True, resolution=512)`), i.e. without interpreter start-up and kernel loading.",
        "",
        "| scene | raykernel s | of which trace s | in-process s | POV-Ray s | speed-up | speed-up in-process |",
        "|---|---:|---:|---:|---:|---:|---:|",
    ]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['raykernel']:.2f} | {r['trace']:.2f} | {r['inproc']:.2f} | "
                     f"{r['povray']:.2f} | {r['povray'] / r['raykernel']:.2f} | {r['povray'] / r['inproc']:.2f} |")
    if rows:
        total = {k: sum(r[k] for r in rows) for k in ("raykernel", "trace", "inproc", "povray")}
        lines.append(f"| all | {total['raykernel']:.2f} | {total['trace']:.2f} | {total['inproc']:.2f} | "
                     f"{total['povray']:.2f} | {total['povray'] / total['raykernel']:.2f} | "
                     f"{total['povray'] / total['inproc']:.2f} |")
    replace_section("renders", "\n".join(lines))
    print(f"wrote the renders section of {ROOT / 'BENCHMARKS.md'}")


if __name__ == "__main__":
    main()
