"""Serving the explorer: on 127.0.0.1, every route under a random token.

    server = start(load("scene:stadium"), "scene:stadium", settings(["octree", "bvh"]), port=0)
    server.url          # http://127.0.0.1:PORT/TOKEN/ : the page; any path without the token is 404
    server.warm.done.wait()     # the kernels, warmed in a thread as it starts (jobs.Warmup)
    server.sessions             # one Renderer a browser tab (jobs.Sessions)
    server.stop()
    server = explore(scene, accels=["octree", "bvh"])   # the same; in Jupyter shown inline below the cell

The token is the first part of every path (Dash's url_base_pathname), so the page's own requests
carry it and the iframe Jupyter shows works as the browser does. Dash serves its scripts from the
installed package: the page fetches nothing from any other host. The server reads no file but
the scene it was given (the page takes structure specs and camera numbers, never a path).
"""

from __future__ import annotations

import logging
import secrets
import threading
from dataclasses import dataclass
from pathlib import Path

from ..errors import OptionError
from .jobs import Renderer, Sessions, Warmup
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
    sessions: Sessions      # one Renderer a browser tab
    warm: Warmup
    http: object            # werkzeug's server
    thread: threading.Thread

    @property
    def renderer(self) -> Renderer | None:
        """The Renderer of the tab that asked last (None before any page asked)."""
        return self.sessions.newest()

    def stop(self) -> None:
        self.sessions.close()
        self.http.shutdown()
        self.thread.join()


def build(scene, label: str, s: Settings, max_memory=None, token: str | None = None, timed: bool = True):
    """(app, sessions, warm-up, token) for `scene` with settings `s`: the kernels begin warming now."""
    _framework()
    from .app import make_app
    token = token or secrets.token_urlsafe(18)
    sessions = Sessions(scene, label, s, max_memory=max_memory, timed=timed)
    warm = Warmup(scene, s.accels, sessions.share, timed)     # within one session's budget
    sessions.ready = warm.done          # a tab's request waits for it (cancellably)
    return make_app(sessions, s, token, label, warm), sessions, warm, token


def start(scene, label: str, s: Settings, port: int = 0, host: str = HOST, max_memory=None,
          timed: bool = True) -> Server:
    """The explorer served from a thread of this process (port 0: any free port)."""
    from werkzeug.serving import make_server
    if isinstance(port, bool) or not isinstance(port, int) or not 0 <= port <= 65535:
        raise OptionError(f"port must be a whole number in 0..65535, got {port!r}")
    app, sessions, warm, token = build(scene, label, s, max_memory, timed=timed)
    logging.getLogger("werkzeug").setLevel(logging.WARNING)       # no line per request (Dash's Jupyter mode does the same)
    http = make_server(host, port, app.server, threaded=True)
    thread = threading.Thread(target=http.serve_forever, name="raykernel-explore-http", daemon=True)
    thread.start()
    shown = f"[{host}]" if ":" in host else host
    return Server(f"http://{shown}:{http.server_port}/{token}/", app, sessions, warm, http, thread)


def initial_settings(accels, resolution=None, settings_file=None) -> Settings:
    """The settings the explorer opens with: a settings file (export's JSON), then the options."""
    if settings_file is not None:
        s = read_settings(Path(settings_file).read_text(encoding="utf-8"))
        changes = {k: v for k, v in (("accels", accels or None), ("resolution", resolution)) if v}
        return s.replace(**changes) if changes else s
    return settings(accels or ["bvh"], resolution or DEFAULT_RESOLUTION)


def explore(scene, accels=("bvh",), resolution: int = DEFAULT_RESOLUTION, port: int = 0, max_memory=None,
            height: int = 900) -> Server:
    """The explorer for `scene`, served from a thread of this process; in Jupyter, shown inline
    below the cell (an iframe of its address), elsewhere its address printed.

    Parameters
    ----------
    scene : Scene or str
        A scene, or what raykernel.load takes ("scene:stadium", "spd:balls", a file).
    accels : list of str
        The structures compared (specs, as --accel takes them).
    resolution : int
        The square image the views show.
    port : int
        The port to serve on (0: any free one).
    height : int
        The inline view's height in pixels.

    Returns
    -------
    Server
        ``url`` (token included) and ``stop()``.

    Raises
    ------
    OptionError
        A bad spec or resolution (the message names it), or Dash and plotly are not installed.
    """
    from ..scene.loading import load
    label = scene if isinstance(scene, str) else getattr(scene, "source", "scene")
    s = settings(list(accels) if not isinstance(accels, str) else [accels], resolution)
    if isinstance(scene, str):
        scene = load(scene)
    server = start(scene, label, s, port=port, max_memory=max_memory)
    shell = _notebook()
    if shell is not None:
        from IPython.display import IFrame, display
        display(IFrame(server.url, width="100%", height=height))
    else:
        print(f"raykernel explore: {server.url}")
    return server


def _notebook():
    """The IPython kernel's shell where this runs in Jupyter, else None."""
    import sys
    ipython = sys.modules.get("IPython")
    shell = ipython.get_ipython() if ipython is not None and hasattr(ipython, "get_ipython") else None
    return shell if shell is not None and getattr(shell, "kernel", None) is not None else None
