"""A mutation and grammar fuzzer of raykernel's inputs: NFF and JSON scene text, accelerator specs,
command lines and RayScene's arrays.

    for case in cases(seed=1, n=1000):        # Case(target, payload): reproducible from the seed alone
        outcome = run(case)                  # "answered", "refused" or a failure's description
    report = campaign(seed=1, n=1000, save=Path("tests/data/fuzz"))   # counts, failures saved

Each case is loaded and rendered tiny (4x4, under bvh, grid and octree), or cast, or run on the
command line, and must either be answered or be refused with one RayKernelError of one line (an
auto spec is parsed, not rendered: its search takes its `seconds`, 30 by default).
Anything else fails: another exception, a message of several lines, a warning that is not one of
raykernel's own (numpy's RuntimeWarnings above all), or a command line that does not return 0 or
2. A failure is saved as a reproducer (tests/data/fuzz), which test_fuzz.py replays ever after.
A hang is caught by bench/fuzz.py, which runs campaigns in processes with a time limit.
"""

from __future__ import annotations

import contextlib
import hashlib
import io
import json
import random
import time
import traceback
import warnings
from collections import Counter
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from raykernel.aggregates.registry import KINDS

TARGETS = ("nff", "json", "spec", "cli", "rays")
ODD_NUMBERS = ["0", "-0", "1", "-1", "3", "0.5", "1e308", "-1e308", "1e-320", "nan", "inf", "-inf", "1e30", "-1e30",
               "1e31", "1e-30", "1e-31", "65537", "2147483648", "9e99", "1e200"]
ODD_TOKENS = ["x", "", "#", "v", "s", "p", "pp", "c", "l", "f", "b", "from", "at", "up", "angle", "hither",
              "resolution", "0x10", "1,2", "--", "\u00e9", "\x00"]

NFF_SEED = """b 0.1 0.2 0.3
v
from 2.1 1.3 1.7
at 0 0 0
up 0 0 1
angle 45
hither 0.01
resolution 4 4
l 4 3 2
l 1 -4 4 0.5 0.5 0.5
f 1 0.75 0.33 0.8 0 100000 0 1
p 4
12 12 -0.5
-12 12 -0.5
-12 -12 -0.5
12 -12 -0.5
f 1 0.9 0.7 0.5 0.5 3.0827 0.5 1.5
s 0 0 0 0.5
s 0.27 0.27 0.54 0.17
c 0 0 1 0.2 0 0 2 0.1
pp 3
1 0 0 0 0 1
0 1 0 0 0 1
0 0 0.1 0 0 1
"""

JSON_SEED = {
    "camera": {"eye": [3, -4, 3], "look_at": [0, 0, 0], "up": [0, 0, 1], "angle": 40, "resolution": 4},
    "background": [0.1, 0.1, 0.2],
    "lights": [{"position": [5, -5, 8]}, {"position": [-3, 2, 6], "color": [0.5, 0.5, 0.5]}],
    "materials": {"red": {"color": [0.9, 0.2, 0.1], "kd": 0.7, "ks": 0.3, "shine": 20}},
    "scene": {"accel": "grid", "items": [
        {"sphere": {"center": [0, 0, 0], "radius": 1}, "material": "red"},
        {"group": {"accel": "octree(depth=4)", "items": [
            {"sphere": {"center": [2, 0, 0], "radius": 0.5}},
            {"polygon": [[-3, -3, -1], [3, -3, -1], [3, 3, -1], [-3, 3, -1]]}]},
         "transform": [{"translate": [0, 1, 0]}, {"rotate": {"axis": [0, 0, 1], "degrees": 30}}, {"scale": 1.5}]},
        {"difference": {"base": [{"sphere": {"center": [0, 0, 2], "radius": 0.6}}],
                        "subtract": [{"sphere": {"center": [0.3, 0, 2.3], "radius": 0.4}}]}},
        {"mesh": {"vertices": [[0, 0, 3], [1, 0, 3], [0, 1, 3], [1, 1, 3.2]], "faces": [[0, 1, 2], [1, 3, 2]]}},
        {"cone": {"base": [-2, 0, 0], "apex": [-2, 0, 1], "base_radius": 0.3, "apex_radius": 0.1}}]},
}

