"""Grey infrared materials for Cycles.

Infrared reflectance is one number per surface point, so every material is grey: base colour
(r, r, r) with r = albedo * (1 - contrast + 2 contrast t) clamped to [0, 1], t the texture's grey
value (luminance of a Non-Color image, sampled at object UV * scale), or r = albedo without a
texture. Grey materials never move light between colour channels, which the renderer relies on to
carry projector, flood and ambient light in R, G and B of one render.

Per-object values (albedo, roughness, specular, texture scale and contrast) live in object custom
properties read by Attribute nodes, so one material per texture image serves every object and
scene: few node trees to build, nothing to grow between scenes.
"""

from __future__ import annotations

from collections import OrderedDict
from pathlib import Path

import bpy

# Object custom-property names read by the shared materials.
PROPERTIES = ("dotsim_albedo", "dotsim_roughness", "dotsim_specular", "dotsim_tex_scale", "dotsim_contrast")


def _attribute(nodes, name: str):
    node = nodes.new("ShaderNodeAttribute")
    node.attribute_type = "OBJECT"
    node.attribute_name = name
    return node.outputs["Fac"]


def _math(tree, operation: str, a, b, c=None):
    """Math node computing operation(a, b[, c]); a, b, c are sockets or numbers."""
    node = tree.nodes.new("ShaderNodeMath")
    node.operation = operation
    for k, value in enumerate((a, b, c)):
        if value is None:
            continue
        if isinstance(value, int | float):
            node.inputs[k].default_value = value
        else:
            tree.links.new(value, node.inputs[k])
    return node.outputs[0]


def build_material(name: str, image: bpy.types.Image | None) -> bpy.types.Material:
    """A Principled BSDF material reading the per-object PROPERTIES; `image` (Non-Color) is the
    reflectance texture or None for a uniform albedo."""
    material = bpy.data.materials.new(name)
    tree = material.node_tree
    tree.nodes.clear()
    bsdf = tree.nodes.new("ShaderNodeBsdfPrincipled")
    output = tree.nodes.new("ShaderNodeOutputMaterial")
    tree.links.new(bsdf.outputs["BSDF"], output.inputs["Surface"])
    albedo = _attribute(tree.nodes, "dotsim_albedo")
    if image is None:
        reflectance = albedo
    else:
        uv = tree.nodes.new("ShaderNodeTexCoord").outputs["UV"]
        scale = _attribute(tree.nodes, "dotsim_tex_scale")
        scaled = tree.nodes.new("ShaderNodeVectorMath")
        scaled.operation = "SCALE"
        tree.links.new(uv, scaled.inputs[0])
        tree.links.new(scale, scaled.inputs["Scale"])
        texture = tree.nodes.new("ShaderNodeTexImage")
        texture.image = image
        texture.extension = "REPEAT"
        texture.interpolation = "Linear"
        tree.links.new(scaled.outputs["Vector"], texture.inputs["Vector"])
        grey = tree.nodes.new("ShaderNodeRGBToBW")
        tree.links.new(texture.outputs["Color"], grey.inputs["Color"])
        contrast = _attribute(tree.nodes, "dotsim_contrast")
        # r = albedo * (1 - c + 2 c t): the texture's mean grey 0.5 keeps the mean at albedo.
        gain = _math(
            tree,
            "MULTIPLY_ADD",
            grey.outputs["Val"],
            _math(tree, "MULTIPLY", contrast, 2.0),
            _math(tree, "SUBTRACT", 1.0, contrast),
        )
        reflectance = _math(tree, "MULTIPLY", gain, albedo)
        reflectance.node.use_clamp = True
    tree.links.new(reflectance, bsdf.inputs["Base Color"])  # float -> grey colour
    tree.links.new(_attribute(tree.nodes, "dotsim_roughness"), bsdf.inputs["Roughness"])
    tree.links.new(_attribute(tree.nodes, "dotsim_specular"), bsdf.inputs["Specular IOR Level"])
    return material


class MaterialCache:
    """One material per texture path (plus one untextured), least recently used dropped beyond
    `capacity` together with its image, so memory stays bounded over many scenes."""

    def __init__(self, capacity: int = 64):
        self.capacity = capacity
        self._materials: OrderedDict[str, bpy.types.Material] = OrderedDict()

    def get(self, texture_path: str | None) -> bpy.types.Material:
        key = texture_path or ""
        if key in self._materials:
            self._materials.move_to_end(key)
            return self._materials[key]
        image = None
        if texture_path:
            if not Path(texture_path).is_file():
                raise ValueError(f"texture {texture_path} does not exist")
            try:
                image = bpy.data.images.load(texture_path, check_existing=False)
            except RuntimeError as error:
                raise ValueError(f"texture {texture_path} cannot be read: {error}") from None
            image.colorspace_settings.name = "Non-Color"
        material = build_material(f"dotsim_{len(self._materials)}_{Path(key).stem or 'plain'}", image)
        self._materials[key] = material
        while len(self._materials) > self.capacity:
            self._remove(self._materials.popitem(last=False)[1])
        return material

    @staticmethod
    def _remove(material: bpy.types.Material) -> None:
        images = [node.image for node in material.node_tree.nodes if node.type == "TEX_IMAGE" and node.image]
        bpy.data.materials.remove(material)
        for image in images:
            bpy.data.images.remove(image)

    def clear(self) -> None:
        while self._materials:
            self._remove(self._materials.popitem()[1])
