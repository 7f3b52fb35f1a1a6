"""Grey infrared materials for Cycles.

Infrared reflectance is one number per surface point, so every material is grey: base colour
(r, r, r) with r = albedo * (1 - contrast + 2 contrast t) clamped to [0, 1], t the texture's grey
value (luminance of a Non-Color image, sampled at object UV * scale), or r = albedo without a
texture. Grey materials never move light between colour channels, which the renderer relies on to
carry projector, flood and ambient light in R, G and B of one render.

Per-object values (albedo, roughness, specular, texture scale and contrast) live in object custom
properties read by Attribute nodes, so one material per texture image serves every object and
scene: few node trees to build, nothing to grow between scenes.

The colour camera's render ([render] rgb, docs/RENDERING.md "Colour camera") swaps an opaque surface's
material for its visible-light twin (build_material with `tinted`): the same grey reflectance times the
object's tint (dotsim_tint, an RGB custom property), since the textures are grey IR reflectance and a
surface's visible colour is drawn apart (generator.sample_scene). Glass and metal stay grey.

Transparent and metal objects (docs/CONFIG.md "Materials") have one material each, grey too: glass
(Cycles' Glass BSDF: Fresnel reflection and refraction by the object's index of refraction, its
albedo the transmittance) and metal (a fully metallic Principled BSDF, its albedo the reflectance at
normal incidence). A point light cannot shine through glass in a path tracer (a delta light behind a
delta refraction is a caustic no path samples), so glass lets shadow rays through unbent, dimmed by
its transmittance and the Fresnel loss of two surfaces at normal incidence: the projector's dots land
on what lies behind it where they would without the small sideways shift of refraction (none through
a plate at normal incidence, about t (1 - 1/n) times the angle for a plate t thick).
"""

from __future__ import annotations

from collections import OrderedDict
from pathlib import Path

import bpy

# Object custom-property names read by the shared materials.
PROPERTIES = ("dotsim_albedo", "dotsim_roughness", "dotsim_specular", "dotsim_tex_scale", "dotsim_contrast",
              "dotsim_ior", "dotsim_shadow_transmittance", "dotsim_tint")


def shadow_transmittance(transmittance: float, ior: float) -> float:
    """The share of a shadow ray's light a transparent object lets through: its transmittance times
    the Fresnel transmission of two surfaces at normal incidence, (1 - R0)^2 with R0 = ((n - 1) /
    (n + 1))^2.

    >>> round(shadow_transmittance(1.0, 1.5), 4)
    0.9216
    """
    reflectance = ((ior - 1.0) / (ior + 1.0)) ** 2
    return transmittance * (1.0 - reflectance) ** 2


def _attribute(nodes, name: str, output: str = "Fac"):
    node = nodes.new("ShaderNodeAttribute")
    node.attribute_type = "OBJECT"
    node.attribute_name = name
    return node.outputs[output]


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


def build_material(name: str, image: bpy.types.Image | None, tinted: bool = False) -> bpy.types.Material:
    """A Principled BSDF material reading the per-object PROPERTIES; `image` (Non-Color) is the
    reflectance texture or None for a uniform albedo; `tinted`: the visible-light twin, its base colour
    the grey reflectance times the object's dotsim_tint."""
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
    if tinted:
        colour = tree.nodes.new("ShaderNodeVectorMath")
        colour.operation = "MULTIPLY"
        tree.links.new(reflectance, colour.inputs[0])  # float -> (r, r, r)
        tree.links.new(_attribute(tree.nodes, "dotsim_tint", "Vector"), colour.inputs[1])
        reflectance = colour.outputs["Vector"]
    tree.links.new(reflectance, bsdf.inputs["Base Color"])  # float -> grey colour
    tree.links.new(_attribute(tree.nodes, "dotsim_roughness"), bsdf.inputs["Roughness"])
    tree.links.new(_attribute(tree.nodes, "dotsim_specular"), bsdf.inputs["Specular IOR Level"])
    return material