SPEC_KINDS = (*KINDS, "auto", "nosuch")
SPEC_PARAMS = ("leaf", "bins", "depth", "density", "res", "max_res", "mailbox", "walk", "budget", "rays", "k",
               "threshold", "width", "split", "optimize", "build", "order", "seed", "lazy", "budget_mb", "inner",
               "outer", "isect", "collapse", "rule60", "seconds")
SPEC_VALUES = ODD_NUMBERS[:12] + ["on", "off", "true", "point", "parametric", "sah", "gs", "woo", "reinsertion",
                                  "bvh", "grid(depth=2)", "()", "[", "="]

CLI_COMMANDS = ("render", "explain", "structure", "scene", "spd", "accels", "compare")
CLI_OPTIONS = {
    "--resolution": ["4", "0", "-3", "x", "4.5", "99999999", "1e3"],
    "--accel": ["bvh", "grid", "octree(depth=3)", "octree(leaf=0)", "nonsense", "bvh(", ""],
    "--spd": None, "--max-depth": ["1", "0", "-1", "1000000"],
    "--eye": ["1,2,3", "1,2", "nan,0,0", "1e31,0,0", "a,b,c"], "--look-at": ["0,0,0", "1,1,1,1"],
    "--up": ["0,0,1", "0,0,0"], "--angle": ["45", "0", "180", "-5", "nan"],
    "--threads": ["1", "0", "-2"], "--shading": ["whitted", "hall", "heckbert", "phong"],
    "--aa": ["jitter", "adaptive", "none"], "--samples": ["4", "3", "0", "1000000"],
    "--seed": ["0", "-1", "x"], "--aa-threshold": ["0.1", "-1", "nan"], "--aa-depth": ["2", "9", "-1"],
    "--cutoff": ["0", "-1", "2", "nan"], "--tricks": ["all", "none", "closest,bogus", ""],
    "--max-memory": ["8G", "1", "lots", "0", "-1G"], "--pixel": ["0 0", "99 99", "-1 0", "x y"],
    "--work-image": ["tests.total", "no.such"], "--draw": ["0", "all", "-1", "x"],
    "--shadows": ["opaque", "filtered", "x"], "--eye-light": ["1", "-1", "nan"],
    "--size": ["1", "0", "-1", "100000"], "-p": ["n=3", "n=-1", "x", "=1"], "--use": None, "--leaves": None,
}
CLI_SCENES = ["spd:balls:1", "spd:balls:0", "spd:nosuch", "scene:stadium", "scene:sun:n=2", "example:heckbert",
              "missing.nff", "spd:balls:1:x", "spd:tetra:1", ""]


@dataclass(frozen=True)
class Case:
    target: str      # one of TARGETS
    payload: object  # text (nff, json, spec), an argument list (cli) or a dict of lists (rays)

    def key(self) -> str:
        return hashlib.sha1(json.dumps([self.target, self.payload], default=str).encode()).hexdigest()[:12]


# ------------------------------------------------------------------ making cases


def cases(seed: int, n: int):
    """n cases drawn from the seed, every target in turn."""
    rng = random.Random(seed)
    makers = {"nff": _nff, "json": _json, "spec": _spec, "cli": _cli, "rays": _rays}
    for k in range(n):
        target = TARGETS[k % len(TARGETS)]
        yield Case(target, makers[target](rng))


