"""What `dotsim capture import` and `capture record --device opencv:VIDEO` read, made for tests: random
8-bit IR frames in folders on/ and off/ (projector on and off), and the same frames as a lossless video."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np


def write_on_off_frames(root: Path, shape: tuple[int, int], seed: int, frames: int = 2,
                        video: Path | None = None) -> None:
    """`frames` random uint8 images of `shape` (h, w) in root/on and in root/off (frame_K.png), each also
    appended to the FFV1 video `video` when given (on frames, then off frames)."""
    rng = np.random.default_rng(seed)
    writer = None
    if video is not None:
        writer = cv2.VideoWriter(str(video), cv2.VideoWriter_fourcc(*"FFV1"), 30, shape[::-1], isColor=False)
        assert writer.isOpened()
    for name in ("on", "off"):
        (root / name).mkdir()
        for k in range(frames):
            image = rng.integers(0, 256, shape, dtype=np.uint8)
            assert cv2.imwrite(str(root / name / f"frame_{k}.png"), image)
            if writer is not None:
                writer.write(image)
    if writer is not None:
        writer.release()
