"""The dot projector and the flood light as ONE Cycles spot light.

The light's node tree turns the direction of each light ray (Texture Coordinate Normal, in the
light's own frame) into pattern texture coordinates, like a pinhole projector, and emits the colour
(pattern * projector_gain, inside_pattern_rectangle * flood_gain, 0). Materials are grey, so the red
channel of the render is the projector's contribution and the green one the flood rectangle's: both
come from the same light samples, so neither steals samples from the other (unlike two lights in
light groups). Blue is left for ambient light (world and extra lights are pure blue).
"""

from __future__ import annotations

import math
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

from .geometry import projector_uv_coefficients, spot_cone_angle
from .pattern_filter import box_prefilter, png16_bytes


def _load_data_image(path: str, what: str) -> bpy.types.Image:
    """Load an image file as raw data (Non-Color); ValueError naming the file when Blender cannot."""
    try:
        image = bpy.data.images.load(path, check_existing=False)
    except RuntimeError as error:
        raise ValueError(f"{what} {path} cannot be read: {error}") from None
    image.colorspace_settings.name = "Non-Color"
    return image


def _math(tree, operation: str, a, b):
    node = tree.nodes.new("ShaderNodeMath")
    node.operation = operation
    for k, value in enumerate((a, b)):
        if isinstance(value, int | float):
            node.inputs[k].default_value = value
        else:
            tree.links.new(value, node.inputs[k])
    return node


