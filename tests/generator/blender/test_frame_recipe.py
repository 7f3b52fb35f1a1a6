"""frame_recipe (generator/blender/frame_recipe.py) without Blender: which renders, passes and
compositor outputs a spec's frames take, checked against a small model of what Cycles puts in a
render's image and passes (the light each raw pass ends up holding)."""

from __future__ import annotations

import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import pytest

from dotsim.rig.presets import get_preset
from generator.blender import demo_scenes as ds
from generator.blender.frame_recipe import (
    ALL_LIGHT_RENDER,
    DIRECT_LIGHT_RENDER,
    INDIRECT_LIGHT_RENDER,
    RAW_PASSES,
    SAMPLING_BOOST,
    WITHOUT_DIRECT_LIGHT,
    FrameRecipe,
    Render,
    frame_recipe,
)
from generator.scene_spec import SceneSpec

REPO = Path(__file__).resolve().parents[3]
LIGHT = {"type": "POINT", "location": [0.0, -0.5, 1.0], "power": 20.0, "radius": 0.1}


def spec(lights: int, direct_light: str | None = None) -> SceneSpec:
    d = ds.base_spec(get_preset("structure_core").scaled(0.1).to_dict(), "pattern.png", "0" * 64,
                     lights=[LIGHT] * lights)
    if direct_light is None:
        del d["render"]["direct_light"]  # a scene.json from before the setting
    else:
        d["render"]["direct_light"] = direct_light
    return SceneSpec.from_dict(d)


def rendered_light(render: Render, scene_has_lights: bool) -> dict[str, dict[str, frozenset[str]]]:
    """What Cycles gives for `render`, by output ("image", "direct_file") and channel: the set of
    light terms in it. The spot (R: projector, G: flood) is the only light sampled unless extra
    lights are on, and then its direct light is missing where one of them was picked ("sampled").
    The compositor reads only passes that are on; a pass that is on and not read costs time."""
    competing = render.extra_lights and scene_has_lights
    needed = set()
    image, direct_file = {}, {}
    for channel, source in (("R", "projector"), ("G", "flood")):
        direct = f"{source} direct" + (" sampled" if competing else "")
        indirect = {f"{source} indirect"} if render.bounces else set()
        image[channel] = {direct} | indirect
        if render.red_green == "indirect":
            image[channel] = indirect
            needed |= {"diffuse_indirect", "diffuse_color", "glossy_indirect", "glossy_color"}
        if render.direct_file:
            direct_file[channel] = {direct}
            needed |= {"diffuse_direct", "diffuse_color", "glossy_direct", "glossy_color"}
    image["B"] = {"world"} | ({"extra lights"} if competing else set())
    image["A"] = {"depth"}
    if render.red_green is None:
        assert not render.direct_file, "only the compositor writes the direct file"
    assert render.light_passes == needed, (render, needed)
    return {"image": image, "direct_file": direct_file}


def _unsampled(terms: frozenset[str]) -> set[str]:
    return {term.removesuffix(" sampled") for term in terms}


def frame_light(recipe: FrameRecipe, scene_has_lights: bool) -> dict[str, frozenset[str]]:
    """Each raw pass's light terms, summing what the recipe's renders give (never a term twice)."""
    frame: dict[str, frozenset[str]] = {}
    for render in recipe.renders:
        light = rendered_light(render, scene_has_lights)
        for output, pairs in (("image", render.image), ("direct_file", render.direct_file)):
            for channel, name in pairs:
                terms, before = frozenset(light[output][channel]), frame.get(name, frozenset())
                assert not _unsampled(before) & _unsampled(terms), f"{name} counts {terms} twice"
                frame[name] = before | terms
    return frame


@pytest.mark.parametrize("lights, direct_light, exact", [
    (0, "separate", True), (0, "shared", True), (2, "separate", True), (2, "shared", False),
    (1, None, True),
])
def test_every_frame_holds_all_light_and_the_direct_light_apart(lights, direct_light, exact):
    """Whatever the recipe, projector and flood hold the spot's direct + indirect light, the *_direct
    passes its direct light alone (exact, or as Cycles sampled it with "shared"), ambient the world
    and the extra lights: the raw passes post_render reads, in its order."""
    recipe = frame_recipe(spec(lights, direct_light))
    assert recipe.raw_passes == RAW_PASSES
    light = frame_light(recipe, lights > 0)
    for source in ("projector", "flood"):
        direct = f"{source} direct" + ("" if exact else " sampled")
        assert light[source] == {direct, f"{source} indirect"}
        assert light[f"{source}_direct"] == {direct}
    assert light["ambient"] == ({"world", "extra lights"} if lights else {"world"})
    assert light["depth"] == {"depth"}


