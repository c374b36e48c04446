"""Where the work goes in Haines's pathological scenes: work images of several structures side by side.

    .venv/bin/python examples/newsletter_work.py [-o work] [--resolution 160] [--counter tests.total]

For the teapot in the stadium (octree, the octree with BVHs in its problem voxels, grid, BVH and
`auto`), the satellite and the sun, it renders each structure with work layers and writes one
figure per scene: every structure's per-pixel count on one scale, each one's log2 ratio against
the first, and which structure did the least work at each pixel with the share it won
(analysis/workimages.py; the same as `raykernel compare SCENE --accel ... --work-images FOLDER`).
It prints each structure's total and the winners' shares. Then it draws the octree with BVHs in
its problem voxels over a render of the stadium (`raykernel render scene:stadium --accel hybrid
--draw 3`). Needs matplotlib (raykernel[plot]).
"""

from __future__ import annotations

import argparse
from pathlib import Path

from raykernel.analysis.compare import compare
from raykernel.analysis.workimages import work_images, write_figure
from raykernel.rendering.imageio import save_image
from raykernel.rendering.overlay import draw_structure
from raykernel.rendering.render import render
from raykernel.scene.loading import load

# auto's search is bounded by evaluations, not seconds, so the hierarchy it finds is the same on every machine
AUTO = "auto(evaluations=400, seconds=600)"
SCENES = {
    "scene:stadium": ["octree", "hybrid", "grid", "bvh", AUTO],
    "scene:satellite": ["octree", "grid", "bvh", AUTO],
    "scene:sun": ["octree", "grid", "bvh", AUTO],
}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--output", default="work", help="folder for the figures (default work)")
    ap.add_argument("--resolution", type=int, default=160)
    ap.add_argument("--counter", default="tests.total", help="the work layer drawn (default tests.total)")
    args = ap.parse_args()
    folder = Path(args.output)
    folder.mkdir(parents=True, exist_ok=True)
    for scene, accels in SCENES.items():
        cmp = compare([scene], accels, resolution=args.resolution, model=None, work=args.counter,
                      command=f"examples/newsletter_work.py --resolution {args.resolution}")
        if cmp.disagreements:
            raise SystemExit("\n".join(d.text() for d in cmp.disagreements))
        w = work_images(cmp, scene)
        path = folder / f"{scene.split(':')[1]}.{args.counter}.png"
        write_figure(w, path)
        print(f"{scene}: {path}")
        shares = w.shares
        for run in cmp.runs:
            print(f"  {run.accel:36s} {args.counter} {int(run.work.sum()):>14,}   least work at "
                  f"{shares[run.accel]:6.1%} of the pixels")
        print(f"  {'(tie)':36s} {'':>14s}{' ' * len(args.counter)}    least work at {shares['tie']:6.1%}")
    stadium = load("scene:stadium")
    image = render(stadium, accel="hybrid", resolution=2 * args.resolution).image
    path = folder / "stadium.hybrid.draw.png"
    save_image(draw_structure(image, stadium, "hybrid", depth=3), path)
    print(f"scene:stadium, hybrid, boxes 0-3 deep: {path}")


if __name__ == "__main__":
    main()
