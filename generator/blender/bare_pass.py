"""The least a full-size Cycles pass can cost: the floor under any second render per frame
(bench.second_pass, docs/RENDERING.md "Why the 10% budget is out of reach")."""

from __future__ import annotations

import contextlib

import bpy


@contextlib.contextmanager
def bare_pass(renderer, percentage: int = 100):
    """The renderer's built scene, rendered as camera rays only while inside: every object shaded
    by one emission material, no light, no bounce, no compositor, at `percentage` of the size."""
    scene = renderer.scene
    layer = scene.view_layers[0]
    material = bpy.data.materials.new("bare_pass_emission")
    nodes = material.node_tree.nodes
    nodes.clear()
    emission = nodes.new("ShaderNodeEmission")
    material.node_tree.links.new(emission.outputs[0], nodes.new("ShaderNodeOutputMaterial").inputs[0])
    lights = [obj for obj in scene.objects if obj.type == "LIGHT" and not obj.hide_render]
    bounces = scene.cycles.max_bounces
    layer.material_override = material
    for obj in lights:
        obj.hide_render = True
    scene.cycles.max_bounces = 0
    scene.render.use_compositing = False
    scene.render.resolution_percentage = percentage
    try:
        yield
    finally:
        scene.render.resolution_percentage = 100
        scene.render.use_compositing = True
        scene.cycles.max_bounces = bounces
        for obj in lights:
            obj.hide_render = False
        layer.material_override = None
        bpy.data.materials.remove(material)
