"""The reference scene of the add-on's tests: one tiny scene as `dotsim generate` writes it, which
the panel's preview of the same config, split, scene and seed must equal."""

from __future__ import annotations

from pathlib import Path

from dotsim.dataset import open_dataset
from generator.config import load_config
from generator.driver import generate

CONFIG = Path(__file__).resolve().parents[2] / "dotsim" / "configs" / "tiny.toml"
SCENE_INDEX, BASE_SEED, SPLIT = 1, 7, "train"


def generate_scene(out: Path) -> tuple[Path, dict, list[dict]]:
    """(dataset dir, scene meta, frames) of scene SCENE_INDEX generated into `out` by the pipeline
    (its own worker process)."""
    summary = generate(load_config(CONFIG), out, SPLIT, scenes=1, start=SCENE_INDEX, seed=BASE_SEED,
                       progress=False)
    assert summary.done == 1, summary.line()
    scene = open_dataset(out).read_scene(0)
    return out, scene.meta, scene.frames
