"""Contact sheet of a built cache: meshes shaded with a UV checker (so UV seams and stretching show)
and textures, in a grid PNG. Pure numpy rasterisation; no Blender."""

import numpy as np

from assets_manifest.mesh_arrays import load_mesh_npz

_VIEW = (np.radians(25.0), np.radians(35.0))  # pitch, yaw of the orthographic view
# Unit vector towards the light in the view frame (x right, y up, z away): upper left, in front.
_LIGHT = np.array([-0.4, 0.6, -0.7]) / np.linalg.norm([-0.4, 0.6, -0.7])


def _view_rotation() -> np.ndarray:
    pitch, yaw = _VIEW
    cy, sy, cp, sp = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch)
    yaw_m = np.array([[cy, 0, sy], [0, 1, 0], [-sy, 0, cy]])
    pitch_m = np.array([[1, 0, 0], [0, cp, -sp], [0, sp, cp]])
    return pitch_m @ yaw_m


def render_mesh_thumbnail(arrays: dict[str, np.ndarray], size: int = 128, checker: int = 8) -> np.ndarray:
    """(size,size) float image in [0,1] of a cache mesh: orthographic view (after a fixed pitch/yaw:
    x right, y up, z away from the viewer), z-buffered, Lambert-shaded with the stored normals and
    modulated by a `checker` x `checker` UV checkerboard. Background 1.0."""
    rotation = _view_rotation()
    v = arrays["vertices"].astype(np.float64) @ rotation.T
    n = arrays["normals"].astype(np.float64) @ rotation.T
    uv, faces = arrays["uvs"].astype(np.float64), arrays["faces"]
    # Vertices lie within a unit cube; its diagonal (sqrt 3) fits the frame.
    scale = (size - 4) / np.sqrt(3.0)
    px = v[:, 0] * scale + size / 2
    py = -v[:, 1] * scale + size / 2  # +y up in the mesh, rows go down
    depth = np.full((size, size), np.inf)
    image = np.ones((size, size))
    for f in faces:
        xs, ys = px[f], py[f]
        x0, x1 = max(int(np.floor(xs.min())), 0), min(int(np.ceil(xs.max())), size - 1)
        y0, y1 = max(int(np.floor(ys.min())), 0), min(int(np.ceil(ys.max())), size - 1)
        if x1 < x0 or y1 < y0:
            continue
        gy, gx = np.mgrid[y0 : y1 + 1, x0 : x1 + 1] + 0.0
        det = (ys[1] - ys[2]) * (xs[0] - xs[2]) + (xs[2] - xs[1]) * (ys[0] - ys[2])
        if abs(det) < 1e-12:
            continue
        w0 = ((ys[1] - ys[2]) * (gx - xs[2]) + (xs[2] - xs[1]) * (gy - ys[2])) / det
        w1 = ((ys[2] - ys[0]) * (gx - xs[2]) + (xs[0] - xs[2]) * (gy - ys[2])) / det
        w2 = 1 - w0 - w1
        inside = (w0 >= 0) & (w1 >= 0) & (w2 >= 0)
        if not inside.any():
            continue
        w = np.stack([w0[inside], w1[inside], w2[inside]], axis=1)
        z = w @ v[f, 2]
        rows, cols = gy[inside].astype(int), gx[inside].astype(int)
        nearer = z < depth[rows, cols]
        if not nearer.any():
            continue
        rows, cols, w, z = rows[nearer], cols[nearer], w[nearer], z[nearer]
        normal = w @ n[f]
        normal /= np.linalg.norm(normal, axis=1, keepdims=True) + 1e-12
        shade = 0.15 + 0.85 * np.clip(normal @ _LIGHT, 0, 1)
        tex_uv = w @ uv[f]
        check = (np.floor(tex_uv[:, 0] * checker) + np.floor(tex_uv[:, 1] * checker)) % 2
        depth[rows, cols] = z
        image[rows, cols] = shade * (0.55 + 0.45 * check)
    return image


def texture_thumbnail(image: np.ndarray, size: int = 128) -> np.ndarray:
    """Centre square of a grey texture, resized to (size,size), as floats in [0,1]."""
    import cv2

    side = min(image.shape)
    top, left = (image.shape[0] - side) // 2, (image.shape[1] - side) // 2
    square = image[top : top + side, left : left + side].astype(np.float64) / np.iinfo(image.dtype).max
    return cv2.resize(square, (size, size), interpolation=cv2.INTER_AREA)


def contact_sheet(cache, count: int = 24, size: int = 128, columns: int = 8) -> np.ndarray:
    """uint8 grid image: `count` meshes then `count` textures of an AssetCache, evenly spread over its
    lists, with a 2 px grey gutter."""
    import cv2

    def spread(entries):
        return [
            entries[i]
            for i in np.unique(np.linspace(0, len(entries) - 1, min(count, len(entries))).astype(int))
        ]

    tiles = (
        [render_mesh_thumbnail(load_mesh_npz(e.path), size) for e in spread(cache.meshes)]
        if cache.meshes
        else []
    )
    tiles += [
        texture_thumbnail(cv2.imread(e.path, cv2.IMREAD_UNCHANGED), size) for e in spread(cache.textures)
    ]
    if not tiles:
        raise ValueError(f"the {cache.split} cache has no meshes or textures to show")
    rows = -(-len(tiles) // columns)
    gutter = 2
    sheet = np.full((rows * (size + gutter) + gutter, columns * (size + gutter) + gutter), 0.5)
    for k, tile in enumerate(tiles):
        r, c = divmod(k, columns)
        y, x = gutter + r * (size + gutter), gutter + c * (size + gutter)
        sheet[y : y + size, x : x + size] = tile
    return np.round(sheet * 255).astype(np.uint8)
