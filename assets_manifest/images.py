"""Greyscale texture images: conversion, validation and deterministic PNG encoding."""

import numpy as np

MIN_TEXTURE_SIZE = 8  # pixels per side; smaller images carry no usable texture


class ImageError(ValueError):
    """An image that cannot become a texture asset; says why."""


def to_grey(image: np.ndarray) -> np.ndarray:
    """(H,W) grey of an (H,W), (H,W,3) or (H,W,4) image in OpenCV's BGR(A) channel order, keeping the
    integer dtype; luminance weights as scikit-image's rgb2gray (Rec. 709). Alpha is dropped."""
    if image.ndim == 2:
        return image
    if image.ndim != 3 or image.shape[2] not in (3, 4):
        raise ImageError(f"unsupported image shape {image.shape}; expected (H,W), (H,W,3) or (H,W,4)")
    b, g, r = (image[..., i].astype(np.float64) for i in range(3))
    grey = 0.2125 * r + 0.7154 * g + 0.0721 * b
    if np.issubdtype(image.dtype, np.integer):
        return np.clip(np.round(grey), 0, np.iinfo(image.dtype).max).astype(image.dtype)
    return grey


def texture_from_image(image: np.ndarray) -> np.ndarray:
    """Validate a grey image and bring it to uint8 or uint16 (floats are taken as [0,1] and become
    uint16). Raises ImageError for tiny, non-finite or constant images."""
    if image.ndim != 2:
        raise ImageError(f"expected a grey (H,W) image, got shape {image.shape}")
    if min(image.shape) < MIN_TEXTURE_SIZE:
        raise ImageError(
            f"too small: {image.shape[1]}x{image.shape[0]} px (at least {MIN_TEXTURE_SIZE} per side)"
        )
    if image.dtype.kind == "f":
        if not np.isfinite(image).all():
            raise ImageError("pixels are not all finite (nan or inf)")
        image = np.round(np.clip(image, 0.0, 1.0) * 65535).astype(np.uint16)
    elif image.dtype not in (np.uint8, np.uint16):
        if image.min() < 0 or image.max() > 65535:
            raise ImageError(f"{image.dtype} pixel values outside 0..65535")
        image = image.astype(np.uint16)
    if image.min() == image.max():
        raise ImageError(f"constant image: every pixel is {image.flat[0]} (no texture)")
    return image


def png_bytes(image: np.ndarray) -> bytes:
    """PNG bytes of a uint8 or uint16 (H,W) image (OpenCV's encoder: no timestamps or text chunks,
    so the same pixels and OpenCV build give the same bytes)."""
    import cv2

    ok, encoded = cv2.imencode(".png", image)
    if not ok:
        raise ImageError("PNG encoding failed")
    return encoded.tobytes()
