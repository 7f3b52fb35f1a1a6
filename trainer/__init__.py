"""The trainer stage: dotsim shards -> the GigaDepth network -> checkpoints, evaluation, inference.

Modules (docs/TRAINER.md):
  config    training config: one TOML file with [model], [data] and [train] tables
  data      training samples from shards: IR crops with the GT projector column at half resolution
  model     the GigaDepth branching network: conv backbone + classification tree over the column
  train     the training loop: tree losses, checkpoints with exact resume, TensorBoard logging
  checkpoint  loading a trained network and predicting disparity with it (eval and infer use it)
  metrics   the metrics: small pure functions (outliers, o(t), ratios), one per metric
  evaluate  outlier rates o(t) of the network and of StereoSGBM on the same frames, error images
  sgbm      the baseline: OpenCV StereoSGBM against the pattern as seen from infinity
  infer     inference on rendered or captured frames: disparity/depth EXR, colour PNG, PLY cloud
  cli       `dotsim train`, `dotsim eval`, `dotsim infer`
"""
