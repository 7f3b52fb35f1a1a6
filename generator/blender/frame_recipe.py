"""The frame recipe: which Cycles renders the frames of a scene take, which view-layer passes each
one switches on and what its compositor writes, decided from the SceneSpec alone (pure: the
standard library only, so Blender's own Python imports it too). SceneRenderer (render.py) carries a
recipe out; docs/RENDERING.md has the why and the measurements.

Colours separate the light (projector.py): R is the dot projector, G the flood rectangle (the
same spot light), B the world and the extra lights (the projector off); the Z pass is depth.

- A scene without extra lights: one render. The spot is then the only light Cycles samples, so it
  is picked at every shading point: R and G hold all its light, and its direct passes (diffuse
  direct x colour + glossy direct x colour) are the direct light, written as a second EXR.
- With extra lights and [render] direct_light = "separate" (the default): Cycles samples one light
  per shading point, so where it picks an extra light the spot's direct light is missing. The
  path-traced render keeps only the spot's indirect light in R and G; a second render without
  bounces and without the extra lights gives its direct light at every pixel, added to them.
- With extra lights and "shared": the one render above, whose direct passes then miss the spot
  where an extra light was sampled; the spot is declared SAMPLING_BOOST times brighter to Cycles.

Two things of a scene add to the first (path-traced) render of its recipe, and to nothing else, so a
scene without them renders as before, byte for byte:
- [render] labels or normals: the object index and normal passes, which Cycles writes from the first
  surface a camera ray hits and which change no sample, written by a File Output node to a data EXR.
- transparent objects: light seen through glass is transmission light, which Cycles keeps in passes
  of its own, so the light sums that make R and G (and the direct EXR) add the transmission passes.
- [lighting] ambient_ratio: the ambient (B) alone goes through OpenImageDenoise, guided by the denoising
  albedo and normal passes, before it is written. The post-render scales the ambient up to the ratio
  (often hundreds of times), and at a few samples the path-traced room is speckled with single bright
  pixels that would then set the exposure and read as dots; scaling the lamps instead scales their
  noise alike (docs/RENDERING.md "Denoised ambient" has the measurements). R and G, the dots, are
  never denoised.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from generator.scene_spec import SceneSpec

# The view layer's diffuse and glossy light passes (Blender's names after `use_pass_`).
LIGHT_PASSES = ("diffuse_indirect", "diffuse_color", "diffuse_direct",
                "glossy_indirect", "glossy_color", "glossy_direct",
                "transmission_indirect", "transmission_color", "transmission_direct")
# The view layer's data passes: the index of the first surface's object and its normal (world frame).
DATA_PASSES = ("object_index", "normal")

# Cycles samples one light per shading point, chosen by each light's energy; it cannot see that the
# spot's node tree carries the projector, the pass that must be clean at one sample. Where an extra
# point light is picked instead, that pixel gets no projector and no flood light at all ("pepper").
# Declaring the spot brighter (and dividing its node gains alike, projector.py: same output,
# unbiased) gives it more samples, at the ambient pass's expense (docs/RENDERING.md has the
# measurements). Only a recipe that takes the spot's light from one render with extra lights present
# needs it; with a direct render, or without extra lights, the ambient light gets the samples.
SAMPLING_BOOST = 3.0


@dataclass(frozen=True)
class Render:
    """One Cycles render of every frame of a scene, and the raw passes it gives.

    bounces: the spec's max_bounces (True) or none. extra_lights: the spec's extra lights on (True)
    or hidden. light_passes: the LIGHT_PASSES switched on (the combined image and Z always are).
    red_green: what the compositor makes R and G of the image: "all" (all light, as rendered) or
    "indirect" (diffuse indirect x diffuse colour + glossy indirect x glossy colour); None: no
    compositing, the image is the render as is. image: (channel, raw pass) pairs read from the
    image (R, G, B; A = Z). direct_file: (channel, raw pass) pairs that a File Output node writes to
    a second EXR from the direct light (diffuse direct x diffuse colour + glossy direct x glossy
    colour); () for none. A raw pass that two renders give is their sum. data_file: (channel, raw
    pass) pairs a File Output node writes to a data EXR from the object index (R) and the normal (G, B,
    A: x, y, z in Blender's world frame) passes; () for none. transmission: the light sums add the
    transmission passes (diffuse, glossy and transmission light x its colour). denoise_ambient: the
    image's B (the ambient) goes through OpenImageDenoise alone (the module docstring).
    """
    bounces: bool
    extra_lights: bool
    light_passes: frozenset[str]
    red_green: str | None
    image: tuple[tuple[str, str], ...]
    direct_file: tuple[tuple[str, str], ...] = ()
    data_file: tuple[tuple[str, str], ...] = ()
    transmission: bool = False
    denoise_ambient: bool = False

    @property
    def data_passes(self) -> frozenset[str]:
        """The DATA_PASSES the data EXR needs switched on."""
        return frozenset(("object_index" if name == "object_index" else "normal")
                         for _, name in self.data_file)


@dataclass(frozen=True)
class FrameRecipe:
    """The renders of a scene, in this order, each one through all its frames before the next (each
    switch between two makes Cycles sync the scene again), and the spot's sampling boost."""
    renders: tuple[Render, ...]
    sampling_boost: float

    @property
    def raw_passes(self) -> tuple[str, ...]:
        """The raw passes of each frame, in the order they are first written."""
        names = [name for render in self.renders
                 for _, name in render.image + render.direct_file + render.data_file]
        return tuple(dict.fromkeys(names))


_PASSES = (("R", "projector"), ("G", "flood"), ("B", "ambient"), ("A", "depth"))
_DIRECT = (("R", "projector_direct"), ("G", "flood_direct"))
# The data EXR: the object index (the object's place in the spec's objects + 1, 0 where no surface is
# hit) and the normal.
LABEL_PASSES = (("R", "object_index"),)
NORMAL_PASSES = (("G", "normal_x"), ("B", "normal_y"), ("A", "normal_z"))

# All light in R and G, the spot's direct light written apart: the one render of a frame.
ALL_LIGHT_RENDER = Render(
    bounces=True, extra_lights=True, red_green="all", image=_PASSES, direct_file=_DIRECT,
    light_passes=frozenset({"diffuse_direct", "diffuse_color", "glossy_direct", "glossy_color"}))
# The spot's indirect light in R and G: the path-traced render that a direct render completes.
INDIRECT_LIGHT_RENDER = Render(
    bounces=True, extra_lights=True, red_green="indirect", image=_PASSES,
    light_passes=frozenset({"diffuse_indirect", "diffuse_color", "glossy_indirect", "glossy_color"}))
# The spot alone without bounces (the world stays: it is blue and never light-sampled): its direct
# light at every pixel, added to the indirect light of R and G. Only the image is read, so no light
# pass is on (docs/RENDERING.md "Direct render settings").
DIRECT_LIGHT_RENDER = Render(
    bounces=False, extra_lights=False, red_green=None, light_passes=frozenset(),
    image=(("R", "projector_direct"), ("R", "projector"), ("G", "flood_direct"), ("G", "flood")))

# The colour camera's render ([render] rgb): the scene as the recipe's first render has it (bounces, extra
# lights), no light pass and no compositing: the image is Cycles' combined light, whose R, G, B the
# renderer reads (render.py; the spot and the light colours are set for visible light around it).
COLOUR_RENDER = Render(bounces=True, extra_lights=True, red_green=None, light_passes=frozenset(), image=())

# The raw passes of each frame of a dataset, which generator/post_render.py turns into the stored
# channels: those of the one render above (the two-render recipe gives the same, tested).
RAW_PASSES = FrameRecipe((ALL_LIGHT_RENDER,), 1.0).raw_passes

# The one-render way from before the spot's direct light had passes (no direct passes, pepper with
# extra lights), kept to compare against: bench.mask_fidelity's "old".
WITHOUT_DIRECT_LIGHT = FrameRecipe(
    (Render(bounces=True, extra_lights=True, red_green="all", image=_PASSES, light_passes=frozenset()),),
    SAMPLING_BOOST)


def frame_recipe(spec: SceneSpec) -> FrameRecipe:
    """How the frames of `spec` are rendered (the module docstring): by its extra lights and its
    render.direct_light (validated with the spec), its render.labels and render.normals, whether it
    has transparent objects, and whether its ambient is scaled to an ambient_ratio."""
    if not spec.lights:
        recipe = FrameRecipe((ALL_LIGHT_RENDER,), 1.0)
    else:
        recipe = {"separate": FrameRecipe((INDIRECT_LIGHT_RENDER, DIRECT_LIGHT_RENDER), 1.0),
                  "shared": FrameRecipe((ALL_LIGHT_RENDER,), SAMPLING_BOOST)}[spec.render.direct_light]
    first, *rest = recipe.renders
    data = (LABEL_PASSES if spec.render.labels else ()) + (NORMAL_PASSES if spec.render.normals else ())
    if data:
        first = replace(first, data_file=data)
    if any(obj.material.kind == "transparent" for obj in spec.objects):
        first = with_transmission(first)
    if spec.ambient_ratio is not None:
        first = replace(first, denoise_ambient=True)
    return replace(recipe, renders=(first, *rest))


def with_transmission(render: Render) -> Render:
    """`render` with the transmission passes in its light sums (and switched on beside the diffuse and
    glossy ones it has). The direct render needs none: it composites nothing."""
    passes = {name.replace("diffuse", "transmission") for name in render.light_passes if "diffuse" in name}
    return replace(render, transmission=True, light_passes=render.light_passes | passes)
