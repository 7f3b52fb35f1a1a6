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
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from capture.frames import CaptureError, list_images, read_image
from dotsim import dataset
from dotsim.dataset import INDEX_FILE, LAYOUT_FILE, SCENE_FILE, SHARD_FILE, FormatError
from dotsim.dataset.layout import scene_dirs, shard_dirs
from dotsim.sensor.settings import recorded_sensor

# Relative rounding of the stored values: the dataset's float16, EXR's float32, integers exact.
FLOAT16_PRECISION = 2.0**-11
FLOAT32_PRECISION = 2.0**-24
INTEGER_PRECISION = 1e-9
# 16-bit files whose values all fit in this many bits hold data of fewer bits (10- or 12-bit sensors
# store theirs in the low bits): refused without --white-level, which says what full scale is.
LOW_BITS = 12


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
    camera: dict | None = None

    def scenes(self) -> Iterator[StaticScene]:
        return self.read()


def open_recording(specs: list[str], off: list[str] = (),
                   white_level: float | None = None) -> StaticRecording:
    """The recording named by `specs`: one dataset folder, or image files, folders or globs (with
    `off` the projector-off images). CaptureError naming the input for what cannot be read: a dataset
    among other recordings, or a dataset's own folders (never their pattern.png as a frame)."""
    kinds = {spec: dataset_folder_kind(Path(spec)) for spec in [*specs, *off]}
    if len(specs) == 1 and kinds[specs[0]] == "dataset":
        if off:
            raise CaptureError(f"--off: {specs[0]} is a dataset; its projector-off frames are its ambient "
                               "channel (leave --off out)")
        if white_level is not None:
            raise CaptureError(f"--white-level: {specs[0]} is a dataset, stored as fractions of full scale "
                               "already (leave --white-level out)")
        return _dataset_recording(Path(specs[0]))
    for spec, kind in kinds.items():
        if kind is None:
            continue
        what = "--off" if spec in off and spec not in specs else "RECORDING"
        if kind == "dataset":
            raise CaptureError(f"{what} {spec}: a dataset, read as its still scenes: give it alone, one "
                               "dataset at a time (not with other recordings or --off)")
        if kind == "unsealed dataset":
            raise CaptureError(f"{what} {spec}: a dataset without its {INDEX_FILE} (unfinished or being "
                               "written); let its run finish, or rerun it, then give the dataset folder "
                               "alone")
        raise CaptureError(f"{what} {spec}: a {kind} of a dataset, not a folder of frames; give the dataset "
                           "folder alone (fit-sensor reads its scenes)")
    return _image_recording(specs, list(off), white_level)


def single_frames(recording: StaticRecording) -> StaticRecording:
    """The recording with each projector-on frame a scene of its own (with the projector-off frame of
    the same index, the last one where there are fewer): measured (capture.sensor_fit.measure) as a
    one-frame recording is, from flat regions of single frames, so that a rendering of several still
    frames reads as a one-frame recording of the same sensor would.

    >>> on = np.zeros((3, 2, 2))
    >>> still = StaticRecording("r", "rendered", (2, 2), (3,), 0.0, 1.0, None,
    ...                         lambda: iter([StaticScene("s", on, depth=np.ones((2, 2)))]))
    >>> alone = single_frames(still)
    >>> alone.frame_counts, [scene.where for scene in alone.scenes()], next(alone.scenes()).on.shape
    ((1, 1, 1), ['s frame 0', 's frame 1', 's frame 2'], (1, 2, 2))
    """
    def read() -> Iterator[StaticScene]:
        for scene in recording.scenes():
            for k in range(len(scene.on)):
                off = None if scene.off is None else scene.off[min(k, len(scene.off) - 1)][None]
                yield replace(scene, where=f"{scene.where} frame {k}", on=scene.on[k][None], off=off)

    return replace(recording, frame_counts=(1,) * sum(recording.frame_counts), read=read)


def dataset_folder_kind(path: Path) -> str | None:
    """What part of a dotsim dataset `path` is: "dataset" (sealed: it has its index), "unsealed
    dataset" (its layout file or shard folders, no index yet), "shard", "scene", or None (not a
    folder of a dataset: image files, or anything else)."""
    if not path.is_dir():
        return None
    if (path / INDEX_FILE).is_file():
        return "dataset"
    if (path / LAYOUT_FILE).is_file() or shard_dirs(path):
        return "unsealed dataset"
    if (path / SHARD_FILE).is_file() or scene_dirs(path):
        return "shard"
    if (path / SCENE_FILE).is_file():
        return "scene"
    return None


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
    _check_white_level(on + off, white_level)
    level = first.white_level if white_level is None else white_level
    precision = FLOAT32_PRECISION if first.pixels.dtype == np.float32 else INTEGER_PRECISION

    def read() -> Iterator[StaticScene]:
        yield StaticScene(f"{len(on)} image file(s) from {specs[0]}",
                          np.stack([image.relative(level) for image in on]),
                          np.stack([image.relative(level) for image in off]) if off else None)

    return StaticRecording(", ".join(specs), "images", (first.shape[1], first.shape[0]), (len(on),),
                           precision, 1.0, None, read)


