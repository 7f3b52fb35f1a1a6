"""Frame EXRs and the common readers: bytes, encode and decode time of each compression a dataset's frames
may have ([output] exr_compression), and what OpenCV, imageio and the OpenEXR package read of them.

    python -m bench.exr_readability [--data out/dataset] [--frames 8] [--repeats 3] [--json OUT.json]

Takes the first --frames frames of a dataset folder as dotsim.dataset.read_frame returns them and writes
each again with every compression of dotsim.dataset.EXR_COMPRESSIONS and three namings of its channels:
as stored (`ir`, `depth`, ...), as standard layer names (`ir.Y`, `depth.Y`, ...: OpenEXR's layer.channel
convention for grey layers), and with the IR as the default layer's plain `Y` (the other channels as
layers), the one grey channel OpenCV's reader takes. Per (compression, naming) it prints the bytes per
frame, the CPU seconds (all threads) to encode and to decode a frame with the OpenEXR package (medians of
--repeats), and what each reader gives back: `cv2.imread(path, cv2.IMREAD_UNCHANGED)` with
OPENCV_IO_ENABLE_OPENEXR=1 (set here before cv2 is imported), `imageio.v3.imread(path)`, and
`OpenEXR.File(path, separate_channels=True)`: "all" (every channel, bit for bit), "ir" (one array,
equal to the IR), "other ..." (an array that is not the IR) or "no" (None or an exception). Sizes and
what is readable do not depend on the machine's load; times do (run it on an idle machine).
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")  # before cv2 is imported, anywhere
os.environ.setdefault("OPENCV_LOG_LEVEL", "SILENT")  # its "can't read header" lines for every file

import argparse  # noqa: E402 (after the variable OpenCV reads once)
import io  # noqa: E402
import json  # noqa: E402
import tempfile  # noqa: E402
import warnings  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402

from bench.generate_stages import median_run  # noqa: E402
from dotsim import dataset as ds  # noqa: E402

NAMINGS = {
    "as stored": lambda name: name,
    "layers (NAME.Y)": lambda name: f"{name}.Y",
    "IR as Y, layers": lambda name: "Y" if name == "ir" else f"{name}.Y",
}
# The EXR pixel type of each channel as dotsim stores it (masks: UINT, 32-bit).
STORED_DTYPE = {"visibility": np.uint32, "edge": np.uint32}


def stored_pixels(frame: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """A frame's stored channels (no derived ones) in their EXR pixel types."""
    return {name: np.ascontiguousarray(array.astype(STORED_DTYPE.get(name, array.dtype)))
            for name, array in frame.items() if name not in ds.DERIVED_CHANNELS}


def encode(pixels: dict[str, np.ndarray], compression: str, naming) -> bytes:
    """The bytes of a single-part scanline EXR of `pixels` with its channels renamed by `naming`."""
    import OpenEXR

    header = {"compression": getattr(OpenEXR, compression), "type": OpenEXR.scanlineimage}
    stream = io.BytesIO()
    OpenEXR.File(header, {naming(name): array for name, array in pixels.items()}).write(stream)
    return stream.getvalue()


def decode(data: bytes) -> dict[str, np.ndarray]:
    """Every channel of an EXR by the OpenEXR package."""
    import OpenEXR

    return {name: channel.pixels for name, channel in
            OpenEXR.File(io.BytesIO(data), separate_channels=True).channels().items()}


def image_read(array, ir: np.ndarray) -> str:
    """What an image reader's result holds: 'no' (nothing), 'ir' (the IR, value for value) or
    'other DTYPE SHAPE' (an array that is not the IR: e.g. an 8-bit rendering of it)."""
    if array is None:
        return "no"
    array = np.asarray(array)
    if array.shape == ir.shape and np.array_equal(array.astype(np.float32), ir.astype(np.float32)):
        return "ir"
    return f"other {array.dtype} {'x'.join(map(str, array.shape))}"


def readers(path: Path, pixels: dict[str, np.ndarray], naming) -> dict[str, str]:
    """What cv2, imageio and OpenEXR read of the file at `path`: image_read's answer for the two image
    readers; 'all' or 'no' for OpenEXR (every channel bit for bit under its name, or not)."""
    import cv2
    import imageio.v3 as iio

    results = {"cv2": image_read(cv2.imread(str(path), cv2.IMREAD_UNCHANGED), pixels["ir"])}
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            results["imageio"] = image_read(iio.imread(path), pixels["ir"])
    except Exception:  # imageio raises whatever its plugins raise
        results["imageio"] = "no"
    found = decode(path.read_bytes())
    results["OpenEXR"] = "all" if all(naming(name) in found and np.array_equal(found[naming(name)], array)
                                      for name, array in pixels.items()) else "no"
    return results


def measure(frames: list[dict], repeats: int, folder: Path) -> list[dict]:
    """One row per (compression, naming): bytes and CPU seconds per frame, and what each reader reads."""
    rows = []
    pixels = [stored_pixels(frame) for frame in frames]
    for key, compression in ds.EXR_COMPRESSIONS.items():
        for label, naming in NAMINGS.items():
            files = [encode(p, compression, naming) for p in pixels]
            path = folder / f"{key}-{len(rows)}.exr"
            path.write_bytes(files[0])
            rows.append({
                "compression": key, "names": label, "bytes": sum(map(len, files)) / len(files),
                "encode_s": median_run(lambda c=compression, n=naming: [encode(p, c, n) for p in pixels],
                                       repeats)[1] / len(files),
                "decode_s": median_run(lambda files=files: [decode(d) for d in files],
                                       repeats)[1] / len(files),
                **readers(path, pixels[0], naming)})
    return rows


def table(rows: list[dict]) -> str:
    lines = ["| compression | channel names | MB per frame | encode s | decode s | cv2 | imageio | OpenEXR |",
             "|---|---|---|---|---|---|---|---|"]
    lines += [f"| {r['compression']} | {r['names']} | {r['bytes'] / 1e6:.3f} | {r['encode_s']:.4f} | "
              f"{r['decode_s']:.4f} | {r['cv2']} | {r['imageio']} | {r['OpenEXR']} |" for r in rows]
    return "\n".join(lines)


def first_frames(data: Path, count: int) -> tuple[list[dict], tuple[int, int]]:
    """The first `count` frames of a dataset folder (read_frame, checked) and their (width, height)."""
    try:
        paths = [path for ref in ds.open_dataset(data).scenes for path in ref.frame_paths][:count]
    except ds.FormatError as error:
        raise SystemExit(f"bench.exr_readability: {error}") from None
    if not paths:
        raise SystemExit(f"bench.exr_readability: {data}: no frames")
    frames = [ds.read_frame(path) for path in paths]
    height, width = frames[0]["ir"].shape
    return frames, (width, height)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=Path("out/dataset"),
                        help="a sealed dataset folder, its first frames are used (default out/dataset: `make "
                        "dataset`'s)")
    parser.add_argument("--frames", type=int, default=8, help="frames to measure (default 8)")
    parser.add_argument("--repeats", type=int, default=3, help="timing repeats, median taken (default 3)")
    parser.add_argument("--json", type=Path, default=None, help="also write the rows as JSON")
    args = parser.parse_args(argv)
    frames, (width, height) = first_frames(args.data, args.frames)
    with tempfile.TemporaryDirectory() as folder:
        rows = measure(frames, args.repeats, Path(folder))
    print(f"{len(frames)} frame(s) of {args.data}, {width} x {height}, channels "
          f"{sorted(stored_pixels(frames[0]))}; CPU s per frame (all threads), medians of {args.repeats}")
    print(table(rows))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