def _nff(rng) -> str:
    lines = NFF_SEED.splitlines()
    for _ in range(rng.choice([1, 1, 1, 2, 3])):
        i = rng.randrange(len(lines))
        op = rng.random()
        if op < 0.3:
            lines[i] = " ".join(_nudged(t, rng) for t in lines[i].split())
        elif op < 0.55:
            tokens = lines[i].split()
            if tokens:
                j = rng.randrange(len(tokens))
                tokens[j] = rng.choice(ODD_NUMBERS if j or rng.random() < 0.5 else ODD_TOKENS)
                lines[i] = " ".join(tokens)
        elif op < 0.7:
            del lines[i]
        elif op < 0.82:
            lines.insert(i, lines[rng.randrange(len(lines))])
        elif op < 0.9:
            lines = lines[:i]
        elif op < 0.95:
            j = rng.randrange(len(lines))
            lines[i], lines[j] = lines[j], lines[i]
        else:
            lines.insert(i, " ".join(rng.choice(ODD_TOKENS + ODD_NUMBERS) for _ in range(rng.randint(1, 5))))
        if not lines:
            lines = [rng.choice(ODD_TOKENS)]
    return "\n".join(lines) + "\n"


def _json(rng) -> str:
    data = json.loads(json.dumps(JSON_SEED))
    for _ in range(rng.choice([1, 1, 1, 2, 3])):
        _mutate_tree(data, rng)
    return json.dumps(data, allow_nan=True)


def _mutate_tree(data, rng) -> None:
    """Change one place of the JSON tree: a value replaced, a key dropped, a list item repeated."""
    parent, key = _random_place(data, rng)
    if parent is None:
        return
    op = rng.random()
    if op < 0.3 and isinstance(parent[key], (int, float)) and not isinstance(parent[key], bool):
        parent[key] = float(_nudged(repr(parent[key]), rng))
    elif op < 0.6:
        parent[key] = rng.choice([float(rng.choice(ODD_NUMBERS)), rng.choice(ODD_TOKENS), None, [], {}, [1, 2],
                                  True, -1, 0, 10 ** 12, [[0, 0, 0]], {"x": 1}])
    elif op < 0.8:
        del parent[key]
    elif isinstance(parent, list):
        parent.insert(key, json.loads(json.dumps(parent[key])))
    else:
        parent[rng.choice(["bogus", "accel", "items", "transform", "material"])] = parent[key]


def _nudged(token: str, rng) -> str:
    """A number moved a little (still a likely scene), anything else as it is."""
    try:
        value = float(token)
    except ValueError:
        return token
    return repr(value * rng.choice([0.0, 0.5, 1.0001, 2.0, -1.0, 1e3, 1e-3]) + rng.choice([0.0, 0.0, 1e-9, -0.5]))


def _random_place(node, rng):
    places = []

    def walk(n):
        items = list(n.items()) if isinstance(n, dict) else list(enumerate(n)) if isinstance(n, list) else []
        for k, v in items:
            places.append((n, k))
            walk(v)
    walk(node)
    return rng.choice(places) if places else (None, None)


def _spec(rng) -> str:
    def one(depth):
        kind = rng.choice(SPEC_KINDS)
        params = []
        for _ in range(rng.randint(0, 3)):
            value = one(depth + 1) if depth < 2 and rng.random() < 0.15 else rng.choice(SPEC_VALUES)
            params.append(f"{rng.choice(SPEC_PARAMS)}={value}")
        return f"{kind}({', '.join(params)})" if params or rng.random() < 0.3 else kind
    text = one(0)
    if rng.random() < 0.25:      # a character dropped, doubled or changed
        i = rng.randrange(len(text))
        text = text[:i] + rng.choice(["", text[i] * 2, rng.choice("(),=x1 ")]) + text[i + 1:]
    return text


def _cli(rng) -> list:
    command = rng.choice(CLI_COMMANDS)
    args = [command]
    if command in ("render", "explain", "structure", "compare"):
        args.append(rng.choice(CLI_SCENES))
        args += ["--resolution", rng.choice(["4", "4", "0", "x"])]
    elif command in ("scene", "spd"):
        args.append(rng.choice(["stadium", "balls", "sun", "nosuch", "list", ""]))
    if command == "explain":
        args += ["--pixel"] + rng.choice(CLI_OPTIONS["--pixel"]).split()
    for _ in range(rng.randint(0, 3)):
        option = rng.choice(list(CLI_OPTIONS))
        args.append(option)
        if CLI_OPTIONS[option] is not None:
            args += rng.choice(CLI_OPTIONS[option]).split(" ") if option == "--pixel" else [rng.choice(CLI_OPTIONS[option])]
    return args


