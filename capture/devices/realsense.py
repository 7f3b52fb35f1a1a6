"""Intel RealSense (D400 family) through pyrealsense2 (extra `realsense`).

One sensor (the stereo module) carries the left IR stream (infrared index 1), the depth stream (in
the left IR camera's frame, so pixel-aligned with it), the right IR stream (infrared index 2, opened
with stereo=True: `capture record --stereo`) and the projector's `emitter_enabled` option; the
streams are opened on it and paired by frame number with an rs.syncer. The frame
metadata `frame_emitter_mode` says whether the projector lit a frame, so recording waits for the
state it asked for rather than guessing a settling time. The same code drives a
pyrealsense2 `software_device` fed with rendered frames (tests/capture/test_capture_record.py).
"""

from __future__ import annotations

import threading
import time
from pathlib import Path

import numpy as np

from capture.devices import Device, DeviceError, DeviceFrame, DeviceGone, require_extra
from dotsim.file_io import sha256_file
from dotsim.rig.files import device_rig
from dotsim.rig.geometry import Intrinsics, Rig

IR_FORMATS = {"y8": 255.0, "y16": 65535.0}  # format -> raw value of a saturated pixel
# Options read back into every scene.json (when the device has them).
RECORDED_OPTIONS = ("exposure", "gain", "enable_auto_exposure", "emitter_enabled", "laser_power",
                    "depth_units")


def _rs():
    return require_extra("pyrealsense2", "realsense", "realsense")


def open_realsense(serial: str = "", devices=None, **mode) -> RealSenseDevice:
    """The RealSense with this serial (any one when empty) among `devices` (default: the connected
    ones, from librealsense's context), opened by RealSenseDevice."""
    rs = _rs()
    devices = list(rs.context().query_devices() if devices is None else devices)
    if not devices:
        raise DeviceError("--device realsense: no RealSense device found; allowed: a connected RealSense "
                          "(check the cable and that librealsense sees it)")
    serials = [device.get_info(rs.camera_info.serial_number) for device in devices]
    if serial and serial not in serials:
        raise DeviceError(f"--device realsense:{serial}: no RealSense with that serial; connected: "
                          f"{', '.join(serials)}")
    return RealSenseDevice(devices[serials.index(serial) if serial else 0], **mode)


def _mode(profile) -> str:
    video = profile.as_video_stream_profile()
    return f"{video.width()}x{video.height()}@{profile.fps()}"


