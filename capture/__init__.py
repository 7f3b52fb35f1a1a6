"""capture: real sensor frames into the dotsim dataset format, dot patterns from wall captures, and the
simulated sensor fitted to a recording.

Hardware-independent: it reads frames a sensor SDK has already saved (PNG / EXR), so no SDK is
imported here. docs/CAPTURE.md says how to record them. Modules: frames (read and pair image
files), dots (projector signal, visibility, local dot normalisation), import_frames (`dotsim
capture import`), wall_pattern (`dotsim capture pattern`), static_recording (a still scene's frames,
scene by scene), photon_transfer (noise and levels), dot_statistics (dot size, brightness spread,
SNR, density), sensor_fit (`dotsim capture fit-sensor`: the statistics and the [sensor] values),
fit_report (its text, table and drawing), cli.
"""
