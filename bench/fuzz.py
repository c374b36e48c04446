"""The long fuzzing run: N inputs (tests/fuzzing.py) over worker processes, each batch of inputs in a
process of its own under a time limit (a hang fails its batch and names it), failures saved as
reproducers under tests/data/fuzz; the counts go to BENCHMARKS.md.

    .venv/bin/python bench/fuzz.py --inputs 100000 --processes 2      # the section "fuzz"
    .venv/bin/python bench/fuzz.py --inputs 2000 --no-write           # a look, nothing written
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from collections import Counter
from concurrent.futures import ThreadPoolExecutor
from datetime import date
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from _report import ROOT, machine, replace_section  # noqa: E402

BATCH = 500             # inputs a worker process runs before it is replaced (bounds what a leak can do)
BATCH_SECONDS = 900     # a batch that runs longer hangs
SAVE = ROOT / "tests" / "data" / "fuzz"

WORKER = """
import json, sys, tempfile
from pathlib import Path
sys.path.insert(0, sys.argv[3])
import fuzzing
with tempfile.TemporaryDirectory() as folder:
    report = fuzzing.campaign(int(sys.argv[1]), int(sys.argv[2]), save=Path(sys.argv[4]), workdir=Path(folder))
print(json.dumps({"counts": [[t, k, n] for (t, k), n in report["counts"].items()],
                  "failures": [[c.target, c.key(), o] for c, o in report["failures"]],
                  "slowest": report["slowest"]}))
"""


def batch(seed: int, n: int) -> dict:
    """One batch in a process of its own: its counts and failures, or the hang or crash that ended it."""
    try:
        run = subprocess.run([sys.executable, "-c", WORKER, str(seed), str(n), str(ROOT / "tests"), str(SAVE)],
                             capture_output=True, text=True, timeout=BATCH_SECONDS, cwd=ROOT)
    except subprocess.TimeoutExpired:
        return {"counts": [], "failures": [["batch", f"seed {seed}", f"no answer within {BATCH_SECONDS} s"]],
                "slowest": []}
    if run.returncode != 0:
        return {"counts": [], "failures": [["batch", f"seed {seed}", f"the process ended with {run.returncode}: "
                                            f"{run.stderr[-300:]}"]], "slowest": []}
    return json.loads(run.stdout.strip().splitlines()[-1])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--inputs", type=int, default=100_000)
    parser.add_argument("--processes", type=int, default=2)
    parser.add_argument("--seed", type=int, default=1, help="the first batch's seed; batch k takes seed + k")
    parser.add_argument("--no-write", action="store_true", help="print the table, leave BENCHMARKS.md alone")
    args = parser.parse_args()
    sizes = [min(BATCH, args.inputs - k) for k in range(0, args.inputs, BATCH)]
    counts, failures, slowest = Counter(), [], []
    start = time.perf_counter()
    with ThreadPoolExecutor(args.processes) as pool:
        for k, result in enumerate(pool.map(lambda kn: batch(args.seed + kn[0], kn[1]), enumerate(sizes))):
            for target, kind, n in result["counts"]:
                counts[target, kind] += n
            failures += result["failures"]
            slowest = sorted(slowest + [(s, t, f"seed {args.seed + k}, {key}") for s, t, key in result["slowest"]],
                             reverse=True)[:5]
            done = sum(counts.values())
            print(f"{done:,} inputs, {len(failures)} failures, {time.perf_counter() - start:.0f} s", flush=True)
    seconds = time.perf_counter() - start
    targets = sorted({t for t, _ in counts})
    rows = ["| input | cases | answered | refused (one line) | failed |", "|---|---:|---:|---:|---:|"]
    for t in targets:
        n = sum(counts[t, k] for k in ("answered", "refused", "failed"))
        rows.append(f"| {t} | {n:,} | {counts[t, 'answered']:,} | {counts[t, 'refused']:,} | {counts[t, 'failed']:,} |")
    total = sum(counts.values())
    text = "\n".join([
        "## Fuzzing", "",
        f"`.venv/bin/python bench/fuzz.py --inputs {args.inputs} --processes {args.processes} --seed {args.seed}` "
        f"({date.today().isoformat()}) on {machine()}: {total:,} inputs in {seconds / 60:.0f} min. Each is "
        "loaded and rendered at 4x4 under bvh, "
        "grid and octree, cast, or run on the command line, and must be answered or refused with one "
        "RayKernelError of one line; any other exception, a warning that is not raykernel's own (numpy's "
        "above all) or a batch with no answer within "
        f"{BATCH_SECONDS} s is a failure, saved under tests/data/fuzz and replayed by tests/test_fuzz.py.", "",
        *rows, "", f"Failures: {len(failures)}" + ("." if not failures else ":"),
        *[f"- {t} {key}: {outcome}" for t, key, outcome in failures[:20]], "",
        "The slowest inputs: " + "; ".join(f"{t} ({key}) {s:.1f} s" for s, t, key in slowest) + "."])
    print(text)
    if not args.no_write:
        replace_section("fuzz", text)


if __name__ == "__main__":
    main()