class ProjectorLight:
    """A spot light projecting a pattern image (red channel) and its bounding rectangle (green)."""

    def __init__(self, collection: bpy.types.Collection):
        # Read by set_powers; the renderer sets it from the scene's frame recipe (frame_recipe.py).
        self.sampling_boost = 1.0
        self.light = bpy.data.lights.new("dotsim_projector", "SPOT")
        self.light.shadow_soft_size = 0.0  # a pinhole: sharp dots and sharp shadows
        self.light.spot_blend = 0.0
        self.light.use_nodes = True
        self.object = bpy.data.objects.new("dotsim_projector", self.light)
        collection.objects.link(self.object)
        self._build_tree()
        self._pattern_key: tuple[str, float] | None = None

    def _build_tree(self) -> None:
        tree = self.light.node_tree
        tree.nodes.clear()
        direction = tree.nodes.new("ShaderNodeTexCoord").outputs["Normal"]
        xyz = tree.nodes.new("ShaderNodeSeparateXYZ")
        tree.links.new(direction, xyz.inputs[0])
        x_over_z = _math(tree, "DIVIDE", xyz.outputs["X"], xyz.outputs["Z"]).outputs[0]
        y_over_z = _math(tree, "DIVIDE", xyz.outputs["Y"], xyz.outputs["Z"]).outputs[0]
        self.u_node = _math(tree, "MULTIPLY_ADD", x_over_z, 1.0)  # input 2 (offset) set per rig
        self.v_node = _math(tree, "MULTIPLY_ADD", y_over_z, 1.0)
        uv = tree.nodes.new("ShaderNodeCombineXYZ")
        tree.links.new(self.u_node.outputs[0], uv.inputs["X"])
        tree.links.new(self.v_node.outputs[0], uv.inputs["Y"])
        self.texture = tree.nodes.new("ShaderNodeTexImage")
        self.texture.extension = "CLIP"
        self.texture.interpolation = "Linear"
        tree.links.new(uv.outputs[0], self.texture.inputs["Vector"])
        # Rectangle: 1 where 0 <= U <= 1 and 0 <= V <= 1 (the pattern's extent), else 0.
        inside = None
        for coordinate in (self.u_node.outputs[0], self.v_node.outputs[0]):
            above = _math(tree, "GREATER_THAN", coordinate, 0.0).outputs[0]
            below = _math(tree, "LESS_THAN", coordinate, 1.0).outputs[0]
            both = _math(tree, "MULTIPLY", above, below).outputs[0]
            inside = both if inside is None else _math(tree, "MULTIPLY", inside, both).outputs[0]
        pattern = tree.nodes.new("ShaderNodeSeparateColor")
        tree.links.new(self.texture.outputs["Color"], pattern.inputs[0])
        self.pattern_gain = _math(tree, "MULTIPLY", pattern.outputs["Red"], 1.0)
        self.flood_gain = _math(tree, "MULTIPLY", inside, 1.0)
        colour = tree.nodes.new("ShaderNodeCombineColor")
        tree.links.new(self.pattern_gain.outputs[0], colour.inputs["Red"])
        tree.links.new(self.flood_gain.outputs[0], colour.inputs["Green"])
        colour.inputs["Blue"].default_value = 0.0
        emission = tree.nodes.new("ShaderNodeEmission")
        emission.inputs["Strength"].default_value = 1.0
        tree.links.new(colour.outputs[0], emission.inputs["Color"])
        output = tree.nodes.new("ShaderNodeOutputLight")
        tree.links.new(emission.outputs[0], output.inputs["Surface"])

    def set_pattern(self, path: str, key: str, prefilter_width: float, scratch: Path) -> None:
        """Project the pattern PNG at `path` (row 0 = top; Blender stores rows bottom-up, which
        projector_uv_coefficients accounts for), averaged over `prefilter_width` pattern pixels
        (pattern_filter.py; <= 1 means as is). The filtered copy is written as a 16-bit PNG into
        the private folder `scratch`. `key` (the pattern's sha256) with the width avoids redoing
        this for every scene; the previous image is removed so memory stays flat."""
        width = prefilter_width if prefilter_width > 1.0 else 0.0
        if (key, width) == self._pattern_key:
            return
        image = _load_data_image(path, "pattern")
        if width:
            columns, rows = image.size
            pixels = np.empty(columns * rows * 4, np.float32)
            image.pixels.foreach_get(pixels)
            bpy.data.images.remove(image)
            top_down = pixels.reshape(rows, columns, 4)[::-1, :, 0]
            filtered_path = scratch / f"pattern_{key[:16]}_{width:.4f}.png"
            filtered_path.write_bytes(png16_bytes(box_prefilter(top_down, width)))
            image = _load_data_image(str(filtered_path), "pattern")
        old = self.texture.image
        self.texture.image = image
        if old is not None:
            old_path = Path(bpy.path.abspath(old.filepath))
            bpy.data.images.remove(old)
            if old_path.parent == scratch:
                old_path.unlink(missing_ok=True)
        self._pattern_key = (key, width)

    def set_intrinsics(self, intrinsics: tuple[int, int, float, float, float, float]) -> None:
        """Pinhole intrinsics (width, height, fx, fy, cx, cy) of the projector, in pattern pixels."""
        a_u, b_u, a_v, b_v = projector_uv_coefficients(*intrinsics)
        self.u_node.inputs[1].default_value = a_u
        self.u_node.inputs[2].default_value = b_u
        self.v_node.inputs[1].default_value = a_v
        self.v_node.inputs[2].default_value = b_v
        self.light.spot_size = spot_cone_angle(*intrinsics)

    def set_powers(self, projector_power: float, flood_power: float) -> None:
        """Spot power (W) for a fully white pattern pixel in red, and for the flood rectangle in green.
        The node gains scale each channel, so either power can be zero without touching the other
        channel; the light's energy is sampling_boost times the larger power (frame_recipe.py
        SAMPLING_BOOST: more light samples for the spot, the same image)."""
        for name, value in (("projector.power", projector_power), ("flood.power", flood_power)):
            if not (math.isfinite(value) and value >= 0):
                raise ValueError(f"{name} must be a finite number >= 0, got {value!r}")
        energy = self.sampling_boost * max(projector_power, flood_power)
        self.light.energy = energy
        self.object.hide_render = energy == 0
        self.pattern_gain.inputs[1].default_value = projector_power / energy if energy else 0.0
        self.flood_gain.inputs[1].default_value = flood_power / energy if energy else 0.0

    def set_pose(self, blender_matrix: np.ndarray) -> None:
        self.object.matrix_world = Matrix(blender_matrix.tolist())
