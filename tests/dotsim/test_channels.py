"""The channels' one declaration: its examples run, bad entries are refused, and the dataset format
follows it (`dotsim show` and `dotsim view` do too: tests/commands/)."""

import doctest

import numpy as np
import pytest

from dotsim import channels
from dotsim import dataset as ds
from dotsim.channels import CHANNELS, Channel


def test_examples_run():
    result = doctest.testmod(channels)
    assert result.attempted > 0 and result.failed == 0


@pytest.mark.parametrize("kwargs, message", [
    ({"source": "camera"}, "source 'camera'; allowed: sensor model"),
    ({"display": "rainbow"}, "display 'rainbow'; allowed: linear"),
    ({"dtype": np.uint8}, "masks, and only masks, are uint8"),
    ({"display": "colour"}, "a colour-mapped channel, and only one, has a unit"),
    ({"source": "labels"}, "labels, and only labels, are int32"),
    ({"switch": "colour"}, "switch 'colour'; allowed: labels, normals"),
    ({"camera": "thermal"}, "camera 'thermal'; allowed: ir, colour"),
])
def test_a_bad_channel_is_refused_naming_it(kwargs, message):
    fields = {"name": "x", "dtype": np.float16, "source": "render", "display": "linear", "title": "x",
              "meaning": "x", **kwargs}
    with pytest.raises(ValueError, match=message):
        Channel(**fields)


def test_the_format_follows_the_declaration():
    assert ds.FRAME_CHANNELS == {c.name: c.dtype for c in CHANNELS}
    assert ds.MASK_CHANNELS == ("visibility", "edge", "stereo_visibility", "transparent_or_mirror")
    assert ds.DERIVED_CHANNELS == ("disparity", "stereo_disparity")
    assert ds.RENDERED_CHANNELS == ("ir", "ambient", "flood", "depth", "visibility", "edge",
                                    "projector_column", "disparity")
    assert channels.rendered_channels(stereo=True) == ds.RENDERED_CHANNELS + (
        "ir_right", "stereo_visibility", "stereo_disparity")
    assert channels.rendered_channels(False, ("labels", "normals")) == ds.RENDERED_CHANNELS + (
        "instance", "material", "transparent_or_mirror", "normal_x", "normal_y", "normal_z")
    assert channels.rendered_channels(False, ("rgb",)) == ds.RENDERED_CHANNELS + ("rgb",)
    assert channels.OWN_SHAPE_CHANNELS == ("rgb",) and channels.CHANNEL["rgb"].shape_suffix == (3,)
    with pytest.raises(ValueError, match="switch 'colour'; allowed: labels, normals"):
        channels.rendered_channels(False, ("colour",))
