"""The trainer's test config: train_tiny at a size the tests train in seconds."""

from __future__ import annotations


def tiny_config(steps: int, **train):
    """The built-in train_tiny config with 64 x 48 crops, batch 2, `steps` steps and the given [train]
    keys."""
    from trainer.config import config_from_dict, load_config

    d = load_config("dotsim/configs/train_tiny.toml").to_dict()
    d["data"].update(crop_width=64, crop_height=48)
    d["train"].update(max_steps=steps, batch_size=2, checkpoint_every=1000, image_every=10, **train)
    return config_from_dict(d, "test config")
