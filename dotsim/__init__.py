"""dotsim: synthetic structured-light depth data with headless Blender, and the GigaDepth network.

This package is the pure core every stage shares (numpy only; torch imported lazily where
needed): the sensor rig geometry, dot patterns, masks, LCN, the dataset format and the config
schema engine (config_schema) that the generator and trainer configs are declared with.
"""

__version__ = "0.1.0"
