"""Record a live sensor (capture.devices) straight into the dataset format, as `capture import`
stores real frames (docs/CAPTURE.md "Recording").

Per pose: a projector-on frame and, where the device can switch its projector, a projector-off
frame of the same pose; the device's own depth (of the on frame) where it has one, stored as the
channel `device_depth`, never as `depth` (ground truth); for a device opened for its stereo pair (a
RealSense with --stereo) the right IR camera's image of the on frame, stored as `ir_right`, with a rig
whose second camera is the right one (its extrinsics in scene.json's capture.device). A scene is
written atomically when its frames are complete. Ctrl-C, SIGTERM or SIGHUP (under
dotsim.process_lifetime.stop_signals, as `dotsim capture record` runs) or a device that stops giving
frames ends the recording: the frames already complete are kept (the last scene may have fewer
frames), the dataset is sealed and the summary says what was kept. The recording holds the
dataset's writer lock (dotsim.dataset.lock).
"""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path

import cv2
import numpy as np

from capture.devices import Device, DeviceError, DeviceFrame
from capture.dots import DEFAULT_DOT_WINDOW, DEFAULT_VISIBILITY_THRESHOLD, capture_visibility
from capture.frames import CaptureError
from capture.import_frames import check_capture_folder, check_pair, scene_meta
from capture.rectify import Rectifier, rectifier
from dotsim import dataset, pattern_store
from dotsim.dataset.lock import writer_lock
from dotsim.patterns import DotPattern
from dotsim.rig.files import Lens
from dotsim.rig.geometry import Rig

# Frames read at most while waiting for a frame whose metadata shows the projector state asked for.
MAX_SWITCH_FRAMES = 60
PREVIEW_WINDOW = "dotsim capture record"


def record_channels(device: Device) -> tuple[str, ...]:
    """The channels a recording from this device stores (a subset of dotsim.dataset.FRAME_CHANNELS)."""
    return (("ir",) + (("ir_right",) if device.stereo else ())
            + (("ambient", "visibility") if device.can_switch_emitter else ())
            + (("device_depth",) if device.has_depth else ()))


def grab(device: Device, emitter: bool | None, settle: int) -> DeviceFrame:
    """A frame with the projector in state `emitter` (None: as it is, no switching).

    After switching, frames are read until one reports the new state in its metadata; a device whose
    frames do not report it gets `settle` frames dropped instead. DeviceError when the state never
    shows.
    """
    if emitter is None:
        return device.read()
    device.set_emitter(emitter)
    frame = device.read()
    if frame.emitter is None:
        for _ in range(settle):
            frame = device.read()
        return frame
    for _ in range(MAX_SWITCH_FRAMES):
        if frame.emitter == emitter:
            return frame
        frame = device.read()
    raise DeviceError(f"{device.name}: the projector did not switch {'on' if emitter else 'off'} within "
                      f"{MAX_SWITCH_FRAMES} frames")


def _source(frame: DeviceFrame) -> dict:
    return {"frame_number": frame.frame_number, "timestamp_ms": frame.timestamp_ms, "emitter": frame.emitter}


def pose_frame(device: Device, settle: int, white_level: float, dot_window: int,
               threshold: float, rectify: Rectifier | None = None) -> tuple[dict, dict]:
    """Record one pose: (dataset channels, where they came from); IR values are raw / white_level,
    rectified to the rig camera when `rectify` is given (a calibrated lens)."""
    def image(frame: DeviceFrame) -> np.ndarray:
        ir = frame.ir.astype(np.float32) / np.float32(white_level)
        return ir if rectify is None else rectify.image(ir)

    switch = device.can_switch_emitter
    on = grab(device, True if switch else None, settle)
    channels = {"ir": image(on)}
    if on.ir_right is not None:
        channels["ir_right"] = on.ir_right.astype(np.float32) / np.float32(white_level)
    source = {"on": _source(on)}
    if switch:
        off = grab(device, False, settle)
        channels["ambient"] = image(off)
        channels["visibility"] = capture_visibility(channels["ir"], channels["ambient"], dot_window,
                                                    threshold)
        source["off"] = _source(off)
    if device.has_depth:
        channels["device_depth"] = on.depth if rectify is None else rectify.depth(on.depth)
    return channels, source


def _preview():
    """A function showing a frame, when a display and an OpenCV with windows are there; else None."""
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        return None
    try:
        cv2.namedWindow(PREVIEW_WINDOW)
    except cv2.error:  # opencv-*-headless has no windows
        return None

    def show(image: np.ndarray) -> None:
        cv2.imshow(PREVIEW_WINDOW, np.clip(image * 255, 0, 255).astype(np.uint8))
        cv2.waitKey(1)

    return show


