"""capture: real sensor frames into the dotsim dataset format, and dot patterns from wall captures.

Hardware-independent: it reads frames a sensor SDK has already saved (PNG / EXR), so no SDK is
imported here. docs/CAPTURE.md says how to record them. Modules: frames (read and pair image
files), dots (projector signal, visibility, local dot normalisation), import_frames (`dotsim
capture import`), wall_pattern (`dotsim capture pattern`), cli.
"""
