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
    scaled-down rigs. params gains `resampled_from` ([width, height] of the source). A pattern of
    another aspect ratio (more than a pixel off after scaling) does not fit the projector and
    raises PatternError.

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
    if abs(pattern.width * height / pattern.height - width) > 1.0:
        raise PatternError(f"{pattern.source}: pattern is {pattern.width}x{pattern.height} px, which does "
                           f"not fit the rig's projector of {width}x{height} px (another aspect ratio); "
                           "allowed: a pattern of the projector's size, or scaled with the same aspect ratio")
    shrinking = pattern.image.shape[1] > width
    image = cv2.resize(pattern.image.astype(np.float32), (width, height),
                       interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)
    return DotPattern(image=np.clip(image, 0.0, 1.0), centres=None, source=pattern.source,
                      params={**pattern.params, "resampled_from": list(pattern.image.shape[::-1])})


def make_pattern(settings, width: int, height: int) -> DotPattern:
    """The projector pattern a config's [pattern] section asks for, at width x height px.

    settings: the section (generator.config.PatternConfig): `source` "procedural" (a Poisson-disc
    pattern from `density`, `min_spacing`, `dot_sigma`, `seed`) or "file" (the image at `path`,
    resampled by resample_pattern when its size differs). Raises PatternError naming the file,
    also for a file with almost no signal (check_pattern_signal).
    """
    if settings.source == "procedural":
        return generate_dot_pattern(width, height, density=settings.density,
                                    min_spacing=settings.min_spacing, dot_sigma=settings.dot_sigma,
                                    seed=settings.seed)
    pattern = load_pattern(settings.path)
    check_pattern_signal(pattern, settings.path)
    return resample_pattern(pattern, width, height)


# A pattern image's dots should reach full scale (the projector's power is scaled by the pattern
# value) and cover a visible share of it. Procedural patterns at the densities the config allows
# have 1-6% of pixels above half their peak; one dot in a whole image has about 0.001%.
MIN_PATTERN_PEAK = 1 / 16
MIN_LIT_SHARE = 1e-3


def check_pattern_signal(pattern: DotPattern, where) -> None:
    """Refuse a pattern with almost no signal: a brightest pixel below MIN_PATTERN_PEAK of full
    scale, or fewer than MIN_LIT_SHARE of its pixels above half the brightest value.

    Examples
    --------
    >>> check_pattern_signal(generate_dot_pattern(64, 48, density=0.01, seed=0), "procedural")
    >>> one_dot = np.zeros((48, 64)); one_dot[10, 10] = 1 / 255
    >>> check_pattern_signal(DotPattern(one_dot), "one_dot.png")  # doctest: +ELLIPSIS
    Traceback (most recent call last):
    ...
    dotsim.patterns.PatternError: one_dot.png: brightest pixel is 0.0039 of full scale (below 1/16): ...
    """
    peak = float(pattern.image.max())
    if peak < MIN_PATTERN_PEAK:
        raise PatternError(f"{where}: brightest pixel is {peak:.4f} of full scale (below 1/16): almost "
                           f"no light; rescale the image so its dots reach full scale")
    lit = int((pattern.image > 0.5 * peak).sum())
    if lit < MIN_LIT_SHARE * pattern.image.size:
        raise PatternError(f"{where}: only {lit} of {pattern.image.size} pixels are above half the "
                           f"brightest value: almost no dots (at least {MIN_LIT_SHARE:.1%} of the pixels "
                           f"are needed; a dot pattern has a few percent)")


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
