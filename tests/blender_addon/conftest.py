"""Fixtures shared by the add-on's test modules."""

import pytest

from tests.blender_addon.generated_scene import generate_scene


@pytest.fixture(scope="module")
def dataset_scene(tmp_path_factory):
    """(dataset dir, scene meta, frames) of the reference scene as `dotsim generate` writes it."""
    return generate_scene(tmp_path_factory.mktemp("dataset") / "dataset")
