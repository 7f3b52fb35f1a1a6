"""The Blender stage: SceneSpec -> raw passes (projector, flood, ambient, depth) with Cycles.

The only generator package that imports bpy. What run_in_blender.py needs imports nothing else but
numpy, the standard library and generator.scene_spec (with dotsim.rig.geometry), so it also runs in
Blender's own Python (demo_scenes, for tests and benchmarks, also uses the generator config).

Modules (bpy only in render, scene_builder, projector, materials, bare_pass):
  render          SceneRenderer: builds a SceneSpec, renders one frame per pose as its recipe says
  frame_recipe    pure: which renders, passes and compositor outputs a spec's frames take
                  (docs/RENDERING.md)
  scene_builder   camera, world, extra lights and objects in bpy; dispatches on mesh and light types
  projector       the dot projector and the flood rectangle as one Cycles spot light
  materials       grey infrared materials (albedo, roughness, specular, texture)
  geometry        pure numpy: OpenCV <-> Blender frames, Blender camera settings, primitive meshes
  pattern_filter  texture-space anti-aliasing of the pattern, 16-bit PNG writer (numpy + zlib)
  exr             reader for the one EXR layout the renderer writes
  run_in_blender  entry script: SceneSpec JSON files -> raw .npz (`blender --python`, or bpy module)
  demo_scenes     hand-built spec dicts with known geometry, for render tests and benchmarks
  bare_pass       the cheapest full-size pass (camera rays only): the floor bench.second_pass measures
"""
