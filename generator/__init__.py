"""The generator stage: config -> sampled scenes -> Cycles renders -> shards of training data.

Modules (one idea each; only generator/blender/ imports bpy):
  config         TOML config -> validated Config (schema, defaults, errors; docs/CONFIG.md)
  scene_spec     the typed SceneSpec, checked on construction (docs/SCENE_SPEC.md); its [render] and
                 [masks] records are the config's tables, its [sensor] the config's at the render
                 scale (dotsim.sensor.settings); numpy + stdlib + dotsim only
  sample_scene   pure, seeded sampling of a SceneSpec from (config, scene index, base seed, split),
                 and every random stream of its frames (frame_streams: sensor noise, laser speckle)
  resources      the files scenes refer to: pattern, built-in textures, asset cache
  blender/       SceneRenderer: SceneSpec -> raw passes (projector, flood, ambient, depth and the
                 projector's and flood's direct light)
  post_render    raw passes + SceneSpec -> stored channels (IR through the sensor model of
                 dotsim.sensor, ambient, flood, depth, masks, GT)
  render_worker  what every render worker does: render_scenes(job, indices) samples, renders,
                 post-renders and writes scenes in this process
  run_request    RunRequest: one run (config, out, split, seed, scenes, start, executor), checked once,
                 carrying the rig and the pattern; the Executor protocol (prepare, render, seal) that
                 every engine implements; RunSummary, what a run did
  driver         run(request): the request's executor through prepare, render and seal; generate()
                 for python callers
  engines/       the engines that render a run (local_pool: processes here, the default; ray_cluster;
                 slurm) and the steps on the dataset folder they share (steps: prepare, render what
                 is missing, seal)
  cli            `dotsim generate`, and the engine modules it offers (ENGINES)
"""