def _rays(rng) -> dict:
    """A RayScene query: the scene (spheres or a mesh), the rays and the query's options; mostly well
    formed, with an odd value, shape or option here and there."""
    n = rng.choice([0, 1, 3, 17, 64])
    values = [0.0, 1.0, -1.0, 0.5, 1e308, -1e308, 1e-320, float("nan"), float("inf"), 1e30, 1e31, 1e-31, 3.0]
    odd = 0.15

    def vectors(count, columns=3):
        shape = [count, columns]
        if rng.random() < odd:
            shape = rng.choice([[columns], [2, count, columns], [count, columns + 1], [count], [count, 1]])
        return np.array([rng.choice(values) if rng.random() < 0.05 else rng.uniform(-3, 3)
                         for _ in range(int(np.prod(shape)))]).reshape(shape).tolist()

    def maybe(usual, *others):
        return rng.choice(others) if rng.random() < odd else usual
    case = {"query": rng.choice(["intersect", "occluded", "count_hits", "intersect_all", "closest_points",
                                 "contains"]),
            "origins": vectors(n), "directions": vectors(n), "tmin": maybe(0.0, -1.0, 1e31, [0.0] * n, "x"),
            "tmax": maybe(float("inf"), 1.0, -1.0, float("nan"), [2.0] * n),
            "fields": maybe(None, ["t"], ["t", "uv", "normal"], ["nosuch"], "t"),
            "dtype": maybe("float64", "float32", "int8")}
    if rng.random() < 0.5:
        k = rng.choice([1, 4, 9])
        case["spheres"] = {"centers": vectors(k), "radii": [maybe(rng.uniform(0.2, 1.5), 0.0, -1.0, 1e-31, 1e31,
                                                                  float("nan")) for _ in range(maybe(k, 1, k + 1))]}
    else:
        case["mesh"] = {"vertices": vectors(4), "faces": maybe([[0, 1, 2], [1, 3, 2]], [[0, 1, 5]], [[0, 1]],
                                                               [[-1, 0, 1]], [], [[0, 0, 0]])}
    return case


# ------------------------------------------------------------------ running cases


def run(case: Case, workdir: Path | None = None) -> str:
    """'answered', 'refused' (a RayKernelError of one line), or what went wrong."""
    from raykernel.errors import RayKernelError
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            RUNNERS[case.target](case.payload, workdir)
            outcome = "answered"
        except RayKernelError as err:
            outcome = "refused" if "\n" not in str(err) and str(err) else f"a refusal of several lines: {err!s:.200}"
        except Exception as err:  # noqa: BLE001 (every other exception is what the fuzzer looks for)
            frame = traceback.extract_tb(err.__traceback__)[-1]
            return f"{type(err).__name__}: {str(err)[:160]} @ {Path(frame.filename).name}:{frame.lineno}"
    for w in caught:    # raykernel's own warnings (a budget reached, ...) say what they mean; others leak
        if not w.category.__module__.startswith("raykernel"):
            return f"{w.category.__name__}: {str(w.message)[:160]} @ {Path(w.filename).name}:{w.lineno}"
    return outcome


MAX_MEMORY = "256M"     # the renders' budget: a spec asking for a huge structure is refused, not built


def _render_all(scene) -> None:
    import raykernel
    for accel in ("bvh", "grid", "octree"):
        raykernel.render(scene, accel=accel, resolution=4, threads=1, max_memory=MAX_MEMORY)


def _run_nff(text, workdir) -> None:
    from raykernel.scene.nff import parse_nff
    _render_all(parse_nff(text, "fuzz.nff"))