class RealSenseDevice(Device):
    """An opened RealSense (or software_device) streaming left IR, where it has it depth, and with
    `stereo` the right IR too (the same mode; its extrinsics are recorded in `info`)."""

    def __init__(self, device, *, size: tuple[int, int] | None = None, fps: int | None = None,
                 exposure: float | None = None, gain: float | None = None, ir_format: str = "y8",
                 timeout_s: float = 5.0, stereo: bool = False):
        rs = self._rs = _rs()
        serial = device.get_info(rs.camera_info.serial_number)
        self.name = f"realsense:{serial}"
        self._device = device  # also keeps a software_device alive while its sensor streams
        self._timeout_s = timeout_s
        if ir_format not in IR_FORMATS:
            raise DeviceError(f"{self.name}: IR format {ir_format!r}; allowed: {', '.join(IR_FORMATS)}")
        fmt = getattr(rs.format, ir_format)
        candidates = [(sensor, profile) for sensor in device.query_sensors()
                      for profile in sensor.get_stream_profiles()
                      if profile.stream_type() == rs.stream.infrared and profile.stream_index() == 1
                      and profile.format() == fmt]
        if not candidates:
            raise DeviceError(f"{self.name}: no left infrared stream (index 1) in {ir_format}")
        offered = sorted({_mode(profile) for _, profile in candidates})
        matching = [(sensor, profile) for sensor, profile in candidates
                    if (size is None or _mode(profile).startswith(f"{size[0]}x{size[1]}@"))
                    and (fps is None or profile.fps() == fps)]
        if not matching:
            wanted = f"{size[0]}x{size[1]}" if size else "any size"
            raise DeviceError(f"{self.name}: no infrared stream {wanted} at {fps or 'any'} fps in "
                              f"{ir_format}; "
                              f"allowed: {', '.join(offered)}")
        # the device's default mode first, then the largest image at the highest rate
        self._sensor, self._ir = max(matching, key=lambda item: (
            item[1].is_default(), item[1].as_video_stream_profile().width(), item[1].fps()))
        ir_mode = _mode(self._ir)
        same_mode = [profile for profile in self._sensor.get_stream_profiles() if _mode(profile) == ir_mode]
        self._depth = next((p for p in same_mode if p.stream_type() == rs.stream.depth
                            and p.format() == rs.format.z16), None)
        self._ir2 = next((p for p in same_mode if p.stream_type() == rs.stream.infrared
                          and p.stream_index() == 2 and p.format() == fmt), None)
        if stereo and self._ir2 is None:
            raise DeviceError(f"{self.name}: --stereo: no right infrared stream (index 2) {ir_mode} in "
                              f"{ir_format}; leave --stereo out")
        self.stereo = stereo
        self.has_depth = self._depth is not None
        self.can_switch_emitter = self._sensor.supports(rs.option.emitter_enabled)
        self.white_level = IR_FORMATS[ir_format]
        self._depth_scale = (self._sensor.get_option(rs.option.depth_units)
                             if self._sensor.supports(rs.option.depth_units) else 0.001)
        self._fix_exposure(exposure, gain)
        video = self._ir.as_video_stream_profile()
        self.info = {"kind": "realsense", "serial": serial, "model": self._info(rs.camera_info.name),
                     "firmware": self._info(rs.camera_info.firmware_version),
                     "stream": {"width": video.width(), "height": video.height(), "fps": self._ir.fps(),
                                "format": ir_format, "depth": self.has_depth}}
        if stereo:
            self.info["right_ir"] = self._right_extrinsics()
        self._syncer = rs.syncer()
        self._sensor.open([self._ir] + ([self._ir2] if stereo else [])
                          + ([self._depth] if self._depth is not None else []))
        self._sensor.start(self._syncer)

    def _info(self, field) -> str | None:
        return self._device.get_info(field) if self._device.supports(field) else None

    def _fix_exposure(self, exposure: float | None, gain: float | None) -> None:
        """Auto exposure off (on and off frames must share one scale), then the asked values."""
        rs = self._rs
        if self._sensor.supports(rs.option.enable_auto_exposure):
            self._sensor.set_option(rs.option.enable_auto_exposure, 0.0)
        for option, value in (("exposure", exposure), ("gain", gain)):
            if value is None:
                continue
            key = getattr(rs.option, option)
            if not self._sensor.supports(key):
                raise DeviceError(f"{self.name}: has no {option} option; leave --{option} out")
            limits = self._sensor.get_option_range(key)
            if not limits.min <= value <= limits.max:
                raise DeviceError(f"{self.name}: --{option} {value:g}; allowed: {limits.min:g} to "
                                  f"{limits.max:g}")
            self._sensor.set_option(key, float(value))

    def camera(self) -> Intrinsics:
        intrinsics = self._ir.as_video_stream_profile().get_intrinsics()
        if any(coefficient != 0 for coefficient in intrinsics.coeffs):
            raise DeviceError(f"{self.name}: the IR stream reports distortion {list(intrinsics.coeffs)}; "
                              "dotsim needs rectified IR images (the D400's are)")
        return Intrinsics(intrinsics.width, intrinsics.height, intrinsics.fx, intrinsics.fy, intrinsics.ppx,
                          intrinsics.ppy)

    def _right_pose(self) -> tuple[np.ndarray, np.ndarray]:
        """(R, T) with X_right = R X_left + T (metres), as the device reports its IR pair's extrinsics."""
        if self._ir2 is None:
            raise DeviceError(f"{self.name}: no right infrared stream whose position would place the "
                              "projector; pass a rig file with --rig")
        extrinsics = self._ir.get_extrinsics_to(self._ir2)
        rotation = np.array(extrinsics.rotation).reshape(3, 3).T  # librealsense stores it column-major
        return rotation, np.array(extrinsics.translation)

    def _right_extrinsics(self) -> dict:
        """The right IR stream and its extrinsics from the left one, for `info`; DeviceError unless the
        pair is rectified (the D400 rectifies its IR streams: same orientation)."""
        rotation, translation = self._right_pose()
        if not np.allclose(rotation, np.eye(3), atol=1e-6):
            raise DeviceError(f"{self.name}: --stereo: its IR pair is not rectified (rotation "
                              f"{np.round(rotation, 6).tolist()} from the left to the right camera); dotsim "
                              "stores rectified pairs only")
        return {"stream_index": 2, "extrinsics_from_left": {
            "rotation": rotation.ravel().tolist(), "translation": translation.tolist(),
            "convention": "X_right = R X_left + T, metres, R row-major"}}

    def rig(self) -> Rig:
        """The left IR camera, with the projector (and second camera) at the right IR camera's place:
        the D400's own projector is not calibrated, so it stands where the stereo partner is."""
        rotation, translation = self._right_pose()
        centre = tuple((-rotation.T @ translation).tolist())  # X2 = R X1 + T
        return device_rig(f"realsense_{self.info['serial']}", self.camera(), centre, centre)

    def settings(self) -> dict:
        rs = self._rs
        return {name: float(self._sensor.get_option(getattr(rs.option, name)))
                for name in RECORDED_OPTIONS if self._sensor.supports(getattr(rs.option, name))}

    def set_emitter(self, on: bool) -> None:
        if not self.can_switch_emitter:
            super().set_emitter(on)
        self._sensor.set_option(self._rs.option.emitter_enabled, 1.0 if on else 0.0)

    def read(self) -> DeviceFrame:
        rs = self._rs
        ir, right, depth = self._frames()
        emitter = None
        if ir.supports_frame_metadata(rs.frame_metadata_value.frame_emitter_mode):
            emitter = ir.get_frame_metadata(rs.frame_metadata_value.frame_emitter_mode) != 0
        metres = None
        if depth is not None:
            raw = np.asanyarray(depth.get_data()).astype(np.float32) * np.float32(self._depth_scale)
            metres = np.where(raw > 0, raw, np.nan).astype(np.float32)
        right_ir = None if right is None else np.asanyarray(right.get_data()).copy()
        return DeviceFrame(np.asanyarray(ir.get_data()).copy(), float(ir.get_timestamp()),
                           int(ir.get_frame_number()), emitter, metres, right_ir)

    def _frames(self):
        """The next left IR frame, its right IR frame (None unless stereo) and its depth frame (None
        without depth), from one frameset."""
        deadline = time.monotonic() + self._timeout_s
        while True:
            ir, right, depth = self._frameset(deadline)
            # the syncer can hand out a stream alone before its partners arrive
            if ir is not None and (right is not None or not self.stereo) and (depth is not None
                                                                             or not self.has_depth):
                return ir, right, depth

    def _frameset(self, deadline: float):
        """(left IR, right IR, depth) frames of the syncer's next frameset, each None when it lacks it;
        DeviceGone past the deadline."""
        rs = self._rs
        remaining_ms = int(1000 * (deadline - time.monotonic()))
        try:
            if remaining_ms <= 0:
                raise RuntimeError
            frames = self._syncer.wait_for_frames(remaining_ms)
        except RuntimeError:
            raise DeviceGone(f"{self.name}: no frame for {self._timeout_s:g} s (unplugged or stopped)") \
                from None
        ir = right = depth = None
        for k in range(frames.size()):
            frame = frames[k]
            if frame.profile.stream_type() == rs.stream.infrared:
                if frame.profile.stream_index() == 1:
                    ir = frame
                elif frame.profile.stream_index() == 2:
                    right = frame
            elif frame.profile.stream_type() == rs.stream.depth:
                depth = frame
        return ir, right, depth

    def close(self) -> None:
        # Frames the syncer still holds are taken while the sensor stops: a played-back recording
        # hands out frames only as they are taken, and its stop waited on them forever (three
        # streams of a recording, measured).
        stopped = threading.Event()

        def drain() -> None:
            while not stopped.is_set():
                self._syncer.poll_for_frames()
                time.sleep(0.001)

        drainer = threading.Thread(target=drain, daemon=True)
        drainer.start()
        try:
            self._sensor.stop()
            self._sensor.close()
        except RuntimeError:  # already stopped, or the device is gone
            pass
        finally:
            stopped.set()
            drainer.join()


