"""Read the user's own meshes (OBJ, PLY, STL, GLB/GLTF, OFF) and images into raw arrays.

Every failure is a MeshError or ImageError whose message says why, so the builder can skip the file
with a report line instead of stopping half-way.
"""

from pathlib import Path

import numpy as np

from assets_manifest.images import ImageError, to_grey
from assets_manifest.mesh_arrays import MeshError


def load_mesh_file(path: str | Path) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
    """(vertices (V,3), faces (F,3), uvs (V,2) or None) of a mesh file; a multi-part file (GLB
    scene) is flattened with its node transforms applied."""
    import trimesh

    path = Path(path)
    if path.stat().st_size == 0:
        raise MeshError("empty file (0 bytes)")
    try:
        # process=False keeps vertices split at UV seams, so texture coordinates stay per vertex.
        mesh = trimesh.load(path, force="mesh", process=False)
    except Exception as exc:  # trimesh raises many exception types for unreadable files
        raise MeshError(f"cannot read as a mesh: {type(exc).__name__}: {exc}") from None
    if not isinstance(mesh, trimesh.Trimesh):
        raise MeshError(f"no triangle mesh in the file (trimesh gave {type(mesh).__name__})")
    uvs = getattr(mesh.visual, "uv", None)
    if uvs is not None and len(uvs) != len(mesh.vertices):
        uvs = None
    return np.asarray(mesh.vertices), np.asarray(mesh.faces), None if uvs is None else np.asarray(uvs)


def load_image_file(path: str | Path) -> np.ndarray:
    """Grey (H,W) pixels of an image file at their stored bit depth (8- or 16-bit, or float)."""
    import cv2

    path = Path(path)
    if path.stat().st_size == 0:
        raise ImageError("empty file (0 bytes)")
    image = cv2.imread(str(path), cv2.IMREAD_UNCHANGED)
    if image is None:
        raise ImageError("cannot read as an image (corrupt or unsupported format)")
    return to_grey(image)
