"""SceneRenderer: SceneSpec (generator/scene_spec.py) -> one frame of raw passes per pose, with
Cycles, as the spec's frame recipe (frame_recipe.py) says: one path-tracing render per frame for
all light and, in scenes with extra lights, one direct-light render of the projector alone
(docs/RENDERING.md).

How the passes are separated (several lights in one render are noisy, docs/RENDERING.md): materials
are grey, so colour channels never mix. One spot light emits the pattern in red and the flood
rectangle in green (projector.py); the world and the extra lights are pure blue. So one render
gives projector = R, flood = G, ambient = B, and the Z pass gives planar depth. The compositor
packs (R, G, B, Z) into one RGBA float EXR in a private temp folder, read back with a tiny numpy
reader (exr.py). Clamping, denoising, adaptive sampling and view transforms are off, because each
of them would mix channels or change values; only a spec with an ambient_ratio has its ambient (B) alone
denoised in the compositor (frame_recipe.py).

Direct light: which renders a frame takes, which passes they switch on and what the compositor
writes is the frame recipe's to say (frame_recipe.py, pure); the renderer sets the bpy scene up for
each render of it in turn, renders every frame through it and adds up the raw passes it names.

Cameras: the spec says which of the rig's cameras each frame is rendered from (SceneSpec.cameras):
its own camera, and for a stereo pair its second one. One Blender camera is placed at each in turn,
the projector staying on the rig; the raw passes of a camera other than the rig's own are named with
its suffix ("projector_right").

Colour camera ([render] rgb; docs/RENDERING.md "Colour camera"): after the recipe's renders, every pose
is rendered once more from the rig's colour camera (its own intrinsics and pose on the rig) under
visible light: the projector's spot (which carries both the dots and the flood rectangle) hidden from
the render, the world and the extra lights white, tinted surfaces in their visible-light materials
(SceneContent.visible_light); no compositing, the image as Cycles gives it (its R, G, B).

Reuse: one bpy scene for the life of the renderer; between the frames of a scene only the camera and
projector poses change and Cycles keeps its scene (persistent data); between scenes objects are
replaced and meshes, materials and the pattern image are cached, so memory stays flat.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import shutil
import sys
import tempfile
import warnings
from dataclasses import astuple
from pathlib import Path

import bpy
import numpy as np

from generator.scene_spec import CameraView, SceneRenderSettings, SceneSpec

from .exr import read_exr
from .frame_recipe import COLOUR_RENDER, DATA_PASSES, LIGHT_PASSES, FrameRecipe, Render, frame_recipe
from .geometry import NO_HIT_DEPTH, blender_matrix_from_opencv_pose, camera_frame_normals, projector_pose
from .pattern_filter import footprint_width
from .projector import ProjectorLight
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


def _light_of(tree: bpy.types.NodeTree, layers: bpy.types.Node, kind: str,
              transmission: bool = False) -> bpy.types.NodeSocket:
    """Diffuse `kind` x diffuse colour + glossy `kind` x glossy colour (kind "Direct" or "Indirect"),
    and with `transmission` + transmission `kind` x transmission colour: how Cycles itself sums those
    passes into the combined image."""
    parts = ("Diffuse", "Glossy") + (("Transmission",) if transmission else ())
    total = None
    for part in parts:
        product = tree.nodes.new("ShaderNodeVectorMath")
        product.operation = "MULTIPLY"
        tree.links.new(layers.outputs[f"{part} {kind}"], product.inputs[0])
        tree.links.new(layers.outputs[f"{part} Color"], product.inputs[1])
        if total is None:
            total = product
            continue
        added = tree.nodes.new("ShaderNodeVectorMath")
        added.operation = "ADD"
        tree.links.new(total.outputs[0], added.inputs[0])
        tree.links.new(product.outputs[0], added.inputs[1])
        total = added
    return total.outputs[0]


def _file_output(tree: bpy.types.NodeTree, path: Path, name: str, colour_mode: str) -> bpy.types.Node:
    """A File Output node writing one uncompressed float EXR at `path` from its one input."""
    node = tree.nodes.new("CompositorNodeOutputFile")
    node.name = name
    node.directory = str(path.parent)
    node.file_name = path.name  # Blender appends the item's name, which is empty
    settings = node.format
    settings.media_type = "IMAGE"
    settings.file_format = "OPEN_EXR"
    settings.color_mode = colour_mode
    settings.color_depth = "32"
    settings.exr_codec = "NONE"
    node.file_output_items.new("RGBA", "")
    return node


def _data_image(tree: bpy.types.NodeTree, layers: bpy.types.Node, data: tuple[tuple[str, str], ...]
                ) -> bpy.types.NodeSocket:
    """RGBA of the data passes `data` asks for: the object index in R, the normal's x, y, z in G, B, A."""
    combine = tree.nodes.new("CompositorNodeCombineColor")
    names = {name for _, name in data}
    if "object_index" in names:
        tree.links.new(layers.outputs["Object Index"], combine.inputs[0])
    if "normal_x" in names:
        normal = tree.nodes.new("ShaderNodeSeparateXYZ")
        tree.links.new(layers.outputs["Normal"], normal.inputs[0])
        for k in range(3):
            tree.links.new(normal.outputs[k], combine.inputs[1 + k])
    return combine.outputs[0]


