"""Haines's puzzle, answered: the light at the eye rendered naively and correctly, side by side.

    .venv/bin/python examples/eye_light_puzzle.py [-o eye-light-puzzle.png]

Left: the trick (no shadow rays toward the eye light from eye rays' hits). Right: the same
light with its shadow rays cast. Under Whitted shading the two are the same image; under the
Hall model, with the camera under water, the right one is darker with distance (docs/guide/rendering.md,
"The light at the eye").
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

import raykernel
from raykernel.rendering.imageio import save_image

SCENE = Path(__file__).with_name("eye_light_puzzle.json")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--output", default="eye-light-puzzle.png")
    args = parser.parse_args()
    scene = raykernel.load(str(SCENE))
    images = []
    for shadows in ("skip", "cast"):
        result = raykernel.render(scene, shading="hall", eye_light=1.5, eye_light_shadows=shadows)
        images.append(result.image)
        print(f"eye light shadows {shadows}: {result.stats['rays.shadow']:,} shadow rays, "
              f"{result.stats['shadow.eye_light_skipped']:,} skipped")
    naive, right = images
    gap = np.ones((naive.shape[0], 4, 3))
    save_image(np.concatenate([naive, gap, right], axis=1), args.output)
    lit = right.sum(axis=2) > 0.02
    print(f"correct / naive brightness where lit: {np.median(right.sum(axis=2)[lit] / naive.sum(axis=2)[lit]):.2f} "
          f"(median), {(right.sum(axis=2)[lit] / naive.sum(axis=2)[lit]).min():.2f} (least) -> {args.output}")


if __name__ == "__main__":
    main()
