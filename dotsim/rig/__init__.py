"""The sensor rig: an IR camera, a dot projector beside it (and optionally a second IR camera), and
everything that makes, reads, checks and shows one (docs/GEOMETRY.md). Its modules, each one idea:

- geometry: Intrinsics, Rig, the conversions between depth, disparity and projector column, and the
  one ground-truth rule (is_ground_truth: a finite depth in (0, max_depth])
- presets: the preset rigs, rig files shipped beside it (presets/NAME.json)
- stereo: the rig's rectified stereo pair (its second IR camera)
- calibration_formats: calibration files as people have them (dotsim JSON, OpenCV, ROS, Kalibr),
  read into their parts
- files: rigs from rig files and [rig] settings, and the checks a rig from outside must pass
- config: a generator config's [rig] table (RigConfig), and reading it alone from a config file
- options: `--rig SPEC` and `--camera-file FILE` as every command reads them
- report: a resolved rig as people read it (`dotsim rig show`)
"""
