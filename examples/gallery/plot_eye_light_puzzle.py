"""
Haines's puzzle: the light at the eye
=====================================

A light at the eye casts no visible shadow, so a ray tracer may skip the shadow rays toward it
from the eye rays' hits (Haines's trick). Under Whitted shading the two images are the same.
Under Hall's model, with the camera under water, light is filtered on its way to each point, so
the trick (left) is wrong and the shadow rays cast (right) darken the image with distance
(examples/eye_light_puzzle.json).
"""

from pathlib import Path

import matplotlib.pyplot as plt

import raykernel

# examples/ (sphinx-gallery runs each script in its own folder, without __file__)
EXAMPLES = Path(__file__).resolve().parents[1] if "__file__" in globals() else Path.cwd().parent
scene = raykernel.load(str(EXAMPLES / "eye_light_puzzle.json"))
fig, axes = plt.subplots(1, 2, figsize=(10, 5))
for ax, shadows in zip(axes, ("skip", "cast")):
    result = raykernel.render(scene, shading="hall", eye_light=1.5, eye_light_shadows=shadows, resolution=256)
    print(f"eye light shadows {shadows}: {result.stats['rays.shadow']:,} shadow rays, "
          f"{result.stats['shadow.eye_light_skipped']:,} skipped")
    ax.imshow(result.image.clip(0, 1))
    ax.set_title("the trick: no shadow rays to the eye light" if shadows == "skip" else "shadow rays cast")
    ax.set_axis_off()
fig.tight_layout()
plt.show()