RECORDING_SUFFIXES = (".bag", ".db3")  # ROS1 bags (RealSense Viewer, SDK <= 2.55) and ROS2 (SDK >= 2.56)


def _load_recording(path: Path):
    """A playback device of a RealSense recording, played as fast as it is read."""
    rs = _rs()
    if path.suffix.lower() not in RECORDING_SUFFIXES:
        raise DeviceError(f"--bag {path}: not a RealSense recording; allowed: "
                          f"{', '.join(RECORDING_SUFFIXES)}")
    if not path.is_file():
        raise DeviceError(f"--bag {path}: file not found")
    try:
        device = rs.context().load_device(str(path))
    except RuntimeError as error:
        raise DeviceError(f"--bag {path}: pyrealsense2 cannot play it back ({error})") from None
    device.as_playback().set_real_time(False)
    return device


def _recorded_ir_format(device, path: Path) -> str:
    rs = _rs()
    for name in IR_FORMATS:
        if any(profile.stream_type() == rs.stream.infrared and profile.stream_index() == 1
               and profile.format() == getattr(rs.format, name)
               for sensor in device.query_sensors() for profile in sensor.get_stream_profiles()):
            return name
    raise DeviceError(f"--bag {path}: holds no left infrared stream (infrared 1, y8 or y16); record the IR "
                      "stream (RealSense Viewer: Stereo Module > Infrared 1)")


