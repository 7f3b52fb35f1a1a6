"""The channels of a frame, declared once: name, dtype as read, what makes it, how it is shown.

The dataset format (dotsim.dataset: the EXR codec and scene.json's channel list), the generator's
post-render (generator/post_render.py), `dotsim show` and `dotsim view` read CHANNELS instead of
keeping lists of their own, so a new channel is one entry here and its description in
docs/FORMAT.md. The order of CHANNELS is the order frames are read and drawn in.

>>> [c.name for c in CHANNELS if c.source == "derived"]
['disparity', 'stereo_disparity']
>>> CHANNEL["ir"].dtype, CHANNEL["visibility"].dtype
(dtype('float16'), dtype('uint8'))
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

# What makes a channel:
SOURCES = {
    "sensor model": "the post-render: a rendered signal through the IR sensor model",
    "render": "the post-render: a rendered pass as Cycles gave it",
    "mask": "the post-render: a 0 / 1 mask (stored as UINT, read as uint8)",
    "ground truth": "the post-render: computed from the rendered depth and the rig, stored",
    "derived": "the reader: computed from `depth` and the rig in the frame's header, never stored",
    "device": "a depth camera's own output, never ground truth: a real sensor's (dotsim capture record) or, "
              "with [device_depth] on, the post-render's simulation of its chip (dotsim.device_depth)",
}
# How `dotsim show` (and `dotsim view`) draw a channel; None: not drawn.
DISPLAYS = {
    "linear": "grey, linear on the sensor's full scale",
    "radiance": "grey, the square root of value / its 99th percentile (radiance falls as 1 / r^2)",
    "colour": "turbo colour map over the frames' range, in `unit`, black where there is no value",
    "mask": "white where 1",
}


@dataclass(frozen=True)
class Channel:
    """One channel of a frame (docs/FORMAT.md describes each), checked when made.

    dtype: as read_frame returns it; source: what makes it (SOURCES); display: how it is drawn
    (DISPLAYS, or None); title and meaning: the two lines `dotsim show` writes above its column;
    unit: of a colour-mapped channel; stereo: only frames rendered from the rig's stereo pair have
    it; since: the format version that added it (a frame records the oldest version that has all
    of its channels, dotsim.dataset.frames.frame_format_version).
    """

    name: str
    dtype: np.dtype
    source: str
    display: str | None
    title: str
    meaning: str
    unit: str = ""
    stereo: bool = False
    since: str = "1.0"

    def __post_init__(self) -> None:
        object.__setattr__(self, "dtype", np.dtype(self.dtype))
        if self.source not in SOURCES:
            raise ValueError(f"channel {self.name!r}: source {self.source!r}; allowed: {', '.join(SOURCES)}")
        if self.display is not None and self.display not in DISPLAYS:
            raise ValueError(f"channel {self.name!r}: display {self.display!r}; allowed: "
                             f"{', '.join(DISPLAYS)} or None")
        if (self.source == "mask") != (self.dtype == np.uint8):
            raise ValueError(f"channel {self.name!r}: masks, and only masks, are uint8")
        if (self.display == "colour") != bool(self.unit):
            raise ValueError(f"channel {self.name!r}: a colour-mapped channel, and only one, has a unit")


CHANNELS: tuple[Channel, ...] = (
    Channel("ir", np.float16, "sensor model", "linear", "IR", "what the sensor sees"),
    Channel("ambient", np.float16, "render", "radiance", "ambient", "projector off"),
    Channel("flood", np.float16, "render", "radiance", "flood", "uniform projector"),
    Channel("depth", np.float32, "render", "colour", "depth", "ground truth", "m"),
    Channel("visibility", np.uint8, "mask", "mask", "visibility", "white: dots seen"),
    Channel("edge", np.uint8, "mask", "mask", "edge", "white: depth edge"),
    Channel("projector_column", np.float32, "ground truth", "colour", "projector column", "ground truth",
            "projector px"),
    Channel("disparity", np.float32, "derived", "colour", "disparity", "ground truth", "camera px"),
    # A depth camera's own depth: a real sensor's beside recordings, or the simulated device's beside
    # rendered frames ([device_depth] on): its estimate, never ground truth (which is "depth").
    Channel("device_depth", np.float32, "device", "colour", "device depth", "the sensor's estimate", "m",
            since="1.1"),
    # The rig's second IR camera (the right one of a rectified pair), and stereo ground truth on the
    # left image.
    Channel("ir_right", np.float16, "sensor model", "linear", "IR right", "the second camera", stereo=True,
            since="2.1"),
    Channel("stereo_visibility", np.uint8, "mask", "mask", "stereo visibility", "white: both see it, lit",
            stereo=True, since="2.1"),
    Channel("stereo_disparity", np.float32, "derived", "colour", "stereo disparity", "ground truth",
            "camera px", stereo=True, since="2.1"),
)
CHANNEL: dict[str, Channel] = {c.name: c for c in CHANNELS}

# What the generator writes: every channel but a device's own, for a stereo pair STEREO_CHANNELS too, and
# with the simulated device's depth engine on DEVICE_CHANNELS.
RENDERED_CHANNELS = tuple(c.name for c in CHANNELS if c.source != "device" and not c.stereo)
DEVICE_CHANNELS = tuple(c.name for c in CHANNELS if c.source == "device")
STEREO_CHANNELS = tuple(c.name for c in CHANNELS if c.stereo)
MASK_CHANNELS = tuple(c.name for c in CHANNELS if c.source == "mask")
DERIVED_CHANNELS = tuple(c.name for c in CHANNELS if c.source == "derived")


def rendered_channels(stereo: bool, device: bool = False) -> tuple[str, ...]:
    """The channels the generator writes for a frame of one camera, or (stereo) of the stereo pair, and
    (device) with the simulated device's own depth."""
    return RENDERED_CHANNELS + (STEREO_CHANNELS if stereo else ()) + (DEVICE_CHANNELS if device else ())


def stored_channels(channels) -> tuple[str, ...]:
    """The channels of `channels` a frame file stores (the derived ones are computed on read)."""
    return tuple(name for name in channels if name not in DERIVED_CHANNELS)
