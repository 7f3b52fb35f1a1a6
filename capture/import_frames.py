"""Import recorded sensor frames (projector on / off pairs) into the dotsim dataset format.

A real capture has no ground truth: each frame stores only the channels a sensor can give,

    ir          projector on (what the simulator's `ir` is), raw value / white level
    ambient     projector off, same units
    visibility  where the projector's dots reach the surface, from the on/off difference
    ir_right    of a stereo pair (--right): the right IR camera's projector-on frame, same units

and scene.json says so with "has_ground_truth": false and "source": "capture" (docs/CAPTURE.md).
Depth, projector column, disparity, flood and edge are absent: the format lets a scene list a
subset of channels (dotsim.dataset.write_scene, `channels`), which beats storing NaN images that
a trainer could mistake for labels. Rig poses are unknown and stored as null.

Every input file is decoded and checked (count, size, readability) before anything is written,
so a bad input leaves no output; scenes are written atomically and a rerun skips the scenes
already written from the same files (by sha256).
"""

from __future__ import annotations

import json
import os
import platform
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from capture.dots import DEFAULT_DOT_WINDOW, DEFAULT_VISIBILITY_THRESHOLD, capture_visibility
from capture.frames import CaptureError, check_size, list_images, pair_on_off, read_image
from capture.rectify import Rectifier, rectifier
from dotsim import __version__ as DOTSIM_VERSION
from dotsim import dataset, pattern_store
from dotsim.images import GreyImage
from dotsim.output_folder import CAPTURED, DATASET, OutputFolderError, check_output_folder
from dotsim.patterns import DotPattern
from dotsim.rig.files import Lens
from dotsim.rig.geometry import Rig
from dotsim.rig.stereo import stereo_baseline

CAPTURE_CHANNELS = ("ir", "ambient", "visibility")
# A stereo pair's captures also store the right camera's projector-on frame.
PAIR_CHANNELS = ("ir", "ir_right", "ambient", "visibility")


@dataclass(frozen=True)
class FramePair:
    """One recorded frame: its projector-on and projector-off files with their checksums, and of a
    stereo pair the right camera's projector-on file."""

    on: Path
    off: Path
    on_sha256: str
    off_sha256: str
    white_level: float
    right: Path | None = None
    right_sha256: str | None = None

    def sources(self) -> dict:
        sources = {"on": {"path": str(self.on.resolve()), "sha256": self.on_sha256},
                   "off": {"path": str(self.off.resolve()), "sha256": self.off_sha256}}
        if self.right is not None:
            sources["right"] = {"path": str(self.right.resolve()), "sha256": self.right_sha256}
        return sources


def _checked_image(path: Path, rig: Rig) -> GreyImage:
    image = read_image(path)
    check_size(image, rig.camera.width, rig.camera.height, rig.name)
    return image


def plan_import(on_spec: str, off_spec: str, rig: Rig, white_level: float | None = None,
                progress: bool = False, right_spec: str | None = None) -> list[FramePair]:
    """Find, pair, decode and check every input frame; nothing is kept but names and checksums.
    right_spec: the right camera's projector-on frames of a stereo pair, paired with the on frames.

    Raises CaptureError naming the file or argument for: a missing folder / no match, unequal
    on/off (/right) counts, an unreadable image, a size other than the rig camera's, or a file whose
    sample type (8-bit, 16-bit, EXR float) differs from the first one's: one capture has one white
    level.
    """
    right_files = None if right_spec is None else list_images(right_spec, what="--right frames")
    pairs = pair_on_off(list_images(on_spec, what="--on frames"), list_images(off_spec, what="--off frames"),
                        right_files)
    planned = []
    first = None
    for paths in _progress(pairs, progress, "checking frames", "pair"):
        images = [_checked_image(path, rig) for path in paths]
        first = first or images[0]
        for image in images:
            if image.pixels.dtype != first.pixels.dtype:
                raise CaptureError(f"{image.path}: sample type {image.pixels.dtype} differs from "
                                   f"{first.path} ({first.pixels.dtype}); record all frames the same way")
        on, off, *right = images
        level = on.white_level if white_level is None else float(white_level)
        planned.append(FramePair(on.path, off.path, on.sha256, off.sha256, level,
                                 *((right[0].path, right[0].sha256) if right else ())))
    return planned


