"""Live sensors behind one small interface: a Device gives IR frames, switches its projector where it
can, reports its own depth and calibration where it has them.

Backends, one module each: realsense (pyrealsense2, extra `realsense`), openni2 (openni, extra
`openni2`), opencv (cv2.VideoCapture: a UVC camera by index or a video file). `open_device` parses
the --device argument and opens the backend; a missing extra is a one-line DeviceError naming it.
"""

from __future__ import annotations

import importlib
from dataclasses import dataclass, replace

import numpy as np

from capture.frames import CaptureError
from dotsim.rig.geometry import DEFAULT_MAX_DEPTH, Intrinsics, Rig

DEVICE_KINDS = ("realsense", "openni2", "opencv")
DEVICE_SYNTAX = "realsense[:SERIAL], openni2[:URI], opencv:INDEX or opencv:PATH"


class DeviceError(CaptureError):
    """No device, an unknown serial, a stream mode the device lacks, a missing extra."""


class DeviceGone(DeviceError):
    """The device stopped giving frames (unplugged, end of a video file, timeout)."""


@dataclass(frozen=True)
class DeviceFrame:
    """One IR frame as the device gave it.

    ir: raw 2-D image (uint8 / uint16); depth: the device's own depth in metres (float32, nan =
    no reading) or None; emitter: the projector state the frame reports (metadata) or None when
    it does not say; timestamp_ms and frame_number as the device counts them; ir_right: the right IR
    camera's image of the same frame when the device records its stereo pair, else None.
    """

    ir: np.ndarray
    timestamp_ms: float
    frame_number: int
    emitter: bool | None = None
    depth: np.ndarray | None = None
    ir_right: np.ndarray | None = None


class Device:
    """What recording needs from a sensor; each backend fills it in.

    name: "kind:id" as given to --device; info: model, serial, firmware, stream mode (JSON-safe);
    white_level: the raw value of a saturated pixel; can_switch_emitter, has_depth: capabilities;
    stereo: it gives the right IR camera's image of every frame too (opened so: a RealSense with
    --stereo).
    """

    name: str
    info: dict
    white_level: float
    can_switch_emitter: bool = False
    has_depth: bool = False
    stereo: bool = False

    def camera(self) -> Intrinsics | None:
        """The IR camera's intrinsics as the device reports them, or None when it reports none."""
        return None

    def rig(self) -> Rig:
        """The device's rig (dotsim.rig.files.device_rig); DeviceError when it has no calibration."""
        raise DeviceError(f"{self.name}: the device reports no calibration; calibrate it "
                          f"(cv2.stereoCalibrate) and pass the rig file with --rig (docs/GEOMETRY.md)")

    def settings(self) -> dict:
        """Exposure, gain and projector settings as read back from the device (JSON-safe)."""
        return {}

    def set_emitter(self, on: bool) -> None:
        raise DeviceError(f"{self.name}: this device cannot switch its projector")

    def read(self) -> DeviceFrame:
        """The next frame; DeviceGone when the device stops giving frames."""
        raise NotImplementedError

    def close(self) -> None:
        pass

    def __enter__(self) -> Device:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def device_rig_file(device: Device, max_depth: float = DEFAULT_MAX_DEPTH) -> tuple[Rig, bytes]:
    """The device's rig with this max_depth, checked (dotsim.rig.files.check_rig), and the bytes of its
    rig file: {"rig": ..., "device": info, settings, white level, capabilities} (`capture info`)."""
    from dotsim.rig.files import check_rig, rig_file_json

    rig = replace(device.rig(), max_depth=max_depth)
    check_rig(rig, device.name)
    info = {**device.info, "settings": device.settings(), "white_level": device.white_level,
            "can_switch_emitter": device.can_switch_emitter, "has_depth": device.has_depth}
    return rig, rig_file_json(rig, device=info)


def require_extra(module: str, extra: str, kind: str):
    """Import an optional dependency or raise a one-line DeviceError naming the extra to install."""
    try:
        return importlib.import_module(module)
    except ImportError as error:
        raise DeviceError(f"--device {kind}: needs the Python package {module.split('.')[0]!r} "
                          f"({error}); install it with: pip install 'dotsim[{extra}]'") from None


def parse_device(spec: str) -> tuple[str, str]:
    """(kind, id) of a --device argument; DeviceError listing the syntax otherwise."""
    kind, _, ident = spec.partition(":")
    if kind not in DEVICE_KINDS:
        raise DeviceError(f"--device {spec!r}: unknown device kind {kind!r}; allowed: {DEVICE_SYNTAX}")
    if kind == "opencv" and not ident:
        raise DeviceError(f"--device {spec!r}: opencv needs a camera index or a video file; allowed: "
                          "opencv:INDEX or opencv:PATH")
    return kind, ident


def open_device(spec: str, *, size: tuple[int, int] | None = None, fps: int | None = None,
                exposure: float | None = None, gain: float | None = None, ir_format: str = "y8",
                stereo: bool = False) -> Device:
    """Open the device named by --device (DEVICE_SYNTAX) with an optional stream mode (width, height,
    fps; ir_format y8 / y16 for a RealSense), fixed exposure / gain and (stereo, a RealSense) both IR
    streams. Raises DeviceError naming the device and what is allowed."""
    kind, ident = parse_device(spec)
    for option, value, default in (("--ir-format", ir_format, "y8"), ("--stereo", stereo, False)):
        if value != default and kind != "realsense":
            raise DeviceError(f"{option}: only a RealSense offers it; leave it out for {kind}")
    if kind == "realsense":
        from capture.devices.realsense import open_realsense

        return open_realsense(ident, size=size, fps=fps, exposure=exposure, gain=gain, ir_format=ir_format,
                              stereo=stereo)
    if kind == "openni2":
        from capture.devices.openni2 import open_openni2

        return open_openni2(ident, size=size, fps=fps, exposure=exposure, gain=gain)
    from capture.devices.opencv import OpenCVDevice

    return OpenCVDevice(ident, size=size, fps=fps, exposure=exposure, gain=gain)
