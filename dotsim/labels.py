"""Per-pixel labels of a rendered frame from its object index pass (pure numpy): which object, of what
material, and whether a structured-light sensor can trust the dots there.

The renderer gives each object of a scene the pass index k + 1 (k its place in the scene's objects, as
scene.json lists them) and Cycles writes the index of the first surface a camera ray hits, 0 where it
hits none, exactly (never averaged over samples). From it:

- `instance`: k + 1, except the room's surfaces (ROOM_SURFACES), which are all 0, as is no surface;
- `material`: the class of the object's material, MATERIAL_CLASSES[c] for label c (0: no surface);
- `transparent_or_mirror`: 1 where the first surface is glass or metal (SEE_THROUGH_KINDS): there a
  sensor sees dots that lie on another surface, refracted through it or reflected off it.

>>> import numpy as np
>>> labels = object_labels(np.array([[0.0, 1.0, 2.0, 3.0]]), ["opaque", "metal", "ir_dark"],
...                        ["floor", "object_0000", "object_0001"])
>>> labels["instance"].tolist(), labels["material"].tolist(), labels["transparent_or_mirror"].tolist()
([[0, 0, 2, 3]], [[0, 1, 3, 4]], [[False, False, True, False]])
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

# What a surface is made of (docs/CONFIG.md "Materials"): grey opaque (matte or glossy), transparent
# (glass, clear plastic), metal (mirror-like), IR-dark (opaque, low near-infrared albedo).
MATERIAL_KINDS = ("opaque", "transparent", "metal", "ir_dark")
# The `material` label's classes: 0 where no surface is hit, then MATERIAL_KINDS in order.
MATERIAL_CLASSES = ("none", *MATERIAL_KINDS)
# The kinds on which a sensor sees dots of another surface than the first one.
SEE_THROUGH_KINDS = ("transparent", "metal")
# The names of the room's surfaces (generator/sample_scene.py): instance 0.
ROOM_SURFACES = ("floor", "ceiling", "wall_back", "wall_front", "wall_left", "wall_right")


def object_labels(object_index: np.ndarray, kinds: Sequence[str], names: Sequence[str],
                  where: str = "frame") -> dict[str, np.ndarray]:
    """{"instance": int32, "material": int32, "transparent_or_mirror": bool} (H, W) from an object index
    pass (float, k + 1 for objects[k], 0 for none) and the scene's objects' material kinds and names, in
    scene order. ValueError naming `where` when the pass holds a value that is no object's index."""
    index = np.rint(object_index).astype(np.int64)
    bad = (index < 0) | (index > len(kinds)) | (np.abs(object_index - index) > 1e-3)
    if bad.any():
        raise ValueError(f"{where}: object index pass holds {float(object_index[bad][0])}, no object's "
                         f"index; allowed: integers 0 to {len(kinds)} (the scene's objects + 1)")
    unknown = sorted(set(kinds) - set(MATERIAL_KINDS))
    if unknown:
        raise ValueError(f"{where}: material kind {unknown[0]!r}; allowed: {', '.join(MATERIAL_KINDS)}")
    instance = np.array([0] + [0 if name in ROOM_SURFACES else k + 1 for k, name in enumerate(names)],
                        np.int32)
    material = np.array([0] + [MATERIAL_CLASSES.index(kind) for kind in kinds], np.int32)
    see_through = np.array([False] + [kind in SEE_THROUGH_KINDS for kind in kinds])
    return {"instance": instance[index], "material": material[index],
            "transparent_or_mirror": see_through[index]}
