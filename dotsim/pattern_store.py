"""The projector pattern of a dataset: made at the projector's resolution, stored once as
DATASET/pattern.png, and referred to by every scene.json's `pattern` entry (docs/FORMAT.md)."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from dotsim.dataset.layout import PATTERN_FILE, FormatError, pattern_path
from dotsim.patterns import DotPattern, PatternError, generate_dot_pattern, load_pattern


def resample_pattern(pattern: DotPattern, width: int, height: int) -> DotPattern:
    """`pattern` at width x height px: itself when it has that size, else resampled (area averaging
    when shrinking, bilinear when enlarging), so one captured full-resolution pattern serves
    scaled-down rigs. params gains `resampled_from` ([width, height] of the source).

    Examples
    --------
    >>> big = generate_dot_pattern(80, 60, n_dots=100, seed=0)
    >>> small = resample_pattern(big, 40, 30)
    >>> small.image.shape, small.params["resampled_from"]
    ((30, 40), [80, 60])
    """
    import cv2

    if pattern.image.shape == (height, width):
        return pattern
    shrinking = pattern.image.shape[1] > width
    image = cv2.resize(pattern.image.astype(np.float32), (width, height),
                       interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)
    return DotPattern(image=np.clip(image, 0.0, 1.0), centres=None, source=pattern.source,
                      params={**pattern.params, "resampled_from": list(pattern.image.shape[::-1])})


def make_pattern(settings, width: int, height: int) -> DotPattern:
    """The projector pattern a config's [pattern] section asks for, at width x height px.

    settings: the section (generator.config.PatternConfig): `source` "procedural" (a Poisson-disc
    pattern from `density`, `min_spacing`, `dot_sigma`, `seed`) or "file" (the image at `path`,
    resampled by resample_pattern when its size differs). Raises PatternError naming the file.
    """
    if settings.source == "procedural":
        return generate_dot_pattern(width, height, density=settings.density,
                                    min_spacing=settings.min_spacing, dot_sigma=settings.dot_sigma,
                                    seed=settings.seed)
    return resample_pattern(load_pattern(settings.path), width, height)


def store_pattern(dataset_dir: str | os.PathLike, pattern: DotPattern) -> Path:
    """Write DATASET/pattern.png (16-bit PNG, atomically) unless it is there; returns its path.

    A rerun that finds the file keeps it when it holds the same pattern (same DotPattern.sha256)
    and raises FormatError naming the file when it holds another one: one dataset, one pattern.
    """
    path = pattern_path(dataset_dir)
    if path.exists():
        try:
            stored = load_pattern(path)
        except PatternError as error:
            raise FormatError(str(error)) from None
        if stored.sha256 != pattern.sha256:
            raise FormatError(
                f"{path}: holds another pattern ({stored.width}x{stored.height}, "
                f"sha256 {stored.sha256[:12]}) than {pattern.source} ({pattern.width}x{pattern.height}, "
                f"sha256 {pattern.sha256[:12]}); a dataset has one pattern")
    else:
        pattern.save_png(path)
    return path


def pattern_entry(pattern: DotPattern) -> dict:
    """scene.json's `pattern` entry for the pattern stored by store_pattern."""
    return {"source": pattern.source, "sha256": pattern.sha256, "file": PATTERN_FILE,
            "width": pattern.width, "height": pattern.height, "params": pattern.params}
