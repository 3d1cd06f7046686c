"""Which local axis of an anny bone is which motion. Renders the main shell with one bone turned 60 deg
about x, y and z (upperarm01.L, upperleg01.L, spine03) into one grid:

    python research/anny_axes.py            # -> research/anny_axes.png (needs `pip install anny`)

Seen in the grid (anny 0.6.2, default local-bone pose parameters): upperarm01 x swings the arm in the sagittal
plane, y raises it sideways, z barely shows (twist); upperleg01 x swings the leg forward/back, y sideways, z
twist; spine03 x bends forward, y sideways, z turns the torso.
"""

import tempfile
from pathlib import Path

import numpy as np
import torch

from neuralcol.data.procedural.body import bone_rotation, main_shell
from neuralcol.metrics.plots import render_mesh_png

BONES = ("upperarm01.L", "upperleg01.L", "spine03")
if __name__ == "__main__":
    torch.set_num_threads(1)
    import anny
    m = anny.Anny()
    faces = m.get_triangular_faces().numpy().astype(np.int64)
    with torch.no_grad():
        rest = m(pose_parameters=None)["vertices"][0].double().numpy()
    keep, bf = main_shell(faces, len(rest))
    col = np.tile([0.7, 0.7, 0.8, 1.0], (int(keep.sum()), 1))
    tmp = Path(tempfile.mkdtemp())
    panels = []
    for bone in BONES:
        for axis in "xyz":
            pose = {bone: bone_rotation(axis, 60.0)}
            with torch.no_grad():
                v = m(pose_parameters=pose)["vertices"][0].double().numpy()[keep]
            panels.append(render_mesh_png(tmp / f"{bone}_{axis}.png", v, bf, col, views=((10, -90), (10, 0)),
                                          title=f"{bone} {axis} +60", size=2.5))
    from PIL import Image

    ims = [Image.open(p) for p in panels]
    w, h = ims[0].size
    grid = Image.new("RGB", (w * 3, h * len(BONES)), "white")
    for i, im in enumerate(ims):
        grid.paste(im, ((i % 3) * w, (i // 3) * h))
    grid.thumbnail((1500, 1500))
    out = Path(__file__).with_name("anny_axes.png")
    grid.save(out)
    print(out)
