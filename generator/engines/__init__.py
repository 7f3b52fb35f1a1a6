"""The engines that render a run's scenes, and the steps they share (the Executor protocol:
generator/run_request.py).

  steps        what every engine does on the dataset folder: prepare_run (checks, writer lock,
               pattern, run record, textures), render_missing (resume, progress, summary),
               seal_written; seal_run for what several range runs wrote
  local_pool   LocalExecutor: spawned render processes on this machine (`--workers`, the default)
  ray_cluster  RayExecutor: the scenes as Ray tasks (`--ray`; docs/SCALE.md)
  slurm        SlurmExecutor: a job array and its sealing job (`--slurm`; docs/SCALE.md)
  one_node_slurm  a one-node Slurm cluster of its own on this machine, to try the Slurm engine here

Imports go one way: an engine imports steps, generator/run_request.py and generator/render_worker.py
(what each of its workers runs); nothing below imports an engine.
"""
