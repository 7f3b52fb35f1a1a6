"""Fixtures of the Cycles render tests (test_blender_render.py, test_blender_stereo.py)."""

import pytest

from dotsim.patterns import generate_dot_pattern


@pytest.fixture(scope="module")
def renderer():
    """One SceneRenderer serves a whole module, as one worker serves many scenes (so reusing the bpy
    scene is checked to leak nothing from one scene into the next)."""
    pytest.importorskip("bpy")
    from generator.blender.render import SceneRenderer

    with SceneRenderer() as instance:
        yield instance


@pytest.fixture(scope="module")
def pattern(request, tmp_path_factory):
    """(DotPattern, the path of its PNG) at the projector size of the module's RIG: dense, small dots."""
    rig = request.module.RIG
    dots = generate_dot_pattern(rig.projector.width, rig.projector.height, density=0.04, min_spacing=2.0,
                                dot_sigma=0.7, seed=3)
    path = tmp_path_factory.mktemp("pattern") / "pattern.png"
    dots.save_png(path)
    return dots, str(path)
