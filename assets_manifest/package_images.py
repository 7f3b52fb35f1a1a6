"""Photographs scikit-image ships inside its wheel, with their licenses.

Only images whose files are in the installed package are listed (no pooch download is ever made:
the builder reads the file from skimage/data/ directly, and reports the image as skipped if a
scikit-image build lacks it). Licenses are as stated in each skimage.data function's docstring.
"""

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class PackageImage:
    filename: str  # inside skimage/data/
    license: str


SKIMAGE_PHOTOS: dict[str, PackageImage] = {
    "astronaut": PackageImage("astronaut.png", "public domain (NASA; skimage.data.astronaut)"),
    "brick": PackageImage("brick.png", "CC0-1.0 (CC0Textures Bricks25; skimage.data.brick)"),
    "camera": PackageImage("camera.png", "CC0-1.0 (Lav Varshney; skimage.data.camera)"),
    "cell": PackageImage("cell.png", "CC0-1.0 (skimage.data.cell)"),
    "chelsea": PackageImage("chelsea.png", "CC0-1.0 (Stefan van der Walt; skimage.data.chelsea)"),
    "clock": PackageImage("clock_motion.png", "public domain (Stefan van der Walt; skimage.data.clock)"),
    "coffee": PackageImage("coffee.png", "CC0-1.0 (Rachel Michetti; skimage.data.coffee)"),
    "coins": PackageImage("coins.png", "no known copyright restrictions (skimage.data.coins)"),
    "grass": PackageImage("grass.png", "CC0-1.0 (CC0Textures Grass; skimage.data.grass)"),
    "gravel": PackageImage("gravel.png", "CC0-1.0 (CC0Textures Gravel04; skimage.data.gravel)"),
    "hubble_deep_field": PackageImage(
        "hubble_deep_field.jpg", "public domain (NASA; skimage.data.hubble_deep_field)"
    ),
    "immunohistochemistry": PackageImage(
        "ihc.png", "no known copyright restrictions (skimage.data.immunohistochemistry)"
    ),
    "microaneurysms": PackageImage(
        "microaneurysms.png", "CC0-1.0 (Andreas Maier; skimage.data.microaneurysms)"
    ),
    "retina": PackageImage("retina.jpg", "CC0-1.0 (Häggström; skimage.data.retina)"),
    "rocket": PackageImage("rocket.jpg", "public domain (SpaceX; skimage.data.rocket)"),
    "text": PackageImage("text.png", "public domain (skimage.data.text)"),
}


def skimage_image_path(name: str) -> Path:
    """Where the named photograph lies in the installed scikit-image (it may be missing)."""
    import skimage.data

    return Path(skimage.data.__file__).parent / SKIMAGE_PHOTOS[name].filename
