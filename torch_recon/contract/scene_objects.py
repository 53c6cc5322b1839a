"""Which parts of a scene are the objects that matter, and which are the room (numpy + trimesh only).

Rules, in order (the simulator applies them to a Blender scene's objects, the evaluator to a dataset
without labels):
1. Labelled: a Blender collection named `Objects` (OBJECTS_COLLECTION): each child collection is one
   object (its name is the label), each mesh directly inside `Objects` is one object; example scenes label
   their parts this way. Everything else is room.
2. Unlabelled: a part is the room's bounding shell when its bounding box spans at least
   SHELL_SPAN_FRACTION of the scene's extent along two axes (walls, floor, ceiling, a curved back wall);
   the other parts are objects, parts whose bounding boxes touch (within TOUCH_M) grouped into one
   (a chair's seat, back and legs), labelled by the largest part's name.
"""

from __future__ import annotations

import numpy as np

OBJECTS_COLLECTION = "Objects"
SHELL_SPAN_FRACTION = 0.6
TOUCH_M = 0.01


def is_shell(part_bounds, scene_bounds, span_fraction=SHELL_SPAN_FRACTION) -> bool:
    """A part spanning most of the scene along two axes is a wall, floor or ceiling."""
    ext = np.asarray(scene_bounds[1], float) - np.asarray(scene_bounds[0], float)
    pext = np.asarray(part_bounds[1], float) - np.asarray(part_bounds[0], float)
    return int((pext >= span_fraction * np.maximum(ext, 1e-9)).sum()) >= 2


def group_objects(parts: dict) -> dict:
    """{part name: (lo, hi) bounds} of non-shell parts -> {label: [part names]} (touching parts grouped)."""
    names = list(parts)
    parent = list(range(len(names)))

    def root(i):
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    b = [(np.asarray(parts[n][0], float), np.asarray(parts[n][1], float)) for n in names]
    for i in range(len(names)):
        for j in range(i + 1, len(names)):
            if np.all(b[i][0] <= b[j][1] + TOUCH_M) and np.all(b[j][0] <= b[i][1] + TOUCH_M):
                parent[root(i)] = root(j)
    groups = {}
    for i, n in enumerate(names):
        groups.setdefault(root(i), []).append(n)
    out = {}
    for members in groups.values():
        vol = [float(np.prod(np.maximum(parts[m][1] - np.asarray(parts[m][0]), 1e-6))) for m in members]
        label = members[int(np.argmax(vol))]
        out[label] = sorted(members)
    return out


def label_parts(part_bounds: dict, labelled: dict | None = None) -> dict:
    """{label: [part names]} for a scene's parts {name: (lo, hi)}: `labelled` wins (rule 1), else rule 2."""
    if labelled:
        known = set(part_bounds)
        return {k: [p for p in v if p in known] for k, v in labelled.items() if any(p in known for p in v)}
    if not part_bounds:
        return {}
    lo = np.min([np.asarray(b[0], float) for b in part_bounds.values()], axis=0)
    hi = np.max([np.asarray(b[1], float) for b in part_bounds.values()], axis=0)
    inner = {n: b for n, b in part_bounds.items() if not is_shell(b, (lo, hi))}
    return group_objects(inner)


def split_mesh_objects(mesh) -> dict:
    """A dataset's GT mesh without labels -> {label: trimesh} by rule 2 over its connected components."""
    comps = mesh.split(only_watertight=False)
    bounds = {f"part_{i:03d}": (c.bounds[0], c.bounds[1]) for i, c in enumerate(comps)}
    labels = label_parts(bounds)
    import trimesh
    return {f"object_{k}": trimesh.util.concatenate([comps[int(p.split('_')[1])] for p in v])
            for k, (_, v) in enumerate(sorted(labels.items()))}
