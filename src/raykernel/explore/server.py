"""Serving the explorer: on 127.0.0.1, every route under a random token.

    server = start(load("scene:stadium"), "scene:stadium", settings(["octree", "bvh"]), port=0)
    server.url          # http://127.0.0.1:PORT/TOKEN/ : the page; any path without the token is 404
    server.stop()
    explore(scene, accels=["octree", "bvh"])     # in Jupyter: the same app inline, below the cell

The token is the first part of every path (Dash's url_base_pathname), so the page's own requests
carry it and an iframe in Jupyter works as the browser does. Dash serves its scripts from the
installed package: the page fetches nothing from any other host. The server reads no file but
the scene it was given (the page takes structure specs and camera numbers, never a path).
"""

from __future__ import annotations

import secrets
import threading
from dataclasses import dataclass
from pathlib import Path

from ..errors import OptionError
from .jobs import Renderer
from .model import DEFAULT_RESOLUTION, Settings, read_settings, settings

HOST = "127.0.0.1"


def _framework():
    try:
        import dash  # noqa: F401
        import plotly  # noqa: F401
    except ImportError:
        raise OptionError("the explorer needs Dash and plotly: pip install 'raykernel[explore]'") from None


@dataclass
class Server:
    url: str
    app: object             # the Dash app
    renderer: Renderer
    http: object            # werkzeug's server
    thread: threading.Thread

    def stop(self) -> None:
        self.http.shutdown()
        self.thread.join()


def build(scene, label: str, s: Settings, max_memory=None, token: str | None = None, timed: bool = True):
    """(app, renderer, token) for `scene` with settings `s`."""
    _framework()
    from .app import make_app
    token = token or secrets.token_urlsafe(18)
    renderer = Renderer(scene, label, max_memory=max_memory, timed=timed)
    return make_app(renderer, s, token, label), renderer, token


def start(scene, label: str, s: Settings, port: int = 0, host: str = HOST, max_memory=None,
          timed: bool = True) -> Server:
    """The explorer served from a thread of this process (port 0: any free port)."""
    from werkzeug.serving import make_server
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
        raise OptionError(f"port must be a whole number in 0..65535, got {port!r}")
    app, renderer, token = build(scene, label, s, max_memory, timed=timed)
    http = make_server(host, port, app.server, threaded=True)
    thread = threading.Thread(target=http.serve_forever, name="raykernel-explore-http", daemon=True)
    thread.start()
    shown = f"[{host}]" if ":" in host else host
    return Server(f"http://{shown}:{http.server_port}/{token}/", app, renderer, http, thread)


def initial_settings(accels, resolution=None, settings_file=None) -> Settings:
    """The settings the explorer opens with: a settings file (export's JSON), then the options."""
    if settings_file is not None:
        s = read_settings(Path(settings_file).read_text(encoding="utf-8"))
        changes = {k: v for k, v in (("accels", accels or None), ("resolution", resolution)) if v}
        return s.replace(**changes) if changes else s
    return settings(accels or ["bvh"], resolution or DEFAULT_RESOLUTION)


def explore(scene, accels=("bvh",), resolution: int = DEFAULT_RESOLUTION, port: int = 8050, max_memory=None,
            mode: str = "inline"):
    """The explorer inline in Jupyter (mode: Dash's jupyter_mode: "inline", "tab", "external").

    Parameters
    ----------
    scene : Scene or str
        A scene, or what raykernel.load takes ("scene:stadium", "spd:balls", a file).
    accels : list of str
        The structures compared (specs, as --accel takes them).
    resolution : int
        The square image the views show.
    port : int
        The port of the server Dash starts for the notebook.
    """
    from ..scene.loading import load
    label = scene if isinstance(scene, str) else getattr(scene, "source", "scene")
    if isinstance(scene, str):
        scene = load(scene)
    app, renderer, token = build(scene, label, settings(list(accels), resolution), max_memory)
    app.run(jupyter_mode=mode, host=HOST, port=port)
    return app