def frame_channels(pair: FramePair, dot_window: int, threshold: float,
                   rectify: Rectifier | None = None) -> dict[str, np.ndarray]:
    """Read one pair again and build its dataset channels (ir, ambient, visibility), rectified to the
    rig camera first when `rectify` is given (a calibrated lens; capture.rectify).

    The checksum is compared with the one taken by plan_import, so a file replaced between the
    check and the write is refused rather than silently stored under the old checksum.
    """
    images = {}
    files = (("on", pair.on, pair.on_sha256), ("off", pair.off, pair.off_sha256),
             ("right", pair.right, pair.right_sha256))
    for role, path, sha in (file for file in files if file[1] is not None):
        image = read_image(path)
        if image.sha256 != sha:
            raise CaptureError(f"{path}: file changed during the import (sha256 differs); rerun")
        images[role] = image.relative(pair.white_level)
        if rectify is not None:
            images[role] = rectify.image(images[role])
    channels = {"ir": images["on"], "ambient": images["off"],
                "visibility": capture_visibility(images["on"], images["off"], dot_window, threshold)}
    if "right" in images:
        channels["ir_right"] = images["right"]
    return channels


def _progress(items, enabled: bool, description: str, unit: str):
    if not enabled:
        return items
    from tqdm import tqdm

    return tqdm(items, desc=description, unit=unit)


def _versions() -> dict:
    return {"dotsim": DOTSIM_VERSION, "numpy": np.__version__, "opencv": cv2.__version__,
            "python": platform.python_version()}


def scene_meta(sources: list[dict], rig: Rig, split: str, settings: dict,
               pattern: dict | None) -> dict:
    """scene.json content for one captured scene (the writer adds format and frame fields).
    sources: per frame, where its on and off images came from (files, or a device's frame numbers
    and timestamps); pattern: pattern_store.pattern_entry of the stored pattern, or None when the
    sensor's pattern is not known."""
    return {
        "split": split,
        "source": dataset.CAPTURED,
        "has_ground_truth": False,
        "rig": rig.to_dict(),
        "pattern": pattern,
        "poses": [None] * len(sources),  # the real rig's poses were not measured
        "capture": {"frames": sources, **settings},
        "versions": _versions(),
    }


def check_pair(rig: Rig, lens: Lens | None, where: str) -> None:
    """CaptureError naming `where` unless `rig` has a rectified stereo pair to store a right IR with,
    and the frames need no lens rectified away (only the left camera's lens would be known)."""
    try:
        stereo_baseline(rig, where)
    except ValueError as error:
        raise CaptureError(str(error)) from None
    if lens is not None:
        raise CaptureError(f"{where}: the rig's camera has lens distortion, which dotsim would rectify "
                           f"from the left images only; allowed: a pair recorded rectified (a RealSense's IR "
                           f"streams are) with a rig without distortion")


def _checksums(sources: list) -> list[tuple[str, ...]]:
    """(on, off and, of a stereo pair, right sha256) per frame: what identifies a scene's inputs,
    wherever the files moved."""
    return [tuple(frame[role]["sha256"] for role in ("on", "off", "right") if role in frame)
            for frame in sources]


def _existing_checksums(dataset_dir: Path, scene_index: int, scenes_per_shard: int) -> list | None:
    path = dataset.scene_dir(dataset_dir, scene_index, scenes_per_shard) / dataset.SCENE_FILE
    try:
        return _checksums(json.loads(path.read_text())["capture"]["frames"])
    except (KeyError, TypeError, ValueError):
        return None  # not a capture scene


def check_capture_folder(dataset_dir: Path, command: str) -> None:
    """CaptureError unless `dataset_dir` is new, empty or a dataset of captured scenes
    (dotsim.output_folder): a dataset holds one kind of data, and no other folder is written."""
    try:
        check_output_folder(dataset_dir, DATASET, "--out", command, CAPTURED)
    except OutputFolderError as error:
        raise CaptureError(str(error)) from None


def _stray_scenes(dataset_dir: Path, scene_count: int) -> list[Path]:
    """Scene directories of `dataset_dir` whose index is not among this import's scenes."""
    stray = []
    for path in sorted(dataset_dir.glob("shard_*/scene_*")):
        try:
            index = int(path.name.split("_")[1])
        except ValueError:
            continue
        if index >= scene_count:
            stray.append(path)
    return stray


