"""dotsim's version, written only here: pyproject.toml reads it (setuptools' dynamic version), and
the code that records it (scene.json, the asset cache, exports) imports it from this module."""

__version__ = "0.1.0"
