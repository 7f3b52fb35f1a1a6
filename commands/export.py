"""`dotsim export DIR --format webdataset OUT`: a sealed dataset as WebDataset tar shards (the format and
how the shards are cut: dotsim/shards/writer.py)."""

from __future__ import annotations

import argparse
import math

from dotsim import dataset as ds
from dotsim.command_options import add_output_or_positional
from dotsim.option_types import integer
from dotsim.shards.format import PRECISIONS
from dotsim.shards.writer import TAR_BLOCK, export_webdataset


def parse_size(text: str) -> int:
    """'256M' -> 268435456; plain bytes or K/M/G (powers of 1024). argparse.ArgumentTypeError (a
    ValueError) naming the text and what is allowed, so that it serves as --shard-size's type.

    >>> parse_size("64M"), parse_size("1e3")
    (67108864, 1000)
    """
    units = {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30}
    t = str(text).strip().upper().removesuffix("B")
    try:
        number = float(t[:-1]) * units[t[-1]] if t and t[-1] in units else float(t)
        value = int(number) if math.isfinite(number) and number < 2**62 else None
    except ValueError:
        value = None
    if value is None:
        raise argparse.ArgumentTypeError(f"{text!r}: allowed: bytes, or a number with K, M or G, from "
                                         f"{TAR_BLOCK} bytes to 4 EB")
    if value < TAR_BLOCK:
        raise argparse.ArgumentTypeError(f"{text!r}: allowed: at least {TAR_BLOCK} bytes")
    return value


def run(args: argparse.Namespace) -> int:
    channels = [c.strip() for c in args.channels.split(",") if c.strip()] if args.channels else None
    result = export_webdataset(args.dataset, args.out, args.shard_size, args.split,
                               verify=not args.no_verify, channels=channels, precision=args.precision,
                               samples_per_shard=args.samples_per_shard, shards=args.shards)
    print(f"exported {result.line()}")
    return 0


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "export", help="write a dataset as WebDataset tar shards (for streaming from object storage)",
        description="Write the frames of a sealed dataset as WebDataset tar shards OUT/shard-NNNNNN.tar: "
        "one sample per frame (KEY.CHANNEL.png or KEY.CHANNEL.npy.gz per channel, KEY.frame.json, and "
        "KEY.scene.json.gz once per scene and shard; KEY = scene_SSSSSSS_frame_K), OUT/pattern.png, and "
        "OUT/index.json and OUT/SHA256SUMS with every shard's sha256. A rerun resumes an unfinished "
        "export. trainer.samples.Frames streams them (or the folder itself) into torch; `dotsim train "
        "--data` and `dotsim eval --data` take OUT, its shards or their URLs. docs/VIEWING.md has the "
        "sizes and the codecs.")
    parser.add_argument("dataset", metavar="DIR", help="sealed dotsim dataset directory")
    add_output_or_positional(parser, "folder for the shards (new, empty, or an unfinished export to resume)")
    parser.add_argument("--format", choices=("webdataset",), default="webdataset",
                        help="webdataset (the only one so far)")
    parser.add_argument("--channels", metavar="A,B,...",
                        help="channels to export (default: every stored one), e.g. "
                        "ir,projector_column,visibility,edge for training")
    parser.add_argument("--precision", choices=PRECISIONS, default="exact",
                        help="exact: every value as read (default); training: also the projector "
                        "column as a 16-bit fixed-point PNG, to 1/32 projector px (a seventh of its "
                        "lossless size)")
    size = parser.add_mutually_exclusive_group()
    size.add_argument("--shard-size", type=parse_size, default=None, metavar="BYTES",
                      help="most bytes of samples per shard, e.g. 64M, 1G (default 256M)")
    size.add_argument("--samples-per-shard", type=integer(1), default=None, metavar="N",
                      help="N samples (frames) per shard")
    size.add_argument("--shards", type=integer(1), default=None, metavar="N",
                      help="N shards whose sample counts differ by at most one (a multiple of the "
                      "loader's workers; at most the number of frames)")
    parser.add_argument("--split", default=None, help="export only the scenes of this split (default: all)")
    parser.add_argument("--no-verify", action="store_true", help="skip sha256 checks of the files read")
    parser.set_defaults(func=run, errors={ds.FormatError: 1, ValueError: 1})
    return parser
