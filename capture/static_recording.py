"""A recording of static scenes, the input of `dotsim capture fit-sensor`: frames in, scene by scene.

Three kinds, read the same way (open_recording):
- image files (8/16-bit PNG or EXR, as a sensor's SDK saves them; files, folders or quoted globs):
  one static scene, its projector-on frames and optionally projector-off frames, values raw /
  white level;
- a dataset from `capture record` or `capture import`: each scene is a static scene, its frames'
  `ir` the projector-on frames, `ambient` (where recorded) the projector-off ones and
  `device_depth` the depth where the device gives one;
- a dataset `dotsim generate` rendered: each scene must be static (`[motion] translation = 0` and
  `rotation = 0`: its frames share one pose, so they differ by the sensor's noise alone); its `ir`
  frames are the projector-on frames, `depth` the depth, and the flood light (`flood` - `ambient`)
  tells each dot's brightness without speckle. Its `ambient` is radiance the sensor never saw, so
  there are no projector-off frames.
Scenes are read one at a time (StaticRecording.scenes), so a large dataset never sits in memory.
"""

from __future__ import annotations

import warnings
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from capture.frames import CaptureError, list_images, read_image
from dotsim import dataset
from dotsim.dataset import INDEX_FILE, FormatError
from dotsim.sensor.settings import recorded_sensor

# Relative rounding of the stored values: the dataset's float16, EXR's float32, integers exact.
FLOAT16_PRECISION = 2.0**-11
FLOAT32_PRECISION = 2.0**-24
INTEGER_PRECISION = 1e-9


@dataclass(frozen=True)
class StaticScene:
    """One static scene: on (N, H, W) and off (M, H, W) or None, levels (fraction of full scale);
    depth (H, W) metres or None; flood (H, W): the light a uniform projector would give, or None;
    visible (H, W) bool: where the projector's direct light shows, or None; where: its name."""
    where: str
    on: np.ndarray
    off: np.ndarray | None = None
    depth: np.ndarray | None = None
    flood: np.ndarray | None = None
    visible: np.ndarray | None = None


@dataclass(frozen=True)
class StaticRecording:
    """A recording: its name, kind ("images", "capture" or "rendered"), the frame size (width,
    height), the projector-on frames per scene, the storage's relative precision, the size of its
    pixels in full-resolution sensor pixels (a rendering's [rig] scale; 1 for a sensor), the
    rendering's [sensor] table (or None) and a reader of its scenes."""
    name: str
    kind: str
    size: tuple[int, int]
    frame_counts: tuple[int, ...]
    precision: float
    pixel_scale: float
    sensor: dict | None
    read: Callable[[], Iterator[StaticScene]]

    def scenes(self) -> Iterator[StaticScene]:
        return self.read()


def open_recording(specs: list[str], off: list[str] = (),
                   white_level: float | None = None) -> StaticRecording:
    """The recording named by `specs`: one dataset folder, or image files, folders or globs (with
    `off` the projector-off images). CaptureError naming the input for what cannot be read."""
    if len(specs) == 1 and (Path(specs[0]) / INDEX_FILE).is_file():
        if off:
            raise CaptureError(f"--off: {specs[0]} is a dataset; its projector-off frames are its ambient "
                               "channel (leave --off out)")
        if white_level is not None:
            raise CaptureError(f"--white-level: {specs[0]} is a dataset, stored as fractions of full scale "
                               "already (leave --white-level out)")
        return _dataset_recording(Path(specs[0]))
    return _image_recording(specs, list(off), white_level)


def _image_recording(specs: list[str], off_specs: list[str], white_level: float | None) -> StaticRecording:
    def images(spec_list: list[str], what: str) -> list:
        return [read_image(path) for spec in spec_list for path in list_images(spec, what=what)]

    on, off = images(specs, "recording"), images(off_specs, "--off")
    first = on[0]
    for image in on + off:
        if image.shape != first.shape:
            raise CaptureError(f"{image.path}: {image.shape[1]} x {image.shape[0]} px, but {first.path} is "
                               f"{first.shape[1]} x {first.shape[0]} px")
        if image.pixels.dtype != first.pixels.dtype:
            raise CaptureError(f"{image.path}: {image.pixels.dtype} samples, but {first.path} has "
                               f"{first.pixels.dtype}; a recording has one sample type")
    if white_level is not None and not (np.isfinite(white_level) and white_level > 0):
        raise CaptureError(f"--white-level {white_level}: allowed: a positive number (the raw value of "
                           "full scale)")
    level = first.white_level if white_level is None else white_level
    precision = FLOAT32_PRECISION if first.pixels.dtype == np.float32 else INTEGER_PRECISION

    def read() -> Iterator[StaticScene]:
        yield StaticScene(f"{len(on)} image file(s) from {specs[0]}",
                          np.stack([image.relative(level) for image in on]),
                          np.stack([image.relative(level) for image in off]) if off else None)

    return StaticRecording(", ".join(specs), "images", (first.shape[1], first.shape[0]), (len(on),),
                           precision, 1.0, None, read)


def _dataset_recording(root: Path) -> StaticRecording:
    try:
        data = dataset.open_dataset(root)
        metas = [dataset.read_scene_meta(ref.path) for ref in data.scenes]
    except FormatError as error:
        raise CaptureError(str(error)) from None
    if not metas:
        raise CaptureError(f"{root}: the dataset holds no scene")
    meta = metas[0]
    rendered = meta.get("source") != "capture"
    if rendered:
        for ref, scene_meta in zip(data.scenes, metas, strict=True):
            poses = np.asarray(scene_meta["poses"], np.float64)
            if not np.array_equal(poses, np.broadcast_to(poses[:1], poses.shape)):
                raise CaptureError(f"{ref.path}: its frames have different poses: not a static scene; "
                                   "render one with [motion] translation = 0 and rotation = 0 in the config")
    channels = ("ir", "depth", "flood", "ambient", "visibility") if rendered else \
        ("ir", "ambient", "device_depth")

    def read() -> Iterator[StaticScene]:
        for ref, scene_meta in zip(data.scenes, metas, strict=True):
            present = [name for name in channels if name in scene_meta["channels"]]
            try:
                frames = dataset.read_scene(ref.path, channels=present).frames
            except FormatError as error:
                raise CaptureError(str(error)) from None
            stack = {name: np.stack([f[name].astype(np.float64) for f in frames]) for name in present}
            if rendered:
                yield StaticScene(str(ref.path), stack["ir"], depth=stack["depth"][0],
                                  flood=stack["flood"][0] - stack["ambient"][0],
                                  visible=stack["visibility"][0] > 0 if "visibility" in stack else None)
            else:
                depth = stack.get("device_depth")
                if depth is not None:
                    with warnings.catch_warnings():  # a pixel no frame has a reading for stays nan
                        warnings.simplefilter("ignore", RuntimeWarning)
                        depth = np.nanmedian(depth, axis=0)
                yield StaticScene(str(ref.path), stack["ir"], stack.get("ambient"), depth)

    width, height = meta["rig"]["camera"]["width"], meta["rig"]["camera"]["height"]
    config = meta.get("config", {}) if rendered else {}
    return StaticRecording(str(root), "rendered" if rendered else "capture", (width, height),
                           tuple(ref.frame_count for ref in data.scenes), FLOAT16_PRECISION,
                           float(config.get("rig", {}).get("scale", 1.0)),
                           recorded_sensor(meta) if rendered else None, read)
