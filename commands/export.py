"""`dotsim export DIR --format webdataset OUT`: a sealed dataset as WebDataset tar shards.

Each frame is one sample, its files named KEY.EXT (the WebDataset convention, so the `webdataset`
library and any tar reader see it): KEY = scene_SSSSSSS_frame_K, then

- KEY.CHANNEL.npy for every stored channel, the arrays dotsim.dataset.read_frame returns (same
  dtype and values, so a round trip is exact);
- KEY.scene.json: the scene's scene.json (rig, pattern, poses, config: what a reader needs);
- KEY.frame.json: scene_index, frame_index, split, and the source frame file and its sha256.

Shards OUT/shard-NNNNNN.tar hold whole samples, at most `shard_bytes` of tar members each (a sample
larger than that gets a shard of its own); scenes and frames keep the dataset's order. OUT/index.json,
written last, lists every shard with its sha256, size and sample count (OUT/SHA256SUMS the same
checksums for `sha256sum -c`). Every file is written under a temporary name and renamed when
complete. dotsim.data reads the shards back (streamed, or indexed for random access).
"""

from __future__ import annotations

import argparse
import io
import tarfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dotsim import __version__
from dotsim import dataset as ds
from dotsim.file_io import atomic_write_bytes, atomic_write_json, atomic_writer, json_bytes, sha256_file

WEBDATASET_FORMAT = "dotsim-webdataset"
WEBDATASET_VERSION = "1.0"
INDEX_NAME = "index.json"
SUMS_NAME = "SHA256SUMS"
DEFAULT_SHARD_BYTES = 256 << 20
_BLOCK = 512  # tar block: every member is a header block plus its data rounded up to blocks


def shard_file_name(n: int) -> str:
    return f"shard-{n:06d}.tar"


def sample_key(scene_index: int, frame_index: int) -> str:
    """The sample's WebDataset key (also `dotsim infer`'s output name for that frame)."""
    return f"{ds.scene_name(scene_index)}_frame_{frame_index}"


def npy_bytes(array: np.ndarray) -> bytes:
    stream = io.BytesIO()
    np.save(stream, np.ascontiguousarray(array), allow_pickle=False)
    return stream.getvalue()


def sample_files(meta: dict, frame_index: int, frame: dict[str, np.ndarray],
                 source: tuple[str, str]) -> list[tuple[str, bytes]]:
    """(member name, bytes) of one frame's sample; source = (frame file, its sha256)."""
    key = sample_key(meta["scene_index"], frame_index)
    files = [(f"{key}.{name}.npy", npy_bytes(frame[name])) for name in frame]
    files.append((f"{key}.scene.json", json_bytes(meta)))
    files.append((f"{key}.frame.json", json_bytes({
        "scene_index": meta["scene_index"], "frame_index": frame_index, "split": meta["split"],
        "file": source[0], "sha256": source[1]})))
    return files


