"""Builds a SceneSpec's content in bpy: camera, ambient (world and extra lights), objects.

It receives a typed SceneSpec (generator/scene_spec.py, validated when it was made) and dispatches
on the types of its meshes and lights, so nothing is looked up by string key here.

Everything that can outlive a scene is cached and reused: the six unit primitive meshes, asset
meshes by path (least recently used dropped beyond a cap), materials by texture path. Objects and
extra lights belong to one collection that is emptied at the start of every scene, so nothing
accumulates over many scenes in one process.
"""

from __future__ import annotations

import contextlib
import functools
from collections import OrderedDict
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

from dotsim.rig.geometry import Intrinsics
from generator.scene_spec import (
    PRIMITIVE_SHAPES,
    AssetMesh,
    CeilingLight,
    PointLight,
    PrimitiveMesh,
    SceneObject,
    SceneSpec,
)

from .geometry import (
    MeshData,
    blender_matrix_from_opencv_pose,
    camera_parameters,
    load_npz_mesh,
    primitive_mesh,
)
from .materials import MaterialCache, shadow_transmittance

# Ambient light is rendered in blue only (projector in red, flood in green); see projector.py.
AMBIENT_COLOUR = (0.0, 0.0, 1.0)


def mesh_from_data(name: str, data: MeshData) -> bpy.types.Mesh:
    """A Blender mesh from triangle arrays via foreach_set (no bpy.ops, no per-vertex Python)."""
    mesh = bpy.data.meshes.new(name)
    n_tris = len(data.triangles)
    mesh.vertices.add(len(data.vertices))
    mesh.vertices.foreach_set("co", data.vertices.ravel())
    mesh.loops.add(3 * n_tris)
    mesh.loops.foreach_set("vertex_index", data.triangles.ravel())
    mesh.polygons.add(n_tris)
    mesh.polygons.foreach_set("loop_start", np.arange(0, 3 * n_tris, 3, dtype=np.int32))
    mesh.polygons.foreach_set("use_smooth", data.smooth)
    mesh.uv_layers.new(name="UVMap").data.foreach_set("uv", data.corner_uvs.ravel())
    mesh.update(calc_edges=True)
    if data.normals is not None:
        mesh.normals_split_custom_set_from_vertices(data.normals.tolist())
    mesh.materials.append(None)  # one slot; each object links its own material to it
    return mesh


class MeshCache:
    """Unit primitives (kept for the process's life) and asset meshes by path (LRU, `capacity`)."""

    def __init__(self, capacity: int = 256):
        self.capacity = capacity
        self._primitives = {
            shape: mesh_from_data(f"dotsim_{shape}", primitive_mesh(shape)) for shape in PRIMITIVE_SHAPES
        }
        self._assets: OrderedDict[str, bpy.types.Mesh] = OrderedDict()

    def primitive(self, shape: str) -> bpy.types.Mesh:
        if shape not in self._primitives:
            raise ValueError(f"unknown primitive shape {shape!r}; allowed: {list(PRIMITIVE_SHAPES)}")
        return self._primitives[shape]

    def asset(self, path: str, in_use: set[str]) -> bpy.types.Mesh:
        """The mesh of asset `path`; drops least recently used meshes not in `in_use` over capacity."""
        if path in self._assets:
            self._assets.move_to_end(path)
            return self._assets[path]
        mesh = mesh_from_data(f"dotsim_asset_{Path(path).stem}", load_npz_mesh(path))
        self._assets[path] = mesh
        excess = max(0, len(self._assets) - self.capacity)
        for old in [key for key in self._assets if key not in in_use][:excess]:
            bpy.data.meshes.remove(self._assets.pop(old))
        return mesh

    def clear(self) -> None:
        for mesh in [*self._primitives.values(), *self._assets.values()]:
            bpy.data.meshes.remove(mesh)
        self._primitives.clear()
        self._assets.clear()


