"""The generator stage: config -> sampled scenes -> Cycles renders -> shards of training data.

Modules (one idea each; only generator/blender/ imports bpy):
  config       TOML config -> validated Config (schema, defaults, errors; docs/CONFIG.md)
  scene_spec   pure, seeded sampling of a SceneSpec from (config, scene index, base seed, split)
  blender/     SceneRenderer: SceneSpec dict -> raw passes (projector, flood, ambient, depth and the
               projector's and flood's direct light)
  sensor_model pure IR sensor model: exposure, bloom, blur, shot/read noise, quantisation
  post_render  raw passes -> stored channels (IR, ambient, flood, depth, masks, ground truth)
  pipeline     workers, resume, failure logs, shards (generate())
  cli          `dotsim generate`
"""