def tar_bytes_of(files: list[tuple[str, bytes]]) -> int:
    """Bytes the files take as tar members (header block + data padded to whole blocks)."""
    return sum(_BLOCK + -(-len(data) // _BLOCK) * _BLOCK for _, data in files)


def _add(tar: tarfile.TarFile, name: str, data: bytes) -> None:
    info = tarfile.TarInfo(name)  # mtime 0, uid 0, mode 0o644: the same data gives the same bytes
    info.size, info.mode = len(data), 0o644
    tar.addfile(info, io.BytesIO(data))


def parse_size(text: str) -> int:
    """'256M' -> 268435456; plain bytes or K/M/G (powers of 1024). ValueError naming the text."""
    units = {"K": 1 << 10, "M": 1 << 20, "G": 1 << 30}
    t = str(text).strip().upper().removesuffix("B")
    try:
        value = int(float(t[:-1]) * units[t[-1]]) if t and t[-1] in units else int(t)
    except ValueError:
        raise ValueError(f"shard size {text!r}: give bytes, or a number with K, M or G") from None
    if value < _BLOCK:
        raise ValueError(f"shard size {text!r}: at least {_BLOCK} bytes")
    return value


@dataclass
class ExportResult:
    out: Path
    shards: list[dict]

    def line(self) -> str:
        samples = sum(s["samples"] for s in self.shards)
        size = sum(s["bytes"] for s in self.shards)
        return f"{samples} sample(s) in {len(self.shards)} shard(s), {size / 1e6:.1f} MB, in {self.out}"


class _ShardWriter:
    """Writes samples into shard-NNNNNN.tar files of at most shard_bytes of members each."""

    def __init__(self, out: Path, shard_bytes: int):
        self.out, self.shard_bytes = out, shard_bytes
        self.shards: list[dict] = []
        self._context = self._stream = self._tar = None
        self._used = self._samples = 0

    def add(self, files: list[tuple[str, bytes]]) -> None:
        size = tar_bytes_of(files)
        if self._tar is not None and self._used + size > self.shard_bytes:
            self.close()
        if self._tar is None:
            name = shard_file_name(len(self.shards))
            self._context = atomic_writer(self.out / name)
            self._stream = self._context.__enter__()
            self._tar = tarfile.open(fileobj=self._stream, mode="w", format=tarfile.USTAR_FORMAT)
            self._used = self._samples = 0
        for name, data in files:
            _add(self._tar, name, data)
        self._used += size
        self._samples += 1

    def close(self) -> None:
        if self._tar is None:
            return
        self._tar.close()
        self._context.__exit__(None, None, None)
        path = self.out / shard_file_name(len(self.shards))
        self.shards.append({"name": path.name, "sha256": sha256_file(path), "bytes": path.stat().st_size,
                            "samples": self._samples})
        self._tar = None

    def abort(self, error: BaseException) -> None:
        if self._tar is not None:
            self._context.__exit__(type(error), error, error.__traceback__)  # removes the temporary
            self._tar = None


def export_webdataset(dataset_dir: str | Path, out: str | Path, shard_bytes: int = DEFAULT_SHARD_BYTES,
                      split: str | None = None, verify: bool = True) -> ExportResult:
    """Write the scenes of `split` (None: all) of the sealed dataset as shards in `out` (see the
    module docstring); `out` must not hold an export already."""
    source = ds.open_dataset(dataset_dir, verify=verify)
    out = Path(out)
    if (out / INDEX_NAME).exists() or (out.is_dir() and any(out.glob("shard-*.tar"))):
        raise ds.FormatError(f"{out}: already holds an export (index.json or shard-*.tar); choose an "
                             f"empty or new folder")
    scenes = source.scenes if split is None else source.split(split)
    if not scenes:
        raise ds.FormatError(f"{dataset_dir}: no scenes to export (split {split!r})")
    out.mkdir(parents=True, exist_ok=True)
    writer = _ShardWriter(out, shard_bytes)
    channels: list[str] = []
    try:
        for ref in scenes:
            meta = ds.read_scene_meta(ref.path, verify=verify)
            channels = channels or list(meta["channels"])
            for k, entry in enumerate(meta["frames"]):
                frame = ds.read_frame(ref.path / entry["file"], verify=verify, meta=meta)
                writer.add(sample_files(meta, k, frame, (entry["file"], entry["sha256"])))
        writer.close()
    except BaseException as error:
        writer.abort(error)
        raise
    shards = writer.shards
    atomic_write_bytes(out / SUMS_NAME, "".join(f"{s['sha256']}  {s['name']}\n" for s in shards).encode())
    atomic_write_json(out / INDEX_NAME, {
        "format": WEBDATASET_FORMAT, "format_version": WEBDATASET_VERSION, "dotsim_version": __version__,
        "source": {"dataset": str(Path(dataset_dir).resolve()), "split": split,
                   "format_version": source.index["format_version"]},
        "channels": channels, "sample_count": sum(s["samples"] for s in shards),
        "shard_bytes": shard_bytes, "shards": shards})
    return ExportResult(out, shards)


def run(args: argparse.Namespace) -> int:
    result = export_webdataset(args.dataset, args.out, parse_size(args.shard_size), args.split,
                               verify=not args.no_verify)
    print(f"exported {result.line()}")
    return 0


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "export", help="write a dataset as WebDataset tar shards (for streaming from object storage)",
        description="Write the frames of a sealed dataset as WebDataset tar shards OUT/shard-NNNNNN.tar: "
        "one sample per frame (KEY.CHANNEL.npy per channel, KEY.scene.json, KEY.frame.json; KEY = "
        "scene_SSSSSSS_frame_K), shards of at most --shard-size bytes, OUT/index.json and OUT/SHA256SUMS "
        "with every shard's sha256. dotsim.data.Frames streams them (or the folder itself) into torch; "
        "`dotsim train --data` takes OUT, its shards or their URLs.")
    parser.add_argument("dataset", metavar="DIR", help="sealed dotsim dataset directory")
    parser.add_argument("out", metavar="OUT", help="folder for the shards (new or empty)")
    parser.add_argument("--format", choices=("webdataset",), default="webdataset",
                        help="webdataset (the only one so far)")
    parser.add_argument("--shard-size", default="256M", metavar="BYTES",
                        help="most bytes of samples per shard, e.g. 64M, 1G (default 256M)")
    parser.add_argument("--split", default=None, help="export only the scenes of this split (default: all)")
    parser.add_argument("--no-verify", action="store_true", help="skip sha256 checks of the files read")
    parser.set_defaults(func=run, errors={ds.FormatError: 1, ValueError: 1})
    return parser
