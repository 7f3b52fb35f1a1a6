"""The test suite, laid out like the repository: tests/generator/ tests generator/, tests/dotsim/dataset/
tests dotsim/dataset/, and so on. Packages, so that shared helpers import as `tests.output_folders`."""