class SceneContent:
    """The camera, world and the per-scene collection of objects and extra lights."""

    def __init__(self, scene: bpy.types.Scene):
        self.scene = scene
        self.camera = bpy.data.objects.new("dotsim_camera", bpy.data.cameras.new("dotsim_camera"))
        scene.collection.objects.link(self.camera)
        scene.camera = self.camera
        self.camera.data.clip_start = 0.01
        self.camera.data.clip_end = 1.0e4
        self.world = bpy.data.worlds.new("dotsim_world")
        scene.world = self.world
        # A constant world is not worth sampling as a light: with sampling off, only rays that
        # escape see it and it never competes with the projector for light samples.
        self.world.cycles.sampling_method = "NONE"
        self.background = self.world.node_tree.nodes["Background"]
        self.collection = bpy.data.collections.new("dotsim_scene")
        scene.collection.children.link(self.collection)
        self.meshes = MeshCache()
        self.materials = MaterialCache()
        # The visible-light twins of the materials (the colour camera's render), a cache of their own:
        # they never push an infrared material out of `materials`.
        self.twins = MaterialCache()
        # (object, texture path or None, material kind) of the built scene's tinted surfaces
        self._tinted: list[tuple[bpy.types.Object, str | None, str]] = []
        self._world_strength = 0.0

    def set_camera(self, camera: Intrinsics) -> None:
        self.scene.render.resolution_x = camera.width
        self.scene.render.resolution_y = camera.height
        self.scene.render.resolution_percentage = 100
        for name, value in camera_parameters(camera.width, camera.height, camera.fx, camera.fy,
                                             camera.cx, camera.cy).items():
            setattr(self.camera.data, name, value)

    def set_camera_pose(self, world_from_camera: np.ndarray) -> None:
        self.camera.matrix_world = Matrix(blender_matrix_from_opencv_pose(world_from_camera).tolist())

    def clear(self) -> None:
        """Remove the previous scene's objects and extra lights (meshes and materials stay cached)."""
        objects = list(self.collection.objects)
        lights = [obj.data for obj in objects if obj.type == "LIGHT"]
        bpy.data.batch_remove(objects + lights)

    def build(self, spec: SceneSpec) -> None:
        """World, extra lights and objects of `spec`."""
        self.clear()
        self.materials.start_scene()
        self._tinted = []
        self._world_strength = spec.world_strength
        self.background.inputs["Color"].default_value = (*AMBIENT_COLOUR[:2], spec.world_strength, 1.0)
        self.background.inputs["Strength"].default_value = 1.0
        for k, light in enumerate(spec.lights):
            self.add_light(light, f"lights[{k}]")
        in_use = {obj.mesh.path for obj in spec.objects if isinstance(obj.mesh, AssetMesh)}
        for k, obj in enumerate(spec.objects):
            self._add_object(obj, f"objects[{k}]", in_use).pass_index = k + 1 if spec.render.labels else 0

    @functools.singledispatchmethod
    def add_light(self, light, where: str) -> None:
        """Add one extra light of the spec (one registered method per light type)."""
        raise TypeError(f"scene spec: {where} is a {type(light).__name__}, not a light type")

    @add_light.register(PointLight)
    def _(self, light: PointLight, where: str) -> None:
        data = bpy.data.lights.new(f"dotsim_{where}", "POINT")
        data.color = AMBIENT_COLOUR
        data.energy = light.power
        data.shadow_soft_size = light.radius
        obj = bpy.data.objects.new(f"dotsim_{where}", data)
        obj.location = light.location
        self.collection.objects.link(obj)

    @add_light.register(CeilingLight)
    def _(self, light: CeilingLight, where: str) -> None:
        data = bpy.data.lights.new(f"dotsim_{where}", "AREA")
        data.color = AMBIENT_COLOUR
        data.energy = light.power
        data.shape = "RECTANGLE"
        data.size, data.size_y = light.size
        obj = bpy.data.objects.new(f"dotsim_{where}", data)
        obj.location = light.location  # an area light faces its local -z: down, unrotated
        self.collection.objects.link(obj)

    @functools.singledispatchmethod
    def mesh(self, mesh, where: str, in_use: set[str]) -> tuple[bpy.types.Mesh, np.ndarray]:
        """(Blender mesh, size along the object's axes) of a spec mesh (one method per mesh type)."""
        raise TypeError(f"scene spec: {where} is a {type(mesh).__name__}, not a mesh type")

    @mesh.register(PrimitiveMesh)
    def _(self, mesh: PrimitiveMesh, where: str, in_use: set[str]) -> tuple[bpy.types.Mesh, np.ndarray]:
        return self.meshes.primitive(mesh.shape), np.array(mesh.size)

    @mesh.register(AssetMesh)
    def _(self, mesh: AssetMesh, where: str, in_use: set[str]) -> tuple[bpy.types.Mesh, np.ndarray]:
        try:
            return self.meshes.asset(mesh.path, in_use), np.ones(3)
        except ValueError as error:
            raise ValueError(f"scene spec: {where}: {error}") from None

    def _add_object(self, spec_object: SceneObject, where: str, in_use: set[str]) -> bpy.types.Object:
        mesh, size = self.mesh(spec_object.mesh, f"{where}.mesh", in_use)
        obj = bpy.data.objects.new(spec_object.name, mesh)
        obj.location = spec_object.location
        obj.rotation_euler = spec_object.rotation_euler
        # The unit primitive times its size, then the object's own scale (both along object axes).
        obj.scale = (size * np.array(spec_object.scale)).tolist()
        material = spec_object.material
        obj["dotsim_albedo"] = material.albedo
        obj["dotsim_roughness"] = material.roughness
        obj["dotsim_specular"] = material.specular
        if material.texture is not None:
            obj["dotsim_tex_scale"] = material.texture.scale
            obj["dotsim_contrast"] = material.texture.contrast
        if material.tint is not None:
            obj["dotsim_tint"] = list(material.tint)
        if material.kind == "transparent":
            obj["dotsim_ior"] = material.ior
            obj["dotsim_shadow_transmittance"] = shadow_transmittance(material.albedo, material.ior)
        try:
            blender_material = self.materials.get(None if material.texture is None else material.texture.path,
                                                  material.kind)
        except ValueError as error:
            raise ValueError(f"scene spec: {where}.material.texture: {error}") from None
        self.collection.objects.link(obj)
        obj.material_slots[0].link = "OBJECT"
        obj.material_slots[0].material = blender_material
        if material.tint is not None:
            texture = None if material.texture is None else material.texture.path
            self._tinted.append((obj, texture, material.kind))
        return obj

    @contextlib.contextmanager
    def visible_light(self):
        """The built scene as the colour camera sees it while inside: tinted surfaces in their visible-
        light materials, the world and the extra lights white (their light is in blue alone for the IR
        passes, AMBIENT_COLOUR); as before after. The projector is the renderer's to switch off."""
        lights = [obj.data for obj in self.collection.objects if obj.type == "LIGHT"]
        infrared = [obj.material_slots[0].material for obj, _, _ in self._tinted]  # as the IR passes saw
        self.twins.start_scene()
        for obj, texture, kind in self._tinted:
            obj.material_slots[0].material = self.twins.get(texture, kind, tinted=True)
        for light in lights:
            light.color = (1.0, 1.0, 1.0)
        self.background.inputs["Color"].default_value = (*(self._world_strength,) * 3, 1.0)
        try:
            yield
        finally:
            for (obj, _, _), material in zip(self._tinted, infrared, strict=True):
                obj.material_slots[0].material = material
            for light in lights:
                light.color = AMBIENT_COLOUR
            self.background.inputs["Color"].default_value = (*AMBIENT_COLOUR[:2], self._world_strength, 1.0)

    def release(self) -> None:
        """Remove everything this object created (used when the renderer closes)."""
        self.clear()
        self.meshes.clear()
        self.materials.clear()
        self.twins.clear()
