"""The sensor rig: an IR camera, a dot projector beside it (and optionally a second IR camera).

Its modules, each one idea (docs/GEOMETRY.md):

- geometry: Intrinsics, Rig, and the conversions between depth, disparity and projector column
- presets: the preset rigs, rig files shipped beside it (presets/NAME.json)
"""
