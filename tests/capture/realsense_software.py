"""A pyrealsense2 software_device that behaves like a D400 stereo module, fed with given frames.

One sensor carries the left IR stream (infrared 1, y8), the right IR stream (infrared 2, only for
its extrinsics, which place the projector), depth (z16) and the options the backend uses
(emitter_enabled, exposure, gain, enable_auto_exposure, depth_units). A feeder thread pushes
frames of the current pose at about 100 fps: the projector-on or -off image as the emitter option
says at that moment, with `frame_emitter_mode` metadata, and the depth. The pose advances each time
the emitter is switched on again after being off (the recorder moves on to the next pose), and
the feeder stops pushing when the poses run out: the device goes silent as an unplugged one does.
"""

from __future__ import annotations

import threading
import time

import numpy as np
import pyrealsense2 as rs

from dotsim.rig.geometry import Rig

DEPTH_UNITS = 0.001
SERIAL = "SIM0001"


def _stream(sensor, kind, index, uid, fmt, bpp, rig: Rig):
    camera = rig.camera
    intrinsics = rs.intrinsics()
    intrinsics.width, intrinsics.height = camera.width, camera.height
    intrinsics.fx, intrinsics.fy, intrinsics.ppx, intrinsics.ppy = camera.fx, camera.fy, camera.cx, camera.cy
    intrinsics.model = rs.distortion.brown_conrady  # as a D400 reports its rectified IR streams
    intrinsics.coeffs = [0.0] * 5
    stream = rs.video_stream()
    stream.type, stream.index, stream.uid, stream.fmt, stream.bpp = kind, index, uid, fmt, bpp
    stream.width, stream.height, stream.fps, stream.intrinsics = camera.width, camera.height, 30, intrinsics
    return sensor.add_video_stream(stream)


def depth_z16(depth: np.ndarray) -> np.ndarray:
    """Metres -> z16 device units (0 = no reading, as beyond 65.535 m or no hit)."""
    units = np.round(np.where(np.isfinite(depth), depth, 0) / DEPTH_UNITS)
    return np.where(units <= 65535, units, 0).astype(np.uint16)


class SoftwareStereoModule:
    """poses: list of (ir_on uint8, ir_off uint8, depth z16) frames; rig: its camera gives the
    streams' intrinsics, its baseline the right IR camera's place. stream_right: push right IR frames
    too, the left ones' images (a recorder records their extrinsics), or with right_poses (per pose
    the right camera's (on, off) uint8 images) those."""

    def __init__(self, rig: Rig, poses: list[tuple[np.ndarray, np.ndarray, np.ndarray]],
                 stream_right: bool = False,
                 right_poses: list[tuple[np.ndarray, np.ndarray]] | None = None):
        self.poses = poses
        self.right_poses = right_poses
        self.stream_right = stream_right or right_poses is not None
        self.device = rs.software_device()
        self.device.register_info(rs.camera_info.serial_number, SERIAL)
        self.device.register_info(rs.camera_info.name, "dotsim software stereo module")
        self.sensor = self.device.add_sensor("Stereo Module")
        self.ir = _stream(self.sensor, rs.stream.infrared, 1, 1, rs.format.y8, 1,
                          rig).as_video_stream_profile()
        self.right = _stream(self.sensor, rs.stream.infrared, 2, 2, rs.format.y8, 1,
                             rig).as_video_stream_profile()
        self.depth = _stream(self.sensor, rs.stream.depth, 0, 3, rs.format.z16, 2,
                             rig).as_video_stream_profile()
        extrinsics = rs.extrinsics()
        extrinsics.rotation = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
        extrinsics.translation = [-rig.baseline, 0.0, 0.0]  # X_right = X_left + T, right camera at +b
        self.ir.register_extrinsics_to(self.right, extrinsics)
        self.sensor.add_read_only_option(rs.option.depth_units, DEPTH_UNITS)
        # rs.option_range(min, max, default, step)
        self.sensor.add_option(rs.option.emitter_enabled, rs.option_range(0, 1, 1, 1), True)
        self.sensor.add_option(rs.option.enable_auto_exposure, rs.option_range(0, 1, 1, 1), True)
        self.sensor.add_option(rs.option.exposure, rs.option_range(1, 165000, 8500, 1), True)
        self.sensor.add_option(rs.option.gain, rs.option_range(16, 248, 16, 1), True)
        self.pose = 0
        self.pushed = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._feed, daemon=True)

    def __enter__(self) -> SoftwareStereoModule:
        self._thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self._stop.set()
        self._thread.join()

    def _push(self, profile, pixels: np.ndarray, number: int, emitter: bool) -> None:
        frame = rs.software_video_frame()
        frame.pixels = np.ascontiguousarray(pixels)
        frame.bpp = pixels.itemsize
        frame.stride = pixels.shape[1] * pixels.itemsize
        frame.timestamp = number * 10.0
        frame.domain = rs.timestamp_domain.hardware_clock
        frame.frame_number = number
        frame.profile = profile
        if profile is self.depth:
            frame.depth_units = DEPTH_UNITS
        self.sensor.set_metadata(rs.frame_metadata_value.frame_emitter_mode, int(emitter))
        self.sensor.on_video_frame(frame)

    def _feed(self) -> None:
        was_on = True
        while not self._stop.is_set():
            on = self.sensor.get_option(rs.option.emitter_enabled) != 0
            if on and not was_on:
                self.pose += 1
            was_on = on
            if self.pose >= len(self.poses):
                return  # silent from now on, like an unplugged device
            ir_on, ir_off, depth = self.poses[self.pose]
            self.pushed += 1
            self._push(self.ir, ir_on if on else ir_off, self.pushed, on)
            self._push(self.depth, depth, self.pushed, on)
            if self.stream_right:
                right_on, right_off = (self.right_poses[self.pose] if self.right_poses is not None
                                       else (ir_on, ir_off))
                self._push(self.right, right_on if on else right_off, self.pushed, on)
            time.sleep(0.01)