def test_a_scene_without_extra_lights_renders_once_and_writes_its_direct_passes_apart():
    for direct_light in ("separate", "shared"):
        recipe = frame_recipe(spec(0, direct_light))
        assert recipe == FrameRecipe((ALL_LIGHT_RENDER,), 1.0)
        (render,) = recipe.renders
        assert render.red_green == "all" and render.bounces and render.extra_lights
        assert render.image == (("R", "projector"), ("G", "flood"), ("B", "ambient"), ("A", "depth"))
        assert render.direct_file == (("R", "projector_direct"), ("G", "flood_direct"))


def test_extra_lights_separate_take_a_path_traced_and_then_a_direct_render():
    for direct_light in ("separate", None):  # None: a spec from before the setting
        recipe = frame_recipe(spec(1, direct_light))
        assert recipe.renders == (INDIRECT_LIGHT_RENDER, DIRECT_LIGHT_RENDER)
        assert recipe.sampling_boost == 1.0
    path_traced, direct = recipe.renders
    assert path_traced.red_green == "indirect" and not path_traced.direct_file
    assert not direct.bounces and not direct.extra_lights and direct.red_green is None
    assert direct.light_passes == frozenset()  # only its image is read


def test_extra_lights_shared_render_once_with_the_spot_boosted():
    assert frame_recipe(spec(3, "shared")) == FrameRecipe((ALL_LIGHT_RENDER,), SAMPLING_BOOST)


def test_the_one_render_way_without_direct_passes():
    """WITHOUT_DIRECT_LIGHT (bench.mask_fidelity's "old"): all light, nothing written apart."""
    assert WITHOUT_DIRECT_LIGHT.raw_passes == ("projector", "flood", "ambient", "depth")
    assert WITHOUT_DIRECT_LIGHT.sampling_boost == SAMPLING_BOOST
    light = frame_light(WITHOUT_DIRECT_LIGHT, True)
    assert light["projector"] == {"projector direct sampled", "projector indirect"}


def test_the_model_catches_a_recipe_that_counts_the_direct_light_twice():
    """The checks above can fail: the direct render after a path-traced render of all light."""
    with pytest.raises(AssertionError, match="twice"):
        frame_light(FrameRecipe((ALL_LIGHT_RENDER, DIRECT_LIGHT_RENDER), 1.0), True)


def test_blender_python_can_import_it():
    """Blender's own Python has no packages but numpy: the recipe needs only the standard library."""
    code = ("import sys; import generator.blender.frame_recipe; "
            "print(sorted(m for m in sys.modules if m.split('.')[0] in ('numpy', 'bpy', 'dotsim') "
            "or m in ('generator.config', 'generator.scene_spec')))")
    out = subprocess.run([sys.executable, "-c", code], cwd=REPO, capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"


@pytest.mark.parametrize("lights", [0, 1])
def test_labels_normals_and_glass_change_the_first_render_alone(lights):
    """Labels and normals add the data EXR to the first (path-traced) render and nothing else; glass
    adds the transmission passes to its light sums; a scene without them keeps its recipe exactly."""
    base = spec(lights, "separate")
    plain = frame_recipe(base)
    labelled = frame_recipe(replace(base, render=replace(base.render, labels=True, normals=True)))
    first, *rest = labelled.renders
    assert tuple(rest) == plain.renders[1:] and labelled.sampling_boost == plain.sampling_boost
    assert first == replace(plain.renders[0], data_file=first.data_file)
    assert first.data_passes == {"object_index", "normal"}
    assert set(labelled.raw_passes) == set(plain.raw_passes) | {"object_index", "normal_x", "normal_y",
                                                                "normal_z"}
    only_labels = frame_recipe(replace(base, render=replace(base.render, labels=True)))
    assert only_labels.renders[0].data_passes == {"object_index"}

    d = base.to_dict()
    d["render"]["labels"] = True
    d["objects"] = [ds.primitive("glass", "sphere", (0.2, 0.2, 0.2), (0.0, 0.0, 1.0),
                                 mat={**ds.material(1.0, 0.0), "kind": "transparent", "ior": 1.5})]
    with_glass = frame_recipe(SceneSpec.from_dict(d))
    first = with_glass.renders[0]
    assert first.transmission and tuple(with_glass.renders[1:]) == plain.renders[1:]
    added = first.light_passes - plain.renders[0].light_passes
    assert added == {name.replace("diffuse", "transmission") for name in plain.renders[0].light_passes
                     if "diffuse" in name}


@pytest.mark.parametrize("lights", [0, 1])
def test_an_ambient_ratio_denoises_the_first_renders_ambient_alone(lights):
    """[lighting] ambient_ratio has the first render's ambient (B, which the later renders never read)
    denoised; a scene without it keeps its recipe exactly."""
    base = spec(lights, "separate")
    plain = frame_recipe(base)
    lit = frame_recipe(replace(base, ambient_ratio=5.0))
    first, *rest = lit.renders
    assert first == replace(plain.renders[0], denoise_ambient=True) and tuple(rest) == plain.renders[1:]
    assert ("B", "ambient") in first.image
    assert not any(("B", "ambient") in render.image for render in rest)
    assert not any(render.denoise_ambient for render in plain.renders)