def build_glass_material(name: str) -> bpy.types.Material:
    """Glass for camera rays (the object's dotsim_ior, its albedo the transmittance), transparent for
    shadow rays (dotsim_shadow_transmittance): the module docstring says why."""
    material = bpy.data.materials.new(name)
    tree = material.node_tree
    tree.nodes.clear()
    glass = tree.nodes.new("ShaderNodeBsdfGlass")
    glass.distribution = "GGX"
    glass.inputs["Roughness"].default_value = 0.0  # a smooth surface: Cycles samples it as a delta
    tree.links.new(_attribute(tree.nodes, "dotsim_albedo"), glass.inputs["Color"])
    tree.links.new(_attribute(tree.nodes, "dotsim_ior"), glass.inputs["IOR"])
    through = tree.nodes.new("ShaderNodeBsdfTransparent")
    tree.links.new(_attribute(tree.nodes, "dotsim_shadow_transmittance"), through.inputs["Color"])
    mix = tree.nodes.new("ShaderNodeMixShader")
    tree.links.new(tree.nodes.new("ShaderNodeLightPath").outputs["Is Shadow Ray"], mix.inputs["Fac"])
    tree.links.new(glass.outputs["BSDF"], mix.inputs[1])
    tree.links.new(through.outputs["BSDF"], mix.inputs[2])
    output = tree.nodes.new("ShaderNodeOutputMaterial")
    tree.links.new(mix.outputs["Shader"], output.inputs["Surface"])
    return material


def build_metal_material(name: str) -> bpy.types.Material:
    """A fully metallic Principled BSDF: the object's albedo its reflectance at normal incidence, its
    roughness its own."""
    material = bpy.data.materials.new(name)
    tree = material.node_tree
    tree.nodes.clear()
    bsdf = tree.nodes.new("ShaderNodeBsdfPrincipled")
    bsdf.inputs["Metallic"].default_value = 1.0
    tree.links.new(_attribute(tree.nodes, "dotsim_albedo"), bsdf.inputs["Base Color"])
    tree.links.new(_attribute(tree.nodes, "dotsim_roughness"), bsdf.inputs["Roughness"])
    output = tree.nodes.new("ShaderNodeOutputMaterial")
    tree.links.new(bsdf.outputs["BSDF"], output.inputs["Surface"])
    return material


# The materials of the kinds that are not grey opaque surfaces (generator.scene_spec.MATERIAL_KINDS).
SPECIAL_MATERIALS = {"transparent": build_glass_material, "metal": build_metal_material}


class MaterialCache:
    """One material per texture path (plus one untextured), least recently used dropped beyond
    `capacity` together with its image, so memory stays bounded over many scenes. A material the
    scene being built uses is never dropped (the scene may use more than `capacity`): removing it
    from Blender would leave its objects in Blender's default material."""

    def __init__(self, capacity: int = 64):
        self.capacity = capacity
        self._materials: OrderedDict[str, bpy.types.Material] = OrderedDict()
        self._in_use: set[str] = set()  # keys the scene being built has asked for

    def start_scene(self) -> None:
        """A new scene is built: the materials the previous one used may be dropped from now on."""
        self._in_use = set()

    def get(self, texture_path: str | None, kind: str = "opaque", tinted: bool = False) -> bpy.types.Material:
        """The material of a surface of `kind` (a SPECIAL_MATERIALS one has no texture), textured by
        `texture_path` or not; `tinted`: an opaque surface's visible-light twin (build_material)."""
        if kind in SPECIAL_MATERIALS:
            key = f"<{kind}>"
            self._in_use.add(key)
            if key not in self._materials:
                self._materials[key] = SPECIAL_MATERIALS[kind](f"dotsim_{kind}")
            self._materials.move_to_end(key)
            return self._materials[key]
        key = (texture_path or "") + ("<tinted>" if tinted else "")
        self._in_use.add(key)
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
        stem = Path(texture_path or "").stem or "plain"
        material = build_material(f"dotsim_{len(self._materials)}_{stem}{'_tinted' if tinted else ''}", image,
                                  tinted)
        self._materials[key] = material
        excess = max(0, len(self._materials) - self.capacity)
        for old in [key for key in self._materials if key not in self._in_use][:excess]:
            self._remove(self._materials.pop(old))
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