def record(device: Device, rig: Rig, out_dir: str | os.PathLike, *, scenes: int, frames_per_scene: int,
           split: str = "test", settle: int = 3, pause_s: float = 0.0, white_level: float | None = None,
           pattern: DotPattern | None = None,
           dot_window: int = DEFAULT_DOT_WINDOW, visibility_threshold: float = DEFAULT_VISIBILITY_THRESHOLD,
           scenes_per_shard: int = dataset.DEFAULT_SCENES_PER_SHARD, progress: bool = True,
           preview: bool = True, lens: Lens | None = None) -> dict:
    """Record `scenes` x `frames_per_scene` poses from an opened device into a new dataset.

    The rig's camera must have the stream's size. pause_s: seconds between poses (to move the sensor
    or the scene). white_level: the raw value stored as 1.0 (default: the device's full scale).
    Returns a summary: dataset, scenes, frames, channels, stopped (None, or why the recording ended
    early: the frames recorded until then are kept), signal (the number of the signal that stopped
    it: SIGINT for Ctrl-C; else None). lens: the calibrated camera (its distortion is rectified
    away; capture.rectify).
    """
    for name, value in (("--scenes", scenes), ("--frames", frames_per_scene)):
        if int(value) != value or value < 1:
            raise CaptureError(f"{name} must be a positive integer, got {value}")
    white_level = device.white_level if white_level is None else white_level
    if not (np.isfinite(white_level) and white_level > 0):
        raise CaptureError(f"--white-level must be a positive number, got {white_level}")
    stream = device.info["stream"]
    if (stream["width"], stream["height"]) != (rig.camera.width, rig.camera.height):
        raise CaptureError(f"{device.name} streams {stream['width']}x{stream['height']} px but rig "
                           f"{rig.name!r} "
                           f"camera is {rig.camera.width}x{rig.camera.height} px; allowed: a rig of the "
                           f"stream's size (--rig) or a stream of the rig's (--size)")
    out_dir = Path(out_dir)
    check_capture_folder(out_dir, "dotsim capture record")
    if out_dir.exists() and dataset.complete_scenes(out_dir):
        raise CaptureError(f"{out_dir}: already holds recorded scenes; choose an empty --out")
    if pattern is not None and pattern.image.shape != (rig.projector.height, rig.projector.width):
        raise CaptureError(f"pattern {pattern.source} is {pattern.width} x {pattern.height} px but rig "
                           f"{rig.name!r} projector is {rig.projector.width} x {rig.projector.height} px")
    if device.stereo:
        check_pair(rig, lens, f"--stereo: {device.name}")
    with writer_lock(out_dir, "dotsim capture record"):
        return _record(device, rig, out_dir, scenes, frames_per_scene, split, settle, pause_s, white_level,
                       pattern, dot_window, visibility_threshold, scenes_per_shard, progress, preview, lens)


def _record(device: Device, rig: Rig, out_dir: Path, scenes: int, frames_per_scene: int, split: str,
            settle: int, pause_s: float, white_level: float, pattern: DotPattern | None, dot_window: int,
            visibility_threshold: float, scenes_per_shard: int, progress: bool, preview: bool,
            lens: Lens | None) -> dict:
    dataset.remove_partial_scenes(out_dir)
    pattern_entry = None
    if pattern is not None:
        pattern_store.store_pattern(out_dir, pattern)
        pattern_entry = pattern_store.pattern_entry(pattern)
    channels = record_channels(device)
    settings = {"white_level": white_level, "frames_per_scene": frames_per_scene,
                "device": device.info, "settings": device.settings(), "settle_frames": settle,
                "visibility": {"dot_window": dot_window, "threshold": visibility_threshold},
                "rectified_from": lens and lens.to_dict()}
    rectify = rectifier(lens, rig.camera)
    show = _preview() if preview else None
    bar = None
    if progress:
        from tqdm import tqdm

        bar = tqdm(total=scenes * frames_per_scene, desc=f"recording {device.name}", unit="pose")
    written = frames_kept = 0
    pending: list[tuple[dict, dict]] = []
    stopped = signum = None

    def write(scene_index: int) -> None:
        nonlocal written, frames_kept
        meta = scene_meta([source for _, source in pending], rig, split, settings, pattern_entry)
        dataset.write_scene(out_dir, scene_index, meta, [frame for frame, _ in pending],
                            scenes_per_shard=scenes_per_shard, channels=channels)
        written += 1
        frames_kept += len(pending)
        pending.clear()

    scene_index = 0
    try:
        for scene_index in range(scenes):
            for pose in range(frames_per_scene):
                if pause_s and (scene_index or pose):
                    time.sleep(pause_s)
                pending.append(pose_frame(device, settle, white_level, dot_window, visibility_threshold,
                                          rectify))
                if show is not None:
                    show(pending[-1][0]["ir"])
                if bar is not None:
                    bar.update()
            write(scene_index)
    except KeyboardInterrupt as stop:  # Ctrl-C, or dotsim.process_lifetime.Stopped (SIGTERM, SIGHUP)
        signum = getattr(stop, "signum", signal.SIGINT)
        stopped = str(stop) if signum != signal.SIGINT else "interrupted (Ctrl-C)"
    except DeviceError as error:  # unplugged (DeviceGone), or a projector that stopped switching
        stopped = str(error)
    finally:
        if bar is not None:
            bar.close()
    # the frames of an unfinished scene are complete frames too (unless Ctrl-C came after its rename)
    if pending and not dataset.is_scene_complete(out_dir, scene_index, scenes_per_shard):
        write(scene_index)
    if written:
        dataset.seal_dataset(out_dir)
    return {"dataset": str(out_dir), "scenes": written, "frames": frames_kept, "stopped": stopped,
            "channels": list(channels), "signal": signum}
