"""SceneRenderer: SceneSpec (generator/scene_spec.py) -> one frame of raw passes per pose, with
Cycles: one path-tracing render per frame for all light and, in scenes with extra lights, one
direct-light render of the projector alone (docs/RENDERING.md).

How the passes are separated (several lights in one render are noisy, docs/RENDERING.md): materials
are grey, so colour channels never mix. One spot light emits the pattern in red and the flood
rectangle in green (projector.py); the world and the extra lights are pure blue. So one render
gives projector = R, flood = G, ambient = B, and the Z pass gives planar depth. The compositor
packs (R, G, B, Z) into one RGBA float EXR in a private temp folder, read back with a tiny numpy
reader (exr.py). Clamping, denoising, adaptive sampling and view transforms are off, because each
of them would mix channels or change values.

Direct light: Cycles samples one light per shading point, so where an extra light was picked at the
surface the camera sees, the projector's direct light is missing ("pepper"). The path-tracing
render therefore keeps only the projector's and flood's indirect light (the diffuse and glossy
indirect passes times their colour passes, composited), and a second render with no bounces and
the extra lights hidden gives their direct light at every pixel (the world stays: it is blue and
not light-sampled): the dots the sensor sees are direct + indirect, and the visibility mask uses
the direct light alone. All path-traced frames of a scene render first, then all direct ones,
because each switch between the two makes Cycles sync the scene again. A scene without extra
lights needs no second render: the spot is then the only light Cycles samples, so it is picked at
every point: the path-traced render then keeps all light in R and G, and its own direct passes
(diffuse and glossy direct times their colour passes, written by a File Output node) are the
direct render's image (equal to 5e-7, measured). With render.direct_light "shared" a scene with
extra lights is rendered that way too, and keeps the pepper: one render, faster.

Reuse: one bpy scene for the life of the renderer; between the frames of a scene only the camera and
projector poses change and Cycles keeps its scene (persistent data); between scenes objects are
replaced and meshes, materials and the pattern image are cached, so memory stays flat.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import sys
import tempfile
import warnings
from dataclasses import astuple
from pathlib import Path

import bpy
import numpy as np

from generator.scene_spec import RenderSettings, SceneSpec

from .exr import read_exr
from .geometry import NO_HIT_DEPTH, blender_matrix_from_opencv_pose, projector_pose
from .pattern_filter import footprint_width
from .projector import SAMPLING_BOOST, ProjectorLight
from .scene_builder import SceneContent

GPU_BACKENDS = ("OPTIX", "CUDA", "HIP", "ONEAPI", "METAL")


@contextlib.contextmanager
def _quiet_stdout():
    """Silence Cycles' per-frame status lines (they would break a progress bar); errors still show
    on stderr."""
    sys.stdout.flush()
    saved = os.dup(1)
    devnull = os.open(os.devnull, os.O_WRONLY)
    os.dup2(devnull, 1)
    try:
        yield
    finally:
        os.dup2(saved, 1)
        os.close(saved)
        os.close(devnull)


def _configure_render(scene: bpy.types.Scene) -> None:
    """Settings that never change: Cycles, raw linear output, no processing that mixes channels."""
    scene.render.engine = "CYCLES"
    cycles = scene.cycles
    cycles.use_denoising = False  # factory default is on; it would smear dots and mix channels
    cycles.use_adaptive_sampling = False
    cycles.sample_clamp_direct = 0.0  # clamping scales a sample's RGB together: channels would mix
    cycles.sample_clamp_indirect = 0.0
    cycles.caustics_reflective = False
    cycles.caustics_refractive = False
    cycles.sampling_pattern = "TABULATED_SOBOL"  # explicit: measured better than blue noise at 1 spp
    cycles.use_animated_seed = False
    # Cycles' box filter spreads samples uniformly over exactly one pixel (its width setting has no
    # effect, measured): the pixel's area, like a sensor pixel and the oracle's supersampling. The
    # default 1.5 px Blackman-Harris would blur the dots.
    cycles.pixel_filter_type = "BOX"
    cycles.film_exposure = 1.0
    scene.render.film_transparent = False
    # Persistent data keeps Cycles' scene (BVH, images) between the frames of a scene; without it
    # every frame rebuilds the BVH (1000 objects cost 2.1x 100 instead of ~1.4x). setup() starts
    # a fresh Cycles scene for each SceneSpec, because Cycles missed changed settings (its seed)
    # when it kept the old one.
    scene.render.use_persistent_data = True
    view = scene.view_settings
    view.view_transform = "Standard"
    view.look = "None"
    view.exposure = 0.0
    view.gamma = 1.0
    scene.render.use_compositing = True
    scene.render.use_sequencer = False
    layer = scene.view_layers[0]
    layer.use_pass_combined = True
    layer.use_pass_z = True
    settings = scene.render.image_settings
    settings.file_format = "OPEN_EXR"
    settings.color_mode = "RGBA"
    settings.color_depth = "32"
    settings.exr_codec = "NONE"
    scene.render.use_file_extension = False


def _light_of(tree: bpy.types.NodeTree, layers: bpy.types.Node, kind: str) -> bpy.types.NodeSocket:
    """Diffuse `kind` x diffuse colour + glossy `kind` x glossy colour (kind "Direct" or "Indirect"):
    how Cycles itself sums those passes into the combined image."""
    terms = []
    for light, colour in ((f"Diffuse {kind}", "Diffuse Color"), (f"Glossy {kind}", "Glossy Color")):
        product = tree.nodes.new("ShaderNodeVectorMath")
        product.operation = "MULTIPLY"
        tree.links.new(layers.outputs[light], product.inputs[0])
        tree.links.new(layers.outputs[colour], product.inputs[1])
        terms.append(product)
    total = tree.nodes.new("ShaderNodeVectorMath")
    total.operation = "ADD"
    for k, term in enumerate(terms):
        tree.links.new(term.outputs[0], total.inputs[k])
    return total.outputs[0]


def _build_compositor(indirect: bool, direct_file: Path | None) -> bpy.types.NodeTree:
    """Render Layers -> RGBA image with alpha = Z (depth), written as the render's output file.
    indirect: R and G of that image hold only indirect light. direct_file: a File Output node also
    writes the direct light (R, G; B is the world's) as an RGB EXR there."""
    tree = bpy.data.node_groups.new("dotsim_compositor", "CompositorNodeTree")
    tree.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
    layers = tree.nodes.new("CompositorNodeRLayers")
    combine = tree.nodes.new("CompositorNodeCombineColor")
    output = tree.nodes.new("NodeGroupOutput")
    combined = tree.nodes.new("CompositorNodeSeparateColor")
    tree.links.new(layers.outputs["Image"], combined.inputs[0])
    red_green = combined
    if indirect:
        red_green = tree.nodes.new("CompositorNodeSeparateColor")
        tree.links.new(_light_of(tree, layers, "Indirect"), red_green.inputs[0])
    if direct_file is not None:
        direct = tree.nodes.new("CompositorNodeOutputFile")
        direct.name = "direct"
        direct.directory = str(direct_file.parent)
        direct.file_name = direct_file.name  # Blender appends the item's name, which is empty
        settings = direct.format
        settings.media_type = "IMAGE"
        settings.file_format = "OPEN_EXR"
        settings.color_mode = "RGB"
        settings.color_depth = "32"
        settings.exr_codec = "NONE"
        direct.file_output_items.new("RGBA", "")
        tree.links.new(_light_of(tree, layers, "Direct"), direct.inputs[0])
    tree.links.new(red_green.outputs[0], combine.inputs[0])
    tree.links.new(red_green.outputs[1], combine.inputs[1])
    tree.links.new(combined.outputs[2], combine.inputs[2])
    tree.links.new(layers.outputs["Depth"], combine.inputs[3])
    tree.links.new(combine.outputs[0], output.inputs[0])
    return tree


def select_device(scene: bpy.types.Scene, device: str) -> str:
    """Use the GPU when asked and one is present (first of OPTIX, CUDA, HIP, oneAPI, Metal that has
    devices), else the CPU with a warning. Returns the backend used ("CPU" or the GPU backend)."""
    if device not in ("CPU", "GPU"):
        raise ValueError(f"scene spec: render.device must be 'CPU' or 'GPU', got {device!r}")
    if device == "GPU":
        preferences = bpy.context.preferences.addons["cycles"].preferences
        for backend in GPU_BACKENDS:
            try:
                preferences.compute_device_type = backend
            except TypeError:  # backend not compiled into this Blender
                continue
            preferences.refresh_devices()
            gpus = [d for d in preferences.devices if d.type == backend]
            if gpus:
                for d in preferences.devices:
                    d.use = d.type == backend
                scene.cycles.device = "GPU"
                return backend
        warnings.warn(
            "render.device is 'GPU' but Cycles found no GPU device; rendering on the CPU",
            RuntimeWarning,
            stacklevel=2,
        )
    scene.cycles.device = "CPU"
    return "CPU"


class SceneRenderer:
    """Renders SceneSpecs (docs/SCENE_SPEC.md) into raw passes with Cycles.

    One instance owns the bpy scene of the process (it starts from factory settings). Call
    render(spec) for each scene; close() removes the temp folder. Use one per process.
    """

    def __init__(self, reset: bool = True, direct_render: bool = True):
        """direct_render=False renders each frame in one path-tracing render, the projector's direct
        light included (the way before the direct render existed, kept to compare against: its
        frames lack projector_direct and flood_direct, and have pepper with extra lights)."""
        if reset:
            bpy.ops.wm.read_factory_settings(use_empty=True)
        self.scene = bpy.context.scene
        _configure_render(self.scene)
        shm = Path("/dev/shm")
        self._tmp = Path(tempfile.mkdtemp(prefix="dotsim_render_", dir=shm if shm.is_dir() else None))
        self.scene.render.filepath = str(self._tmp / "frame.exr")
        self._direct_file = self._tmp / "direct.exr"
        self._compositor: tuple[tuple[bool, bool], bpy.types.NodeTree] | None = None  # (key, tree)
        self._separate_direct = False  # set by setup()
        self.content = SceneContent(self.scene)
        self.projector = ProjectorLight(self.scene.collection)
        self.direct_render = direct_render  # applied by setup(); may change between scenes
        self.device = "CPU"

    def _use_compositor(self, indirect: bool, direct: bool, rebuild: bool = False) -> None:
        """Passes and compositor (_build_compositor): R and G as indirect light only (`indirect`), the
        direct light written apart (`direct`). Passes are on only where used: each costs render
        time. Built anew when these change, or with `rebuild` after the passes were switched off
        and on (the direct render does): Blender leaves links from passes switched off invalid
        after they come back, and an invalid link reads as 0 (the indirect light was lost that way)."""
        key = (indirect, direct)
        if self._compositor is not None and self._compositor[0] == key and not rebuild:
            return
        self._set_light_passes(indirect, direct)
        tree = _build_compositor(indirect, self._direct_file if direct else None)
        self.scene.compositing_node_group = tree
        if self._compositor is not None:
            bpy.data.node_groups.remove(self._compositor[1])
        self._compositor = (key, tree)

    def _set_light_passes(self, indirect: bool, direct: bool) -> None:
        """The diffuse and glossy light passes: indirect and colour for `indirect`, direct and colour
        for `direct` (none when both are False, as in the direct render, whose image is all it needs)."""
        layer = self.scene.view_layers[0]
        for light in ("diffuse", "glossy"):
            for part, on in (("indirect", indirect), ("color", indirect or direct), ("direct", direct)):
                setattr(layer, f"use_pass_{light}_{part}", on)

    def close(self) -> None:
        self.content.release()
        shutil.rmtree(self._tmp, ignore_errors=True)

    def __enter__(self) -> SceneRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _apply_render_settings(self, render: RenderSettings) -> None:
        cycles = self.scene.cycles
        cycles.samples = render.samples
        cycles.seed = render.seed
        cycles.max_bounces = render.max_bounces
        cycles.diffuse_bounces = render.max_bounces
        cycles.glossy_bounces = render.max_bounces
        cycles.transmission_bounces = render.max_bounces
        cycles.volume_bounces = 0
        self._bounces = render.max_bounces
        self.scene.render.threads_mode = "FIXED" if render.threads else "AUTO"
        if render.threads:
            self.scene.render.threads = render.threads
        self.device = select_device(self.scene, render.device)

    def setup(self, spec: SceneSpec) -> tuple[np.ndarray, ...]:
        """Build `spec` in the bpy scene (everything except the frame poses); returns the 4x4
        world_from_camera poses to render."""
        # Checked first: a bad spec should fail before anything is built.
        if not Path(spec.pattern.path).is_file():
            raise ValueError(f"scene spec: pattern.path {spec.pattern.path} does not exist")
        self._apply_render_settings(spec.render)
        # The spot's direct light: from a render of its own where extra lights compete with it for
        # Cycles' one light sample per point ("separate"), else from the path-traced render's own
        # passes: exact without extra lights (the spot is then picked at every point), missing
        # where an extra light was picked with "shared" (docs/RENDERING.md).
        shared, extra_lights = spec.render.direct_light == "shared", bool(spec.lights)
        self._separate_direct = self.direct_render and extra_lights and not shared
        # Only where the path-traced render's direct light is used with extra lights does the spot
        # need extra samples (projector.py SAMPLING_BOOST); otherwise the ambient light gets them.
        boosted = not self.direct_render or (shared and extra_lights)
        self.projector.sampling_boost = SAMPLING_BOOST if boosted else 1.0
        rig = spec.rig
        self.content.set_camera(rig.camera)
        self.projector.set_intrinsics(astuple(rig.projector))
        self._rig = rig
        width = footprint_width(rig.projector.fx, rig.camera.fx, self.scene.cycles.samples)
        pattern = spec.pattern
        self.projector.set_pattern(pattern.path, pattern.sha256 or pattern.path, width, self._tmp)
        self.projector.set_powers(spec.projector_power, spec.flood_power)
        self.content.build(spec)
        # R and G are indirect light only where the direct render adds the rest; otherwise all
        # light, with the direct light written apart (the combined image needs no compositing).
        self._use_compositor(indirect=self._separate_direct,
                             direct=self.direct_render and not self._separate_direct)
        self.refresh()
        return spec.poses

    def refresh(self) -> None:
        """Make the next render sync the whole scene into Cycles. setup() calls it; call it after
        changing anything else than the poses between renders. Switching persistent data off frees
        Cycles' kept scene (Cycles missed changed settings, e.g. the seed, when it kept it)."""
        self.scene.render.use_persistent_data = False
        self.scene.render.use_persistent_data = True

    def place_rig(self, world_from_camera: np.ndarray) -> None:
        """Move the camera to `world_from_camera` (4x4, OpenCV axes) and the projector with it, as
        the built spec's rig says."""
        self.content.set_camera_pose(world_from_camera)
        self.projector.set_pose(blender_matrix_from_opencv_pose(
            projector_pose(world_from_camera, self._rig.R, self._rig.t)))

    def _render_channels(self) -> dict[str, np.ndarray]:
        output = Path(self.scene.render.filepath)
        output.unlink(missing_ok=True)  # never read a previous frame if Blender fails to write
        with _quiet_stdout():
            bpy.ops.render.render(write_still=True)
        if not output.is_file():
            raise RuntimeError(f"Cycles wrote no image to {output}")
        return read_exr(output)

    def _path_traced(self, world_from_camera: np.ndarray) -> dict[str, np.ndarray]:
        """One path-traced frame (projector and flood: all their light, or their indirect light where
        a direct render follows), and the direct light where the compositor writes it."""
        self.place_rig(world_from_camera)
        self._direct_file.unlink(missing_ok=True)
        channels = self._render_channels()
        depth = channels["A"].copy()
        depth[depth >= NO_HIT_DEPTH] = np.inf
        frame = {
            "projector": channels["R"].copy(),
            "flood": channels["G"].copy(),
            "ambient": channels["B"].copy(),
            "depth": depth,
        }
        _, direct_written = self._compositor[0]  # (indirect, direct) of _use_compositor
        if direct_written:
            if not self._direct_file.is_file():
                raise RuntimeError(f"Cycles' compositor wrote no direct light to {self._direct_file}")
            direct = read_exr(self._direct_file)
            frame["projector_direct"] = direct["R"].copy()
            frame["flood_direct"] = direct["G"].copy()
        return frame

    @contextlib.contextmanager
    def _projector_direct_only(self):
        """The scene lit by the spot alone, without bounces: a render gives the spot's direct light
        in R and G (the world is blue, so it may stay); no compositing, the image is the result, so
        the light passes are off too (measured: 9-18% less CPU per direct render at 608 x 448, the
        same pixels; docs/RENDERING.md "Direct render settings")."""
        lights = [obj for obj in self.content.collection.objects if obj.type == "LIGHT"]
        self.scene.cycles.max_bounces = 0
        for obj in lights:
            obj.hide_render = True
        self.scene.render.use_compositing = False
        self._set_light_passes(indirect=False, direct=False)
        try:
            yield
        finally:
            self.scene.cycles.max_bounces = self._bounces
            for obj in lights:
                obj.hide_render = False
            self.scene.render.use_compositing = True
            self._use_compositor(*self._compositor[0], rebuild=True)

    def render_frame(self, world_from_camera: np.ndarray) -> dict[str, np.ndarray]:
        """Render the built scene from one rig pose: {projector, flood, ambient, depth,
        projector_direct, flood_direct} float32 (H, W); depth is planar (metres), inf where nothing
        is hit; projector and flood hold direct + indirect light, the *_direct passes the spot's
        direct light alone (absent with direct_render=False)."""
        return self.render_poses([world_from_camera])[0]

    def render_poses(self, poses: list[np.ndarray]) -> list[dict[str, np.ndarray]]:
        """render_frame for each pose: the path-traced renders first, then the direct ones (each
        switch between the two makes Cycles sync the scene again, so it happens once); none
        without extra lights or with render.direct_light "shared" (setup)."""
        frames = [self._path_traced(pose) for pose in poses]
        if not self._separate_direct:
            return frames
        with self._projector_direct_only():
            for frame, pose in zip(frames, poses, strict=True):
                self.place_rig(pose)
                direct = self._render_channels()
                frame["projector_direct"] = direct["R"].copy()
                frame["flood_direct"] = direct["G"].copy()
                frame["projector"] += frame["projector_direct"]  # the path-traced R, G: indirect only
                frame["flood"] += frame["flood_direct"]
        return frames

    def render(self, spec: SceneSpec) -> list[dict[str, np.ndarray]]:
        """All frames of `spec`: a list (one per pose) of render_frame's passes."""
        return self.render_poses(self.setup(spec))
