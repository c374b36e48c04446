"""The work explorer: every view of where the work goes, linked, in the browser or in Jupyter.

    raykernel explore scene:stadium --accel octree --accel bvh     # prints its address, token included
    raykernel.explore(scene, accels=["octree", "bvh"])              # the same app inline in Jupyter

model.py renders each structure and links its views (numbers only, no framework); quality.py
measures each node of a structure; jobs.py renders off the page's thread, newest request first,
one renderer a browser tab, and warms the kernels as the server starts; figures.py draws the
model with plotly; app.py lays out the page and wires its callbacks (Dash); server.py serves it
on 127.0.0.1 behind a token. Dash and plotly are the explore extra (pip install
'raykernel[explore]'), imported only when the explorer starts.
"""
