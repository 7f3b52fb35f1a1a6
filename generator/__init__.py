"""The generator stage: config -> sampled scenes -> Cycles renders -> shards of training data.

Modules (one idea each; only generator/blender/ imports bpy):
  config         TOML config -> validated Config (schema, defaults, errors; docs/CONFIG.md)
  scene_spec     the typed SceneSpec, checked on construction (docs/SCENE_SPEC.md); its [render],
                 [sensor], [masks] records are the config's tables; numpy + stdlib + dotsim only
  sample_scene   pure, seeded sampling of a SceneSpec from (config, scene index, base seed, split)
  resources      the files scenes refer to: pattern, built-in textures, asset cache
  blender/       SceneRenderer: SceneSpec -> raw passes (projector, flood, ambient, depth and the
                 projector's and flood's direct light)
  sensor_model   pure IR sensor model: exposure, bloom, blur, shot/read noise, quantisation
  post_render    raw passes + SceneSpec -> stored channels (IR, ambient, flood, depth, masks, GT)
  render_scenes  render_scenes(job, indices): sample, render, post-render, write; the worker pool
  pipeline       generate(): checks, prepare_run, resume, progress, sealing; seal_run for clusters
  ray_cluster    RayBackend: generate()'s scenes as Ray tasks (`--ray`; docs/SCALE.md)
  slurm          sbatch scripts for a job array and its sealing job (`--slurm`; docs/SCALE.md)
  cli            `dotsim generate`
"""