def import_frames(on_spec: str, off_spec: str, rig: Rig, out_dir: str | os.PathLike, *,
                  frames_per_scene: int = 4, split: str = "test", white_level: float | None = None,
                  dot_window: int = DEFAULT_DOT_WINDOW,
                  visibility_threshold: float = DEFAULT_VISIBILITY_THRESHOLD,
                  capture_settings: dict | None = None, pattern: DotPattern | None = None,
                  scenes_per_shard: int = dataset.DEFAULT_SCENES_PER_SHARD,
                  progress: bool = True, lens: Lens | None = None, right_spec: str | None = None) -> dict:
    """Import projector on/off frame pairs as a sealed dataset; returns a summary dict.

    Pairs are grouped into scenes of `frames_per_scene` consecutive frames (the count must divide
    evenly). capture_settings (exposure, gain, ... as the user recorded them) go into every
    scene.json; pattern (the sensor's pattern, e.g. extracted from wall captures; it must have the
    rig projector's resolution) is stored as DATASET/pattern.png and referenced by every scene.
    A rerun skips scenes already written from files with the same checksums and refuses a
    dataset written from other files. lens: the calibrated camera the frames were recorded with
    (dotsim.rig.files.Lens), whose distortion is rectified away (capture.rectify) and recorded in
    scene.json under capture.rectified_from. right_spec: the right IR camera's projector-on frames
    of a stereo pair (stored as ir_right; the rig must have the pair, and no lens: check_pair).
    """
    if int(frames_per_scene) != frames_per_scene or frames_per_scene < 1:
        raise CaptureError(f"--frames-per-scene must be a positive integer, got {frames_per_scene}")
    if white_level is not None and not (np.isfinite(white_level) and white_level > 0):
        raise CaptureError(f"--white-level must be a positive number, got {white_level}")
    if right_spec is not None:
        check_pair(rig, lens, "--right")
    pairs = plan_import(on_spec, off_spec, rig, white_level, progress, right_spec)
    if len(pairs) % frames_per_scene:
        raise CaptureError(f"{len(pairs)} frame pairs do not split into scenes of {frames_per_scene} "
                           f"frames (--frames-per-scene); record a multiple of {frames_per_scene} "
                           f"pairs or pass --frames-per-scene 1")
    out_dir = Path(out_dir)
    scenes = [pairs[k:k + frames_per_scene] for k in range(0, len(pairs), frames_per_scene)]
    check_capture_folder(out_dir, "dotsim capture import")
    if out_dir.exists():
        stray = _stray_scenes(out_dir, len(scenes))
        if stray:
            raise CaptureError(f"{out_dir}: holds {stray[0]}, which this import of {len(scenes)} scene(s) "
                               f"would not write; choose an empty --out")
        dataset.remove_partial_scenes(out_dir)
    if pattern is not None and pattern.image.shape != (rig.projector.height, rig.projector.width):
        raise CaptureError(f"pattern {pattern.source} is {pattern.width} x {pattern.height} px but rig "
                           f"{rig.name!r} projector is {rig.projector.width} x {rig.projector.height} px")
    pattern_entry = None
    if pattern is not None:
        try:
            pattern_store.store_pattern(out_dir, pattern)
        except dataset.FormatError as error:
            raise CaptureError(f"{error}; choose an empty --out") from None
        pattern_entry = pattern_store.pattern_entry(pattern)
    rectify = rectifier(lens, rig.camera)
    settings = {"white_level": pairs[0].white_level, "frames_per_scene": frames_per_scene,
                "visibility": {"dot_window": dot_window, "threshold": visibility_threshold},
                "settings": capture_settings or {}, "rectified_from": lens and lens.to_dict()}
    written = skipped = 0
    for scene_index, scene_pairs in enumerate(_progress(scenes, progress, "importing scenes", "scene")):
        if dataset.is_scene_complete(out_dir, scene_index, scenes_per_shard):
            expected = _checksums([pair.sources() for pair in scene_pairs])
            if _existing_checksums(out_dir, scene_index, scenes_per_shard) != expected:
                raise CaptureError(f"{dataset.scene_dir(out_dir, scene_index, scenes_per_shard)}: was "
                                   f"imported from other files; choose an empty --out")
            skipped += 1
            continue
        frames = [frame_channels(pair, dot_window, visibility_threshold, rectify) for pair in scene_pairs]
        meta = scene_meta([pair.sources() for pair in scene_pairs], rig, split, settings, pattern_entry)
        dataset.write_scene(out_dir, scene_index, meta, frames, scenes_per_shard=scenes_per_shard,
                            channels=CAPTURE_CHANNELS if right_spec is None else PAIR_CHANNELS)
        written += 1
    index = dataset.seal_dataset(out_dir).index
    return {"dataset": str(out_dir), "frames": len(pairs), "scenes": len(scenes), "written": written,
            "skipped": skipped, "index_scenes": index["scene_count"]}