class RealSenseRecording(RealSenseDevice):
    """A RealSense recording played back as a Device: left IR frames with the emitter state each one
    recorded (frame_emitter_mode metadata), depth where recorded, and the recorded calibration.

    Its projector cannot be switched: `set_emitter(on)` moves on to the next frame recorded in that
    state, so recording's on/off pairs are an on frame and the next off frame. `poses` (counted by a
    first pass over the file) is how many poses the recording gives: on/off pairs when both states
    were recorded, else every IR frame.
    """

    def __init__(self, path, timeout_s: float = 2.0, count_poses: bool = True, stereo: bool = False):
        path = Path(path)
        states = self._emitter_states(path) if count_poses else []
        # frames waiting for their partners, by frame number: left IR, right IR, depth
        self._waiting: tuple[dict, dict, dict] = ({}, {}, {})
        device = _load_recording(path)
        try:
            super().__init__(device, ir_format=_recorded_ir_format(device, path), timeout_s=timeout_s,
                             stereo=stereo)
        except DeviceError as error:
            raise DeviceError(f"--bag {path}: {error}") from None
        self.name = f"recording:{path.name}"
        self.can_switch_emitter = {True, False} <= set(states)
        self.poses = _pose_count(states) if self.can_switch_emitter else len(states)
        self._pending: DeviceFrame | None = None
        if count_poses:
            self.info.update(kind="realsense-recording", file=str(path.resolve()), sha256=sha256_file(path))

    @staticmethod
    def _emitter_states(path: Path) -> list[bool | None]:
        """The emitter state of every recorded left IR frame, in order (None where not recorded): a
        first pass over the file (its end shows as a second without frames)."""
        states = []
        with RealSenseRecording(path, timeout_s=1.0, count_poses=False) as scan:
            while True:
                try:
                    states.append(scan.read().emitter)
                except DeviceGone:
                    return states

    def _fix_exposure(self, exposure, gain) -> None:
        """A recording's exposure is what it was: nothing to set."""

    def _frames(self):
        """The next left IR frame and the right IR (when stereo) and depth frames of the same frame
        number: played back, the streams may come in framesets of their own (ROS1 bags do), so they
        are paired by number."""
        deadline = time.monotonic() + self._timeout_s
        wanted = (True, self.stereo, self.has_depth)
        needed = [store for store, want in zip(self._waiting, wanted, strict=True) if want]
        while True:
            common = sorted(set.intersection(*(set(store) for store in needed)))
            if common:
                number = common[0]
                for store in self._waiting:  # unmatched older frames never pair any more
                    for older in [key for key in store if key < number]:
                        del store[older]
                return tuple(store.pop(number, None) for store in self._waiting)
            for store, frame in zip(self._waiting, self._frameset(deadline), strict=True):
                if frame is not None:
                    store[frame.get_frame_number()] = frame

    def set_emitter(self, on: bool) -> None:
        while self._pending is None or self._pending.emitter != on:
            self._pending = super().read()

    def read(self) -> DeviceFrame:
        frame, self._pending = self._pending, None
        return frame if frame is not None else super().read()


def _pose_count(states: list[bool | None]) -> int:
    """On/off pairs in a sequence of emitter states: an on frame, then the next off frame."""
    poses, want = 0, True
    for state in states:
        if state is want:
            poses += not want
            want = not want
    return poses

