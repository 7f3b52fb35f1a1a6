"""scene.json: the keys a caller must give, the keys the writer adds, and their validation."""

from __future__ import annotations

import json
import os
from pathlib import Path

from dotsim.channels import CAMERAS, CHANNEL
from dotsim.dataset.frames import FRAME_CHANNELS
from dotsim.dataset.layout import (
    SCENE_FILE,
    FormatError,
    check_format_version,
    complete_scenes,
    load_json,
    require,
)

# Scene meta keys the writer requires from the caller; the writer adds format_version,
# dotsim_version, scene_index, frame_count, channels and frames itself.
REQUIRED_META_KEYS = ("split", "rig", "pattern", "poses")
WRITER_META_KEYS = ("format_version", "dotsim_version", "scene_index", "frame_count", "channels", "frames")
# scene.json's "source" in scenes of real sensors (capture/); rendered scenes have no "source".
CAPTURED = "capture"


def holds_captures(dataset_dir: str | os.PathLike) -> bool | None:
    """True when the dataset holds real captures, False when it holds rendered scenes, None when it
    holds no (readable) scene yet: its first readable scene.json tells. A dataset holds one kind of
    data (`dotsim generate` and `dotsim capture` refuse a folder of the other kind), so one scene is
    enough."""
    for _, path in complete_scenes(dataset_dir):
        try:
            meta = json.loads((path / SCENE_FILE).read_bytes())
        except (OSError, ValueError):
            continue  # a damaged scene: the next one tells
        if isinstance(meta, dict):
            return meta.get("source") == CAPTURED
    return None


def camera_size(meta: dict, where="scene meta") -> tuple[int, int]:
    """(height, width) of the camera image from a scene's rig dict (Rig.to_dict())."""
    try:
        cam = meta["rig"]["camera"]
        h, w = cam["height"], cam["width"]
    except (KeyError, TypeError):
        raise FormatError(f"{where}: rig.camera.width/height missing") from None
    if not (isinstance(h, int) and isinstance(w, int) and h > 0 and w > 0):
        raise FormatError(f"{where}: rig.camera size must be positive integers, found {w} x {h}")
    return h, w


def scene_shapes(meta: dict, where="scene meta") -> dict[str, tuple[int, int]]:
    """{camera: (height, width)} of a scene's cameras (dotsim.channels.CAMERAS): the rig's IR camera
    (camera_size) and, in scenes with a colour camera (format 2.3 on), its `colour_camera.intrinsics`."""
    shapes = {"ir": camera_size(meta, where)}
    if meta.get("colour_camera") is not None:
        try:
            size = meta["colour_camera"]["intrinsics"]
            h, w = size["height"], size["width"]
        except (KeyError, TypeError):
            raise FormatError(f"{where}: colour_camera.intrinsics.width/height missing") from None
        if not (isinstance(h, int) and isinstance(w, int) and h > 0 and w > 0):
            raise FormatError(f"{where}: colour_camera size must be positive integers, found {w} x {h}")
        shapes["colour"] = (h, w)
    return shapes


def parse_scene_meta(path: Path, data: bytes) -> dict:
    """Validate scene.json bytes: JSON object, known major version, every required key, the
    channel list, the frame list, the rig camera size. Returns the dict."""
    meta = load_json(path, data)
    check_format_version(meta.get("format_version"), path)
    for key in REQUIRED_META_KEYS + WRITER_META_KEYS:
        if key not in meta:
            raise FormatError(f"{path}: missing key {key!r}")
    channels = require(meta, "channels", dict, path)
    unknown = [c for c in channels if c not in FRAME_CHANNELS]
    if unknown:
        raise FormatError(f"{path}: unknown channel(s) {unknown}; known: {list(FRAME_CHANNELS)}")
    frames = require(meta, "frames", list, path)
    if len(frames) != require(meta, "frame_count", int, path) or not all(
            isinstance(e, dict) and isinstance(e.get("file"), str) and e["file"] == Path(e["file"]).name
            and e["file"] not in ("", ".", "..") and isinstance(e.get("sha256"), str) for e in frames):
        raise FormatError(f"{path}: 'frames' must list frame_count entries {{file: a file name in the "
                          f"scene folder, sha256}}")
    shapes = scene_shapes(meta, path)
    without = [c for c in channels if CHANNEL[c].camera not in shapes]
    if without:
        raise FormatError(f"{path}: channel(s) {without} of a camera whose size scene.json does not give; "
                          f"required: {CAMERAS[CHANNEL[without[0]].camera]}")
    return meta
