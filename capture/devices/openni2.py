"""OpenNI2 sensors (PrimeSense / Kinect v1 class, Orbbec) through the `openni` package (extra
`openni2`) and the native OpenNI2 library (Debian: libopenni2-dev, which links libOpenNI2.so; or
set OPENNI2_REDIST to its folder).

IR stream in GRAY16 (white level: the stream's maximum pixel value, 1023 on PS1080 devices), depth
in millimetres where the device has a depth sensor, the projector switched with the PS1080 device
property XN_MODULE_PROPERTY_EMITTER_STATE (0x1080E007, boolean; PS1080.h). OpenNI2 reports fields of
view rather than a calibration, so the rig has a centred principal point, focal lengths from the
fields of view and the projector at +0.075 m (PrimeSense's baseline); calibrate for anything better.
Not exercised on a device here: no OpenNI2 sensor is attached to the build machines.
"""

from __future__ import annotations

import ctypes
import math
import os
import sysconfig
from pathlib import Path

import numpy as np

from capture.devices import Device, DeviceError, DeviceFrame, DeviceGone, require_extra
from dotsim.rig.files import device_rig
from dotsim.rig.geometry import Intrinsics, Rig

EMITTER_STATE = 0x1080E007
PRIMESENSE_BASELINE = 0.075


def library_directories() -> list[str]:
    """Where to look for libOpenNI2.so: $OPENNI2_REDIST, the bindings' defaults, and Debian's
    multiarch folder (libopenni2-dev links libOpenNI2.so there)."""
    multiarch = sysconfig.get_config_var("MULTIARCH")
    return ([os.environ["OPENNI2_REDIST"]] if os.environ.get("OPENNI2_REDIST") else []) + [
        ".", "/lib", "/usr/lib", "/usr/local/lib", "/lib64"] + (
        [f"/usr/lib/{multiarch}"] if multiarch else [])


def open_openni2(uri: str = "", **mode) -> OpenNI2Device:
    """The OpenNI2 device at `uri` (a device URI or a .oni recording; any device when empty)."""
    openni2 = require_extra("openni.openni2", "openni2", "openni2")
    try:
        if not openni2.is_initialized():
            openni2.initialize(library_directories())
    except Exception as error:  # the bindings raise plain Exceptions (OpenNIError or ctypes OSError)
        raise DeviceError(f"--device openni2: the native OpenNI2 library cannot be loaded ({error}); install "
                          "it (Debian: libopenni2-dev) or set OPENNI2_REDIST to its folder") from None
    if uri and Path(uri).suffix == ".oni":
        return OpenNI2Device(openni2, openni2.Device.open_file(uri.encode()), uri, **mode)
    uris = [u.decode() if isinstance(u, bytes) else u for u in openni2.Device.enumerate_uris()]
    if not uris:
        raise DeviceError("--device openni2: no OpenNI2 device found; allowed: a connected OpenNI2 sensor "
                          "or openni2:FILE.oni")
    if uri and uri not in uris:
        raise DeviceError(f"--device openni2:{uri}: no device at that URI; connected: {', '.join(uris)}")
    chosen = uri or uris[0]
    return OpenNI2Device(openni2, openni2.Device(chosen.encode()), chosen, **mode)


class OpenNI2Device(Device):
    def __init__(self, openni2, device, uri: str, *, size: tuple[int, int] | None = None,
                 fps: int | None = None, exposure: float | None = None, gain: float | None = None):
        self.name = f"openni2:{uri}"
        self._device = device
        self._ir = device.create_ir_stream()
        modes = [m for m in self._ir.get_sensor_info().videoModes
                 if m.pixelFormat == openni2.PIXEL_FORMAT_GRAY16]
        offered = sorted({f"{m.resolutionX}x{m.resolutionY}@{m.fps}" for m in modes})
        matching = [m for m in modes if (size is None or (m.resolutionX, m.resolutionY) == tuple(size))
                    and (fps is None or m.fps == fps)]
        if not matching:
            wanted = f"{size[0]}x{size[1]}" if size else "any size"
            raise DeviceError(f"{self.name}: no 16-bit IR mode {wanted} at {fps or 'any'} fps; allowed: "
                              f"{', '.join(offered) or 'none'}")
        mode = max(matching, key=lambda m: (m.resolutionX, m.fps))
        self._ir.set_video_mode(mode)
        self._depth = None
        if device.has_sensor(openni2.SENSOR_DEPTH):
            self._depth = device.create_depth_stream()
            self._depth.configure_mode(mode.resolutionX, mode.resolutionY, mode.fps,
                                       openni2.PIXEL_FORMAT_DEPTH_1_MM)
        self.has_depth = self._depth is not None
        self.can_switch_emitter = device.is_property_supported(EMITTER_STATE)
        camera_settings = self._ir.camera
        if exposure is not None or gain is not None:
            if camera_settings is None:
                raise DeviceError(f"{self.name}: the IR stream has no exposure or gain to set")
            camera_settings.set_auto_exposure(False)
            if exposure is not None:
                camera_settings.set_exposure(int(exposure))
            if gain is not None:
                camera_settings.set_gain(int(gain))
        self.white_level = float(self._ir.get_max_pixel_value())
        self.info = {"kind": "openni2", "uri": uri, "serial": uri,
                     "stream": {"width": mode.resolutionX, "height": mode.resolutionY, "fps": mode.fps,
                                "format": "gray16", "depth": self.has_depth}}
        self._ir.start()
        if self._depth is not None:
            self._depth.start()

    def camera(self) -> Intrinsics:
        mode = self._ir.get_video_mode()
        width, height = mode.resolutionX, mode.resolutionY
        fx = width / 2 / math.tan(self._ir.get_horizontal_fov() / 2)
        fy = height / 2 / math.tan(self._ir.get_vertical_fov() / 2)
        return Intrinsics(width, height, fx, fy, width / 2 - 0.5, height / 2 - 0.5)

    def rig(self) -> Rig:
        return device_rig(f"openni2_{Path(self.info['uri']).name}", self.camera(),
                          (PRIMESENSE_BASELINE, 0.0, 0.0))

    def settings(self) -> dict:
        camera_settings = self._ir.camera
        if camera_settings is None:
            return {}
        return {"exposure": camera_settings.get_exposure(), "gain": camera_settings.get_gain(),
                "auto_exposure": bool(camera_settings.get_auto_exposure())}

    def set_emitter(self, on: bool) -> None:
        if not self.can_switch_emitter:
            super().set_emitter(on)
        self._device.set_property(EMITTER_STATE, ctypes.c_int(int(on)))

    def read(self) -> DeviceFrame:
        try:
            frame = self._ir.read_frame()
            depth = self._depth.read_frame() if self._depth is not None else None
        except Exception as error:  # OpenNIError when the device is unplugged
            raise DeviceGone(f"{self.name}: no frame ({error})") from None
        ir = np.frombuffer(frame.get_buffer_as_uint16(), np.uint16).reshape(frame.height, frame.width).copy()
        metres = None
        if depth is not None:
            raw = np.frombuffer(depth.get_buffer_as_uint16(), np.uint16).reshape(depth.height, depth.width)
            metres = np.where(raw > 0, raw.astype(np.float32) * np.float32(0.001), np.nan).astype(np.float32)
        return DeviceFrame(ir, frame.timestamp / 1000.0, int(frame.frameIndex), None, metres)

    def close(self) -> None:
        for stream in (self._ir, self._depth):
            if stream is not None:
                stream.stop()
        self._device.close()
