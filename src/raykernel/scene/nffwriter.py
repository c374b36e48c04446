"""Writing NFF text entity by entity, numbers in C's %g as the SPD programs print them.

    w = NffWriter()
    w.background((0.078, 0.361, 0.753))
    w.view(eye, at, up, 45, 0.01, 512)
    w.light((4, 3, 2))
    w.fill((1, 0.75, 0.33), kd=0.8, ks=0, shine=100000, t=0, ior=1)
    w.sphere((0, 0, 0), 0.5)
    text = w.text()
"""

from __future__ import annotations


def fmt(x: float) -> str:
    """A number as C's printf("%g") writes it (6 significant digits)."""
    s = "%g" % float(x)
    return "0" if s == "-0" else s


def _nums(values) -> str:
    return " ".join(fmt(v) for v in values)


class NffWriter:
    """Collects NFF lines; `text()` joins them with a final newline."""

    def __init__(self):
        self.lines: list[str] = []

    def comment(self, text: str):
        for line in str(text).splitlines() or [""]:
            self.lines.append("# " + line)

    def background(self, color):
        self.lines.append("b " + _nums(color))

    def view(self, eye, at, up, angle, hither, resolution):
        res = resolution if isinstance(resolution, (tuple, list)) else (resolution, resolution)
        self.lines += ["v", "from " + _nums(eye), "at " + _nums(at), "up " + _nums(up),
                       "angle " + fmt(angle), "hither " + fmt(hither), "resolution %d %d" % tuple(res)]

    def light(self, position, color=None):
        self.lines.append("l " + _nums(position) + ("" if color is None else " " + _nums(color)))

    def fill(self, color, kd, ks, shine, t, ior):
        self.lines.append("f " + _nums(color) + " " + _nums((kd, ks, shine, t, ior)))

    def sphere(self, center, radius):
        self.lines.append("s " + _nums(center) + " " + fmt(radius))

    def cone(self, base, base_radius, apex, apex_radius):
        # The SPD writes a cone on one line; NFF is read by tokens, so this is valid.
        self.lines.append("c " + _nums(base) + " " + fmt(base_radius) + " " + _nums(apex) + " " + fmt(apex_radius))

    def polygon(self, vertices):
        self.lines.append("p %d" % len(vertices))
        self.lines += [_nums(v) for v in vertices]

    def patch(self, vertices, normals):
        self.lines.append("pp %d" % len(vertices))
        self.lines += [_nums(v) + " " + _nums(n) for v, n in zip(vertices, normals)]

    def text(self) -> str:
        return "\n".join(self.lines) + "\n"
