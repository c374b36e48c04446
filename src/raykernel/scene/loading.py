"""One entry point for every kind of scene: files, SPD generators and examples.

    load("balls-sf4.nff")      load("scene.json")
    load("spd:balls")          load("spd:balls:2")      load("example:heckbert")
    load("bunny.ply")          load("model.obj")        (OBJ, PLY, STL, OFF, glTF, GLB: meshfile.py)
"""

from __future__ import annotations

import time
from pathlib import Path

from ..errors import OptionError, SceneError
from .model import Scene


def load(source) -> Scene:
    """Load a Scene from a file, an SPD generator, a named scene or an example.

    Parameters
    ----------
    source : str or path-like
        A path to a ``.nff``, ``.json`` or model file (``.obj``, ``.ply``, ``.stl``, ``.off``,
        ``.gltf``, ``.glb``), or ``spd:NAME[:SIZE]`` (an SPD generator at size factor SIZE,
        default its own), ``scene:NAME`` (a pathological scene) or ``example:NAME``.

    Returns
    -------
    Scene
        The scene; its ``parse_seconds`` say how long loading took (a render reports them as
        ``time.parse``), less the kernels' compiling and loading on a first call (its
        ``compile_seconds`` and ``load_seconds``).

    Raises
    ------
    SceneError
        The file does not exist, its format is unknown, or the scene in it is not valid.
    OptionError
        An unknown ``spd:``, ``scene:`` or ``example:`` name, or an SPD size factor that is
        not a positive integer in range; or a model file without trimesh installed.

    Examples
    --------
    >>> scene = load("balls-sf4.nff")
    >>> scene = load("spd:balls:2")
    >>> scene = load("example:heckbert")
    """
    from ..geometry.compiletime import CompileClock, compile_notice, typing_setup
    setup = typing_setup()      # numba's, on a process's first kernel call
    t0 = time.perf_counter()
    notice = compile_notice("reader", "compiling the scene reader's kernel (once per install)")
    with CompileClock(notice=notice) as clock:
        scene = _load(source)
    scene.parse_seconds = time.perf_counter() - t0 - clock.seconds - clock.loading
    scene.compile_seconds, scene.load_seconds = clock.seconds, setup + clock.loading
    return scene


def _load(source) -> Scene:
    text = str(source)
    prefix, _, rest = text.partition(":")
    if prefix == "spd" and rest:
        from . import spd
        from .nff import parse_nff
        name, _, size = rest.partition(":")
        if size:
            try:
                size_factor = int(size)
            except ValueError:
                raise OptionError(f"{text}: the SPD size factor must be an integer, got {size!r}") from None
        else:
            size_factor = spd.default_size(name)
        return parse_nff(spd.generate(name, size_factor), path=f"spd:{name}:{size_factor}")
    if prefix == "example" and rest:
        from . import examples
        return examples.load(rest)
    if prefix == "scene" and rest:
        from . import pathological
        return pathological.load(rest)
    path = Path(text)
    suffix = path.suffix.lower()
    if suffix == ".nff":
        from .nff import read_nff
        return read_nff(path)
    if suffix == ".json":
        from .jsonscene import read_json
        return read_json(path)
    from .meshfile import SUFFIXES, read_mesh_file
    if suffix in SUFFIXES:
        return read_mesh_file(path)
    if not path.exists():
        raise SceneError("no such file, and not spd:NAME, scene:NAME or example:NAME", path=text)
    raise SceneError(f"unknown scene format {suffix or '(no suffix)'}; expected .nff, .json or a model file "
                     f"({', '.join(SUFFIXES)})", path=text)
