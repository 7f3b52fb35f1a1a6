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
    "labels": "the post-render: integer labels from the render's object index pass (stored as UINT, "
              "read as int32)",
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
    "labels": "a colour of its own per label (dotsim.false_colour.label_colours), black for 0",
    "normal": "the three normal components as one colour tile, (n + 1) / 2 as red, green, blue, black "
              "where there is no surface; drawn in the column of normal_x",
    "colour image": "the colour image itself: linear radiance / its 99th percentile, sRGB-encoded, resized "
                    "to the IR camera's tile",
}
# The cameras whose images a frame's channels are, each with where its image size is read from. Channels
# of the IR camera share its (height, width); the colour camera's have their own (docs/FORMAT.md).
CAMERAS = {
    "ir": "the rig's IR camera: scene.json rig.camera",
    "colour": "the rig's colour camera ([render] rgb): scene.json colour_camera.intrinsics",
}
# The switches of the generator's config that add channels to a rendered frame, and what turns each on.
SWITCHES = {
    "labels": "[render] labels = true (or a transparent or metal object in the scene)",
    "normals": "[render] normals = true",
    "device_depth": "[device_depth] engine other than \"off\": the simulated device's depth "
                    "(dotsim.device_depth)",
    "rgb": "[render] rgb = true: the rig preset's colour camera (dotsim.rig.colour_camera)",
}


@dataclass(frozen=True)
class Channel:
    """One channel of a frame (docs/FORMAT.md describes each), checked when made.

    dtype: as read_frame returns it; source: what makes it (SOURCES); display: how it is drawn
    (DISPLAYS, or None); title and meaning: the two lines `dotsim show` writes above its column;
    unit: of a colour-mapped channel; stereo: only frames rendered from the rig's stereo pair have
    it; since: the format version that added it (a frame records the oldest version that has all
    of its channels, dotsim.dataset.frames.frame_format_version); switch: the switch (SWITCHES) without
    which the generator does not write it ("" for none); camera: whose image it is (CAMERAS), so whose
    (height, width) it has; components: the names of its last axis's entries ("RGB": an (H, W, 3) image),
    "" for a plain (H, W) channel.
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
    switch: str = ""
    camera: str = "ir"
    components: str = ""

    @property
    def shape_suffix(self) -> tuple[int, ...]:
        """What its arrays' shape adds to its camera's (height, width): (3,) for an RGB image."""
        return (len(self.components),) if self.components else ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "dtype", np.dtype(self.dtype))
        if self.source not in SOURCES:
            raise ValueError(f"channel {self.name!r}: source {self.source!r}; allowed: {', '.join(SOURCES)}")
        if self.display is not None and self.display not in DISPLAYS:
            raise ValueError(f"channel {self.name!r}: display {self.display!r}; allowed: "
                             f"{', '.join(DISPLAYS)} or None")
        if (self.source == "mask") != (self.dtype == np.uint8):
            raise ValueError(f"channel {self.name!r}: masks, and only masks, are uint8")
        if (self.source == "labels") != (self.dtype == np.int32):
            raise ValueError(f"channel {self.name!r}: labels, and only labels, are int32")
        if self.switch and self.switch not in SWITCHES:
            raise ValueError(f"channel {self.name!r}: switch {self.switch!r}; allowed: {', '.join(SWITCHES)}")
        if self.camera not in CAMERAS:
            raise ValueError(f"channel {self.name!r}: camera {self.camera!r}; allowed: {', '.join(CAMERAS)}")
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
            since="1.1", switch="device_depth"),
    # The rig's second IR camera (the right one of a rectified pair), and stereo ground truth on the
    # left image.
    Channel("ir_right", np.float16, "sensor model", "linear", "IR right", "the second camera", stereo=True,
            since="2.1"),
    Channel("stereo_visibility", np.uint8, "mask", "mask", "stereo visibility", "white: both see it, lit",
            stereo=True, since="2.1"),
    Channel("stereo_disparity", np.float32, "derived", "colour", "stereo disparity", "ground truth",
            "camera px", stereo=True, since="2.1"),
    # From the path-traced render's object index and normal passes ([render] labels, normals).
    Channel("instance", np.int32, "labels", "labels", "instance", "object + 1, 0: room", since="2.2",
            switch="labels"),
    Channel("material", np.int32, "labels", "labels", "material", "class (FORMAT.md)", since="2.2",
            switch="labels"),
    Channel("transparent_or_mirror", np.uint8, "mask", "mask", "glass / mirror", "white: first surface",
            since="2.2", switch="labels"),
    Channel("normal_x", np.float16, "render", "normal", "normals", "camera frame, RGB = xyz", since="2.2",
            switch="normals"),
    Channel("normal_y", np.float16, "render", None, "normal y", "camera frame", since="2.2",
            switch="normals"),
    Channel("normal_z", np.float16, "render", None, "normal z", "camera frame", since="2.2",
            switch="normals"),
    # The rig's colour camera ([render] rgb): its own image size and pose, visible light, no projector.
    Channel("rgb", np.float16, "render", "colour image", "colour", "visible light, own camera", since="2.3",
            switch="rgb", camera="colour", components="RGB"),
)
CHANNEL: dict[str, Channel] = {c.name: c for c in CHANNELS}

# What the generator writes: every channel without a switch, for a stereo pair STEREO_CHANNELS too, and
# those of each switch that is on (a device's own depth, without its switch, only real recordings have).
RENDERED_CHANNELS = tuple(c.name for c in CHANNELS if not c.stereo and not c.switch)
STEREO_CHANNELS = tuple(c.name for c in CHANNELS if c.stereo)
MASK_CHANNELS = tuple(c.name for c in CHANNELS if c.source == "mask")
LABEL_CHANNELS = tuple(c.name for c in CHANNELS if c.source == "labels")
DERIVED_CHANNELS = tuple(c.name for c in CHANNELS if c.source == "derived")
NORMAL_CHANNELS = ("normal_x", "normal_y", "normal_z")
# The channels with an image size of their own (another camera's than the IR camera's).
OWN_SHAPE_CHANNELS = tuple(c.name for c in CHANNELS if c.camera != "ir")


def rendered_channels(stereo: bool, switches=()) -> tuple[str, ...]:
    """The channels the generator writes for a frame of one camera, or (stereo) of the stereo pair, with
    the `switches` that are on (SWITCHES: [render] labels and normals, the simulated device's depth).

    >>> rendered_channels(False, ("normals",))[-3:]
    ('normal_x', 'normal_y', 'normal_z')
    >>> rendered_channels(True, ("device_depth",))[-1]
    'device_depth'
    """
    unknown = [name for name in switches if name not in SWITCHES]
    if unknown:
        raise ValueError(f"switch {unknown[0]!r}; allowed: {', '.join(SWITCHES)}")
    return (RENDERED_CHANNELS + (STEREO_CHANNELS if stereo else ())
            + tuple(c.name for c in CHANNELS if c.switch and c.switch in switches))


def stored_channels(channels) -> tuple[str, ...]:
    """The channels of `channels` a frame file stores (the derived ones are computed on read)."""
    return tuple(name for name in channels if name not in DERIVED_CHANNELS)
