"""Builds a SceneSpec's content in bpy: camera, ambient (world and extra lights), objects.

Everything that can outlive a scene is cached and reused: the six unit primitive meshes, asset
meshes by path (least recently used dropped beyond a cap), materials by texture path. Objects and
extra lights belong to one collection that is emptied at the start of every scene, so nothing
accumulates over many scenes in one process.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from pathlib import Path

import bpy
import numpy as np
from mathutils import Matrix

from .geometry import (
    PRIMITIVE_SHAPES,
    MeshData,
    blender_matrix_from_opencv_pose,
    camera_parameters,
    load_npz_mesh,
    primitive_mesh,
)
from .materials import MaterialCache

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


def spec_field(d: dict, key: str, where: str):
    """d[key]; ValueError naming `where`.key when d is not a dict or lacks the key."""
    if not isinstance(d, dict) or key not in d:
        raise ValueError(f"scene spec: {where}.{key} is missing")
    return d[key]


def spec_number(d: dict, key: str, where: str, minimum: float | None = None) -> float:
    """d[key] as a float; ValueError naming `where`.key unless it is a finite number >= minimum."""
    value = spec_field(d, key, where)
    if isinstance(value, bool) or not isinstance(value, int | float) or not math.isfinite(value):
        raise ValueError(f"scene spec: {where}.{key} must be a finite number, got {value!r}")
    if minimum is not None and value < minimum:
        raise ValueError(f"scene spec: {where}.{key} must be >= {minimum}, got {value!r}")
    return float(value)


def spec_vector(d: dict, key: str, where: str) -> tuple[float, float, float]:
    """d[key] as 3 floats; ValueError naming `where`.key otherwise."""
    value = spec_field(d, key, where)
    if not isinstance(value, list | tuple) or len(value) != 3:
        raise ValueError(f"scene spec: {where}.{key} must be 3 numbers, got {value!r}")
    return tuple(spec_number({key: v}, key, f"{where}[{k}]") for k, v in enumerate(value))  # type: ignore[return-value]


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

    def set_camera(self, intrinsics: tuple[int, int, float, float, float, float]) -> None:
        width, height = intrinsics[:2]
        self.scene.render.resolution_x = width
        self.scene.render.resolution_y = height
        self.scene.render.resolution_percentage = 100
        for name, value in camera_parameters(*intrinsics).items():
            setattr(self.camera.data, name, value)

    def set_camera_pose(self, world_from_camera: np.ndarray) -> None:
        self.camera.matrix_world = Matrix(blender_matrix_from_opencv_pose(world_from_camera).tolist())

    def clear(self) -> None:
        """Remove the previous scene's objects and extra lights (meshes and materials stay cached)."""
        objects = list(self.collection.objects)
        lights = [obj.data for obj in objects if obj.type == "LIGHT"]
        bpy.data.batch_remove(objects + lights)

    def build(self, spec: dict) -> None:
        """World, extra lights and objects of `spec` (a SceneSpec dict, generator/scene_spec.py)."""
        self.clear()
        strength = spec_number(spec_field(spec, "world", "spec"), "strength", "world", minimum=0.0)
        self.background.inputs["Color"].default_value = (*AMBIENT_COLOUR[:2], strength, 1.0)
        self.background.inputs["Strength"].default_value = 1.0
        for k, light_spec in enumerate(spec_field(spec, "lights", "spec")):
            self._add_light(light_spec, f"lights[{k}]")
        objects = spec_field(spec, "objects", "spec")
        meshes = [o.get("mesh") for o in objects if isinstance(o, dict)]
        in_use = {m.get("path") for m in meshes if isinstance(m, dict) and m.get("kind") == "asset"}
        for k, object_spec in enumerate(objects):
            self._add_object(object_spec, f"objects[{k}]", in_use)

    def _add_light(self, light_spec: dict, where: str) -> None:
        kind = spec_field(light_spec, "type", where)
        if kind != "POINT":
            raise ValueError(f"scene spec: {where}.type must be 'POINT', got {kind!r}")
        light = bpy.data.lights.new(f"dotsim_{where}", "POINT")
        light.color = AMBIENT_COLOUR
        light.energy = spec_number(light_spec, "power", where, minimum=0.0)
        light.shadow_soft_size = spec_number(light_spec, "radius", where, minimum=0.0)
        obj = bpy.data.objects.new(f"dotsim_{where}", light)
        obj.location = spec_vector(light_spec, "location", where)
        self.collection.objects.link(obj)

    def _add_object(self, object_spec: dict, where: str, in_use: set[str]) -> None:
        mesh_spec = spec_field(object_spec, "mesh", where)
        kind = spec_field(mesh_spec, "kind", f"{where}.mesh")
        if kind == "primitive":
            mesh = self.meshes.primitive(spec_field(mesh_spec, "shape", f"{where}.mesh"))
            size = np.array(spec_vector(mesh_spec, "size", f"{where}.mesh"))
        elif kind == "asset":
            path = spec_field(mesh_spec, "path", f"{where}.mesh")
            try:
                mesh = self.meshes.asset(path, in_use)
            except ValueError as error:
                raise ValueError(f"scene spec: {where}.mesh: {error}") from None
            size = np.ones(3)
        else:
            raise ValueError(f"scene spec: {where}.mesh.kind must be 'primitive' or 'asset', got {kind!r}")
        obj = bpy.data.objects.new(str(object_spec.get("name", where)), mesh)
        obj.location = spec_vector(object_spec, "location", where)
        obj.rotation_euler = spec_vector(object_spec, "rotation_euler", where)
        # The unit primitive times its size, then the object's own scale (both along object axes).
        obj.scale = (size * np.array(spec_vector(object_spec, "scale", where))).tolist()
        material_spec = spec_field(object_spec, "material", where)
        texture = material_spec.get("texture") if isinstance(material_spec, dict) else None
        mwhere = f"{where}.material"
        obj["dotsim_albedo"] = spec_number(material_spec, "albedo", mwhere, minimum=0.0)
        obj["dotsim_roughness"] = spec_number(material_spec, "roughness", mwhere, minimum=0.0)
        obj["dotsim_specular"] = spec_number(material_spec, "specular", mwhere, minimum=0.0)
        if texture is not None:
            obj["dotsim_tex_scale"] = spec_number(texture, "scale", f"{mwhere}.texture")
            obj["dotsim_contrast"] = spec_number(texture, "contrast", f"{mwhere}.texture", minimum=0.0)
            texture_path = spec_field(texture, "path", f"{mwhere}.texture")
        else:
            texture_path = None
        try:
            material = self.materials.get(texture_path)
        except ValueError as error:
            raise ValueError(f"scene spec: {mwhere}.texture: {error}") from None
        self.collection.objects.link(obj)
        obj.material_slots[0].link = "OBJECT"
        obj.material_slots[0].material = material

    def release(self) -> None:
        """Remove everything this object created (used when the renderer closes)."""
        self.clear()
        self.meshes.clear()
        self.materials.clear()
