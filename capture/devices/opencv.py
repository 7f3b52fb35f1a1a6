"""A camera OpenCV can open (cv2.VideoCapture): a UVC IR camera by index, or a video file.

It cannot switch a projector or measure depth: every frame is a projector-on frame as it comes
(a home-built projector stays on; record projector-off frames separately, or in a dark room
leave them out). It reports no calibration, so recording needs --rig. Colour frames whose three
channels are equal (how UVC greyscale and greyscale videos arrive) keep one channel; others are
converted with cv2.COLOR_BGR2GRAY.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from capture.devices import Device, DeviceError, DeviceFrame, DeviceGone


class OpenCVDevice(Device):
    def __init__(self, source: str, *, size: tuple[int, int] | None = None, fps: int | None = None,
                 exposure: float | None = None, gain: float | None = None):
        self.name = f"opencv:{source}"
        self._is_camera = source.isdigit()
        if not self._is_camera and not Path(source).is_file():
            raise DeviceError(f"--device {self.name}: no such video file; allowed: opencv:INDEX (a camera "
                              "number: 0, 1, ...) or opencv:PATH (an existing video file)")
        self._capture = cv2.VideoCapture(int(source) if self._is_camera else source)
        if not self._capture.isOpened():
            raise DeviceError(f"--device {self.name}: OpenCV cannot open this "
                              f"{'camera (no such device?)' if self._is_camera else 'video file'}")
        settings = ((cv2.CAP_PROP_FRAME_WIDTH, size and size[0]),
                    (cv2.CAP_PROP_FRAME_HEIGHT, size and size[1]),
                    (cv2.CAP_PROP_FPS, fps), (cv2.CAP_PROP_EXPOSURE, exposure), (cv2.CAP_PROP_GAIN, gain))
        if self._is_camera:
            self._capture.set(cv2.CAP_PROP_AUTO_EXPOSURE, 1)  # V4L2: 1 = manual exposure
            for key, value in settings:
                if value is not None:
                    self._capture.set(key, float(value))
        elif exposure is not None or gain is not None:
            raise DeviceError(f"--device {self.name}: a video file has no exposure or gain to set")
        self._count = 0
        self._first = self.read()  # learn the frame size and sample type now
        height, width = self._first.ir.shape
        if size is not None and (width, height) != tuple(size):
            raise DeviceError(f"--device {self.name}: gives {width}x{height} frames, not "
                              f"{size[0]}x{size[1]}; "
                              f"allowed: --size {width}x{height}")
        self.white_level = float(np.iinfo(self._first.ir.dtype).max)
        self.info = {"kind": "opencv", "source": source, "backend": self._capture.getBackendName(),
                     "stream": {"width": width, "height": height,
                                "fps": float(self._capture.get(cv2.CAP_PROP_FPS))}}

    def settings(self) -> dict:
        if not self._is_camera:
            return {}
        return {"exposure": float(self._capture.get(cv2.CAP_PROP_EXPOSURE)),
                "gain": float(self._capture.get(cv2.CAP_PROP_GAIN)),
                "auto_exposure": float(self._capture.get(cv2.CAP_PROP_AUTO_EXPOSURE))}

    def read(self) -> DeviceFrame:
        if getattr(self, "_first", None) is not None:
            frame, self._first = self._first, None
            return frame
        ok, image = self._capture.read()
        if not ok:
            raise DeviceGone(f"{self.name}: " + ("no frame (unplugged?)" if self._is_camera
                                                 else f"end of the video file after {self._count} frames"))
        if image.ndim == 3:
            same = all(np.array_equal(image[..., 0], image[..., k]) for k in range(1, image.shape[2]))
            image = image[..., 0].copy() if same else cv2.cvtColor(image, cv2.COLOR_BGR2GRAY)
        self._count += 1
        return DeviceFrame(image, float(self._capture.get(cv2.CAP_PROP_POS_MSEC)), self._count - 1)

    def close(self) -> None:
        self._capture.release()
