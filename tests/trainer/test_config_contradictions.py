"""Trainer settings that cannot work are refused when they are read, in one line (issue 45 item 5):
[model] stride outside its choices (0 divided by zero, -1 failed after writing RUN/tb, 100 trained
silently), and a min_depth so close to the rig's max_depth that the tree has nothing to choose."""

from dataclasses import replace

import pytest

from dotsim.config_schema import ConfigError
from dotsim.rig.presets import get_preset
from trainer.config import config_from_dict, load_config
from trainer.model import MIN_FEASIBLE_LEAVES, build_model, feasible_positions

RIG = get_preset("structure_core").scaled(0.1)


@pytest.mark.parametrize("stride", [0, -1, 3, 100])
def test_a_stride_other_than_1_or_2_is_refused_at_load(stride):
    d = load_config("train_tiny").to_dict()
    d["model"]["stride"] = stride
    with pytest.raises(ConfigError, match=rf"t\.toml: \[model\] stride = {stride}: not a valid choice; "
                                          r"allowed: one of 1, 2$"):
        config_from_dict(d, "t.toml")


def test_min_depth_too_close_to_max_depth_is_refused_naming_the_nearest_that_works():
    """The span of the feasible columns, counted independently: leaves x (1 - 2 padding) x the
    normalised column difference of a point at min_depth and at max_depth on the optical axis."""
    cfg = load_config("train_tiny")
    leaves = 1
    for c in cfg.model.classes:
        leaves *= c
    proj = RIG.projector
    # the column of depth z on the camera's optical axis: projector fx * b / z px from its place at infinity
    span = lambda z: leaves * (1 - 2 * cfg.model.column_padding) * proj.fx * RIG.baseline * (  # noqa: E731
        1 / z - 1 / RIG.max_depth) / proj.width
    limit = 1 / (MIN_FEASIBLE_LEAVES / (span(1.0) / (1 - 1 / RIG.max_depth)) + 1 / RIG.max_depth)
    for min_depth in (19.9, 1.2 * limit):
        with pytest.raises(ConfigError, match=rf"min_depth = {min_depth:g} m is too close to the rig's "
                                              rf"max_depth 20 m.*allowed: 0 \(every class\) or at most"):
            feasible_positions(replace(cfg.model, min_depth=min_depth), RIG)
    assert feasible_positions(replace(cfg.model, min_depth=0.8 * limit), RIG) is not None
    assert build_model(replace(cfg, model=replace(cfg.model, min_depth=0.3)), RIG) is not None


def test_a_rig_of_another_max_depth_is_named_with_both_values():
    """Issue 45: a network trained on renders of a config's max_depth (20 m) was refused on data imported
    with the preset's rig (10 m) by a message naming only the key."""
    from trainer.checkpoint import check_rig
    from trainer.samples import DataError

    named = r"in \['max_depth'\] \(max_depth 10.0 here, 20.0 in the checkpoint\)"
    with pytest.raises(DataError, match=named):
        check_rig(RIG, replace(RIG, max_depth=10.0), "checkpoint", "captured")