def _denoised(tree: bpy.types.NodeTree, layers: bpy.types.Node, channel: bpy.types.NodeSocket
              ) -> bpy.types.NodeSocket:
    """`channel` through OpenImageDenoise on its own (grey: the denoiser sees no other channel's light),
    guided by the denoising albedo and normal passes of the first surface."""
    grey = tree.nodes.new("CompositorNodeCombineColor")
    for k in range(3):
        tree.links.new(channel, grey.inputs[k])
    denoise = tree.nodes.new("CompositorNodeDenoise")
    tree.links.new(grey.outputs[0], denoise.inputs["Image"])
    tree.links.new(layers.outputs["Denoising Albedo"], denoise.inputs["Albedo"])
    tree.links.new(layers.outputs["Denoising Normal"], denoise.inputs["Normal"])
    back = tree.nodes.new("CompositorNodeSeparateColor")
    tree.links.new(denoise.outputs[0], back.inputs[0])
    return back.outputs[0]


def _build_compositor(render: Render, direct_file: Path, data_file: Path) -> bpy.types.NodeTree:
    """Render Layers -> RGBA image with alpha = Z (depth), written as the render's output file.
    With render.red_green "indirect", R and G of that image hold only indirect light. With
    render.direct_file a File Output node also writes the direct light (R, G; B is the world's) as an
    RGB EXR at `direct_file`, with render.data_file another the data passes (_data_image) at
    `data_file`. With render.denoise_ambient, B (the ambient) is denoised on its own (_denoised)."""
    tree = bpy.data.node_groups.new("dotsim_compositor", "CompositorNodeTree")
    tree.interface.new_socket("Image", in_out="OUTPUT", socket_type="NodeSocketColor")
    layers = tree.nodes.new("CompositorNodeRLayers")
    combine = tree.nodes.new("CompositorNodeCombineColor")
    output = tree.nodes.new("NodeGroupOutput")
    combined = tree.nodes.new("CompositorNodeSeparateColor")
    tree.links.new(layers.outputs["Image"], combined.inputs[0])
    red_green = combined
    if render.red_green == "indirect":
        red_green = tree.nodes.new("CompositorNodeSeparateColor")
        tree.links.new(_light_of(tree, layers, "Indirect", render.transmission), red_green.inputs[0])
    if render.direct_file:
        direct = _file_output(tree, direct_file, "direct", "RGB")
        tree.links.new(_light_of(tree, layers, "Direct", render.transmission), direct.inputs[0])
    if render.data_file:
        data = _file_output(tree, data_file, "data", "RGBA")
        tree.links.new(_data_image(tree, layers, render.data_file), data.inputs[0])
    tree.links.new(red_green.outputs[0], combine.inputs[0])
    tree.links.new(red_green.outputs[1], combine.inputs[1])
    ambient = combined.outputs[2]
    if render.denoise_ambient:
        ambient = _denoised(tree, layers, ambient)
    tree.links.new(ambient, combine.inputs[2])
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

    def __init__(self, reset: bool = True):
        if reset:
            bpy.ops.wm.read_factory_settings(use_empty=True)
        self.scene = bpy.context.scene
        _configure_render(self.scene)
        shm = Path("/dev/shm")
        self._tmp = Path(tempfile.mkdtemp(prefix="dotsim_render_", dir=shm if shm.is_dir() else None))
        self.scene.render.filepath = str(self._tmp / "frame.exr")
        self._direct_file = self._tmp / "direct.exr"
        self._data_file = self._tmp / "data.exr"
        self._tree: bpy.types.NodeTree | None = None  # the compositor
        # The render whose passes and compositor the bpy scene holds; None after passes were off.
        self._composited: Render | None = None
        self.recipe: FrameRecipe | None = None  # the built spec's, set by setup()
        self.cameras: tuple[CameraView, ...] = ()  # the built spec's, set by setup()
        self.colour_camera = None  # the built spec's colour camera (render.rgb) or None, set by setup()
        self._colour_samples = 0  # its render's samples (0: the spec's), set by setup()
        self._intrinsics = None  # of the Blender camera now
        self.content = SceneContent(self.scene)
        self.projector = ProjectorLight(self.scene.collection)
        self.device = "CPU"

    def _use_compositor(self, render: Render) -> None:
        """Passes and compositor (_build_compositor) for `render`. Passes are on only where used: each
        costs render time. Built anew unless the scene holds them for `render` already, also after
        the passes were switched off (the direct render does): Blender leaves links from passes
        switched off invalid after they come back, and an invalid link reads as 0 (the indirect
        light was lost that way)."""
        if self._composited == render:
            return
        self._set_light_passes(render)
        tree = _build_compositor(render, self._direct_file, self._data_file)
        self.scene.compositing_node_group = tree
        if self._tree is not None:
            bpy.data.node_groups.remove(self._tree)
        self._tree, self._composited = tree, render

    def _set_light_passes(self, render: Render) -> None:
        """Switch the LIGHT_PASSES and DATA_PASSES `render` uses on and the others off, and the
        denoising data passes (albedo, normal) on only where it denoises its ambient."""
        layer = self.scene.view_layers[0]
        for name in LIGHT_PASSES:
            setattr(layer, f"use_pass_{name}", name in render.light_passes)
        for name in DATA_PASSES:
            setattr(layer, f"use_pass_{name}", name in render.data_passes)
        layer.cycles.denoising_store_passes = render.denoise_ambient

    @contextlib.contextmanager
    def _set_for(self, render: Render):
        """The bpy scene as `render` needs it while inside: bounces, extra lights, passes and
        compositor; as before after."""
        before = self._composited
        hidden = [] if render.extra_lights else [
            obj for obj in self.content.collection.objects if obj.type == "LIGHT"]
        if not render.bounces:
            self.scene.cycles.max_bounces = 0
        for obj in hidden:
            obj.hide_render = True
        if render.red_green is None:
            self.scene.render.use_compositing = False
            self._set_light_passes(render)
            self._composited = None
        else:
            self._use_compositor(render)
        try:
            yield
        finally:
            if not render.bounces:
                self.scene.cycles.max_bounces = self._bounces
            for obj in hidden:
                obj.hide_render = False
            if render.red_green is None:
                self.scene.render.use_compositing = True
            if before is not None:
                self._use_compositor(before)

    def close(self) -> None:
        self.content.release()
        shutil.rmtree(self._tmp, ignore_errors=True)

    def __enter__(self) -> SceneRenderer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _apply_render_settings(self, render: SceneRenderSettings) -> None:
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

    def setup(self, spec: SceneSpec, recipe: FrameRecipe | None = None) -> tuple[np.ndarray, ...]:
        """Build `spec` in the bpy scene (everything except the frame poses), to be rendered as
        `recipe` says (frame_recipe(spec) unless given); returns the 4x4 world_from_camera poses to
        render."""
        # Checked first: a bad spec should fail before anything is built.
        if not Path(spec.pattern.path).is_file():
            raise ValueError(f"scene spec: pattern.path {spec.pattern.path} does not exist")
        recipe = frame_recipe(spec) if recipe is None else recipe
        self._apply_render_settings(spec.render)
        self.projector.sampling_boost = recipe.sampling_boost
        rig = spec.rig
        self.cameras = spec.cameras
        self.colour_camera = spec.colour_camera
        self._colour_samples = spec.render.rgb_samples
        self._intrinsics = self.cameras[0].intrinsics
        self.content.set_camera(self._intrinsics)
        self.projector.set_intrinsics(astuple(rig.projector))
        self._rig = rig
        width = footprint_width(rig.projector.fx, rig.camera.fx, self.scene.cycles.samples)
        pattern = spec.pattern
        self.projector.set_pattern(pattern.path, pattern.sha256 or pattern.path, width, self._tmp)
        self.projector.set_powers(spec.projector_power, spec.flood_power)
        self.content.build(spec)
        self._use_compositor(recipe.renders[0])
        self.recipe = recipe
        self.refresh()
        return spec.poses

    def refresh(self) -> None:
        """Make the next render sync the whole scene into Cycles. setup() calls it; call it after
        changing anything else than the poses between renders. Switching persistent data off frees
        Cycles' kept scene (Cycles missed changed settings, e.g. the seed, when it kept it)."""
        self.scene.render.use_persistent_data = False
        self.scene.render.use_persistent_data = True

    def place_rig(self, world_from_rig: np.ndarray, camera: CameraView | None = None) -> None:
        """Put the rig at `world_from_rig` (4x4, OpenCV axes: its own camera's pose): the projector as
        the built spec's rig says, and the Blender camera at `camera` of its cameras (default the
        rig's own)."""
        camera = self.cameras[0] if camera is None else camera
        if camera.intrinsics != self._intrinsics:
            self._intrinsics = camera.intrinsics
            self.content.set_camera(camera.intrinsics)
        self.content.set_camera_pose(camera.pose(world_from_rig))
        self.projector.set_pose(blender_matrix_from_opencv_pose(
            projector_pose(world_from_rig, self._rig.R, self._rig.t)))

    def _render_channels(self) -> dict[str, np.ndarray]:
        output = Path(self.scene.render.filepath)
        output.unlink(missing_ok=True)  # never read a previous frame if Blender fails to write
        with _quiet_stdout():
            bpy.ops.render.render(write_still=True)
        if not output.is_file():
            raise RuntimeError(f"Cycles wrote no image to {output}")
        channels = read_exr(output)
        _return_freed_memory()  # the render's buffers: a scene's poses would stack them otherwise
        return channels

    def _render_through(self, render: Render, poses: list[np.ndarray] | tuple[np.ndarray, ...],
                        frames: list[dict[str, np.ndarray]]) -> None:
        """Render every pose from each camera through `render` and add the raw passes it gives to its
        frame."""
        with self._set_for(render):
            for frame, pose in zip(frames, poses, strict=True):
                for camera in self.cameras:
                    self.place_rig(pose, camera)
                    self._direct_file.unlink(missing_ok=True)
                    self._data_file.unlink(missing_ok=True)
                    _add_passes(frame, self._render_channels(), render.image, camera.suffix)
                    if render.direct_file:
                        direct = _read_written(self._direct_file, "direct light")
                        _add_passes(frame, direct, render.direct_file, camera.suffix)
                    if render.data_file:
                        data = _read_written(self._data_file, "object index and normal passes")
                        if "G" in {channel for channel, _ in render.data_file}:
                            data["G"], data["B"], data["A"] = camera_frame_normals(
                                data["G"], data["B"], data["A"], camera.pose(pose))
                        _add_passes(frame, data, render.data_file, camera.suffix)

    def _render_colour(self, poses, frames: list[dict[str, np.ndarray]]) -> None:
        """Render every pose from the colour camera under visible light (the module docstring) and add
        its image to the frame as the raw pass "rgb", (h, w, 3) float32 linear radiance."""
        camera = self.colour_camera
        projector_hidden = self.projector.object.hide_render
        samples = self.scene.cycles.samples
        self.scene.cycles.samples = self._colour_samples or samples
        self._intrinsics = camera.intrinsics  # place_rig sets the IR camera's again
        self.content.set_camera(camera.intrinsics)
        self.projector.object.hide_render = True  # its dots and its flood rectangle: both infrared
        try:
            with self._set_for(COLOUR_RENDER), self.content.visible_light():
                self.refresh()  # materials, lights and the world changed: Cycles syncs the scene anew
                for frame, pose in zip(frames, poses, strict=True):
                    self.content.set_camera_pose(camera.pose(pose))
                    image = self._render_channels()
                    frame["rgb"] = np.stack([image["R"], image["G"], image["B"]], axis=-1)
        finally:
            self.projector.object.hide_render = projector_hidden
            self.scene.cycles.samples = samples
            self.refresh()

    def render_frame(self, world_from_camera: np.ndarray) -> dict[str, np.ndarray]:
        """Render the built scene from one rig pose: {projector, flood, ambient, depth,
        projector_direct, flood_direct} float32 (H, W); depth is planar (metres), inf where nothing
        is hit; projector and flood hold direct + indirect light, the *_direct passes the spot's
        direct light alone (the recipe's raw_passes: frame_recipe.WITHOUT_DIRECT_LIGHT has none); with
        render.labels object_index (the first surface's object's place in spec.objects + 1, 0 where
        none is hit), with render.normals normal_x, normal_y, normal_z (its unit normal in the camera's
        OpenCV frame, nan where none is hit); the same of each further camera of the spec, named with its
        suffix (CameraView.suffix); with render.rgb "rgb", the colour camera's image (its own (h, w, 3),
        linear radiance of visible light, the projector off)."""
        return self.render_poses([world_from_camera])[0]

    def render_poses(self, poses: list[np.ndarray]) -> list[dict[str, np.ndarray]]:
        """render_frame for each pose: every pose through the recipe's first render, then through
        the next (each switch between two makes Cycles sync the scene again, so it happens once)."""
        frames: list[dict[str, np.ndarray]] = [{} for _ in poses]
        for render in self.recipe.renders:
            self._render_through(render, poses, frames)
        if self.colour_camera is not None:
            self._render_colour(poses, frames)
        for frame in frames:
            for camera in self.cameras:
                depth = frame["depth" + camera.suffix]
                depth[depth >= NO_HIT_DEPTH] = np.inf
        return frames

    def render(self, spec: SceneSpec, recipe: FrameRecipe | None = None) -> list[dict[str, np.ndarray]]:
        """All frames of `spec`, rendered as `recipe` says (frame_recipe(spec) unless given): a list
        (one per pose) of render_frame's passes. Cycles' kept scene is freed once the last pose is
        rendered (the next setup syncs the whole scene again in any case), so the worker
        post-renders the frames with that memory given back (bench.generate_cost)."""
        frames = self.render_poses(self.setup(spec, recipe))
        self.scene.render.use_persistent_data = False  # setup() switches it on again (refresh)
        _return_freed_memory()
        return frames


def _read_written(path: Path, what: str) -> dict[str, np.ndarray]:
    """The channels of an EXR the compositor's File Output node wrote; RuntimeError when it wrote none."""
    if not path.is_file():
        raise RuntimeError(f"Cycles' compositor wrote no {what} to {path}")
    return read_exr(path)


def _return_freed_memory() -> None:
    """Give the memory the process freed back to the system (glibc's malloc_trim; nothing
    elsewhere). glibc keeps freed memory in the process for reuse, and the worker's next
    allocations come partly from elsewhere (the post-render threads' own arenas), so without this
    a worker's peak grows with every render of a scene (bench.generate_cost measures it)."""
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):
        pass


def _add_passes(frame: dict[str, np.ndarray], channels: dict[str, np.ndarray],
                passes: tuple[tuple[str, str], ...], suffix: str) -> None:
    """Add each (channel, raw pass) of `passes` to the frame, the pass named with the camera's
    `suffix`: a copy of the channel, or its sum with what an earlier render gave."""
    for channel, name in passes:
        name += suffix
        if name in frame:
            frame[name] += channels[channel]
        else:
            frame[name] = channels[channel].copy()
