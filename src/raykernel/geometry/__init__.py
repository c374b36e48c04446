"""What every compiled kernel uses: primitive intersection tests, box tests, the counter
layout and the compile configuration.

    from raykernel.geometry.primitives import hit_sphere
    from raykernel.geometry import counters as C
"""