def _run_json(text, workdir) -> None:
    from raykernel.scene.jsonscene import parse_json
    _render_all(parse_json(text, "fuzz.json"))


def _run_spec(text, workdir) -> None:
    import raykernel
    from raykernel.aggregates.registry import parse_spec
    from raykernel.scene.loading import load
    parse_spec(text)
    if "auto" not in text.lower():      # auto is parsed only: its search takes `seconds` (30 by default)
        raykernel.render(load("spd:balls:1"), accel=text, resolution=4, threads=1, max_memory=MAX_MEMORY)


def _run_cli(args, workdir) -> None:
    from raykernel.cli import main
    folder = Path(workdir or ".")
    args = list(args) + ["-o", str(folder / "out.png")] if args[0] in ("render", "structure") else list(args)
    if args[0] == "structure":
        args[-1] = str(folder / "out.ply")
    if args[0] in ("render", "explain", "structure", "compare") and "--max-memory" not in args:
        args += ["--max-memory", MAX_MEMORY]
    with contextlib.redirect_stdout(io.StringIO()), contextlib.redirect_stderr(io.StringIO()) as err:
        try:
            status = main(args)
        except SystemExit as exit_:       # argparse refuses with a usage line and status 2
            status = exit_.code
    if status not in (0, 2):
        raise AssertionError(f"status {status}: {err.getvalue()[-200:]}")
    if status == 2:
        from raykernel.errors import OptionError
        lines = err.getvalue().strip().splitlines()
        if "Traceback" in err.getvalue() or not lines or ": error: " not in lines[-1]:
            raise AssertionError(f"a refusal that is not one error line: {err.getvalue()[-200:]}")
        raise OptionError(lines[-1])        # refused, as the last line says


def _run_rays(case, workdir) -> None:
    from raykernel import RayScene
    if "spheres" in case:
        scene = RayScene.from_spheres(np.array(case["spheres"]["centers"]), np.array(case["spheres"]["radii"]))
    else:
        scene = RayScene.from_mesh(np.array(case["mesh"]["vertices"]), np.array(case["mesh"]["faces"]))
    o, d = np.array(case["origins"]), np.array(case["directions"])
    tmin, tmax = case["tmin"], case["tmax"]
    query = case["query"]
    if query == "intersect":
        scene.intersect(o, d, tmin, tmax, fields=case["fields"], dtype=case["dtype"])
    elif query in ("closest_points", "contains"):
        getattr(scene, query)(o)
    else:
        getattr(scene, query)(o, d, tmin, tmax)


RUNNERS = {"nff": _run_nff, "json": _run_json, "spec": _run_spec, "cli": _run_cli, "rays": _run_rays}


# ------------------------------------------------------------------ campaigns and reproducers


def campaign(seed: int, n: int, save: Path | None = None, workdir: Path | None = None) -> dict:
    """Run n cases from the seed: counts by target and outcome, the failures (saved to `save`) and
    the five slowest cases (seconds, target, key)."""
    counts, failures, slowest = Counter(), [], []
    for case in cases(seed, n):
        start = time.perf_counter()
        outcome = run(case, workdir)
        slowest = sorted(slowest + [(time.perf_counter() - start, case.target, case.key())], reverse=True)[:5]
        kind = outcome if outcome in ("answered", "refused") else "failed"
        counts[case.target, kind] += 1
        if kind == "failed":
            failures.append((case, outcome))
            if save is not None:
                save_case(case, outcome, save)
    return {"counts": counts, "failures": failures, "slowest": slowest}


def save_case(case: Case, outcome: str, folder: Path) -> Path:
    """The case as a reproducer, folder/TARGET-KEY.json, written whole (temporary file, then rename)."""
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / f"{case.target}-{case.key()}.json"
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps({"target": case.target, "payload": case.payload, "outcome": outcome}, indent=1))
    tmp.replace(path)
    return path


def load_case(path: Path) -> Case:
    data = json.loads(Path(path).read_text())
    return Case(data["target"], data["payload"])