def _check_white_level(images: list, white_level: float | None) -> None:
    """CaptureError naming the file with the highest value when --white-level is below it (values
    above full scale: every level, and so the noise, would be off by their ratio), or, without
    --white-level, when 16-bit files use only their low LOW_BITS bits (10- or 12-bit data)."""
    brightest = max(images, key=lambda image: float(image.pixels.max()))
    highest = float(brightest.pixels.max())
    if white_level is not None and highest > white_level:
        raise CaptureError(f"--white-level {white_level:g}: below the data's maximum {highest:g} "
                           f"({brightest.path}); allowed: at least {highest:g} (the raw value of full scale: "
                           "1023 for 10-bit data, 4095 for 12-bit, 65535 for 16-bit)")
    if white_level is None and brightest.pixels.dtype == np.uint16 and 0 < highest < 2**LOW_BITS:
        bits = max(int(highest).bit_length(), 1)
        raise CaptureError(f"{brightest.path}: 16-bit files whose values reach only {highest:g}: {bits}-bit "
                           f"data in the low bits of a 16-bit file? pass --white-level {2**bits - 1} (its "
                           "full scale), or --white-level 65535 for 16-bit data of a dark scene")


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
                           recorded_sensor(meta) if rendered else None, read, meta["rig"]["camera"])


# A rendering is of the recording's camera when their fields of view (focal length over image width)
# agree this closely, relatively (whole-pixel rounding of a scaled rig moves them by about 1 / width).
FIELD_OF_VIEW_TOLERANCE = 0.02


def comparison_notes(recording: StaticRecording, rendering: StaticRecording, where: str) -> list[str]:
    """What `--compare` needs of a rendering: the recording's camera (its field of view, when the
    recording's rig is known: a dataset; its aspect ratio otherwise), at any size. CaptureError naming
    `where` when it is another camera; otherwise notes: the sizes converted between them, what could
    not be checked.

    >>> def still(size, camera=None):
    ...     return StaticRecording("x", "rendered", size, (4,), 0.0, 1.0, None, iter, camera)
    >>> comparison_notes(still((640, 480)), still((320, 240)), "--compare r")[0][:40]
    'the rendering is 320 x 240 px, the recor'
    >>> comparison_notes(still((640, 480)), still((320, 180)), "--compare r")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    capture.frames.CaptureError: --compare r: 320 x 180 px (aspect 1.778), the recording 640 x 480 px ...
    """
    (w_c, h_c), (w_r, h_r) = recording.size, rendering.size
    notes = []
    if recording.camera is not None and rendering.camera is not None:
        fov_c = recording.camera["fx"] / recording.camera["width"]
        fov_r = rendering.camera["fx"] / rendering.camera["width"]
        aspect = abs(w_r / h_r / (w_c / h_c) - 1)
        if abs(fov_r / fov_c - 1) > FIELD_OF_VIEW_TOLERANCE or aspect > FIELD_OF_VIEW_TOLERANCE:
            raise CaptureError(f"{where}: its camera (fx {rendering.camera['fx']:.5g} px at {w_r} x {h_r} "
                               f"px) is not the recording's (fx {recording.camera['fx']:.5g} px at {w_c} x "
                               f"{h_c} px): another field of view; render your config with the recording's "
                               "rig (any [rig] scale)")
    else:
        if abs(w_r / h_r / (w_c / h_c) - 1) > FIELD_OF_VIEW_TOLERANCE:
            raise CaptureError(f"{where}: {w_r} x {h_r} px (aspect {w_r / h_r:.3f}), the recording {w_c} "
                               f"x {h_c} px (aspect {w_c / h_c:.3f}): another camera; render your config "
                               "with the recording's rig (any [rig] scale)")
        notes.append("the recording's rig is not known (image files): only the rendering's aspect ratio was "
                     "checked against it; give a dataset of `capture import` to check its field of view")
    if (w_r, h_r) != (w_c, h_c):
        notes.insert(0, f"the rendering is {w_r} x {h_r} px, the recording {w_c} x {h_c} px: the rendering's "
                        f"sizes are converted to the recording's pixels (x {w_c / w_r:.4g})")
    return notes
