"""An example scene's triangles with the part that owns each face, as the simulator's world_triangles gives
them (vertices, faces, owner index per face, part names): the input of ground_truth.object_meshes/room_mesh."""

from __future__ import annotations

import numpy as np


def example_triangles(ex):
    verts, faces, alb = ex.triangles()
    owner = np.repeat(np.arange(len(ex.parts)), [len(p.faces) for p in ex.parts])
    return verts, faces, owner, [p.name for p in ex.parts]
