"""Writing a sealed dataset as WebDataset tar shards (`dotsim export`; dotsim/shards/reader.py reads them).

Each frame is one sample, its files named KEY.EXT (the WebDataset convention, so the `webdataset`
library and any tar reader see it): KEY = scene_SSSSSSS_frame_K, then

- KEY.CHANNEL.png or KEY.CHANNEL.npy.gz for every exported channel (dotsim/shards/format.py says
  which codec each gets: masks and IR codes as PNG, float channels as gzip'ed .npy; with precision
  "training" the projector column as fixed-point PNG too);
- KEY.frame.json: scene_index, frame_index, split, the source frame file and its sha256, how PNG
  channels decode (`encoding`), and the scene's rig and pattern (what decoding and training need,
  so a sample stands alone in a shuffled pipeline);
- KEY.scene.json.gz: the scene's whole scene.json (poses, objects, lights, config), gzip'ed, once per
  scene and shard, in the scene's first sample there.

Channels derived on read (`disparity`) are never stored. Shards OUT/shard-NNNNNN.tar hold whole
samples: at most `shard_bytes` of tar members each (a sample larger than that gets a shard of its
own), or `samples_per_shard` samples each; scenes and frames keep the dataset's order. OUT/pattern.png
is the dataset's pattern (SGBM and `dotsim eval` need it). OUT/index.json, written last, lists every
shard with its sha256, size and sample count (OUT/SHA256SUMS the same checksums for `sha256sum -c`).

An export resumes: every shard is written under a temporary name and renamed when complete, and
OUT/.progress.json (the plan and the shards done, each with its sha256) is rewritten after each
one. A rerun of the same export skips the shards that match it and writes the rest, exactly as an
unbroken run would have; one with other options or of changed data starts the unfinished export
over. A finished export (index.json) is never overwritten.
"""

from __future__ import annotations

import gzip
import io
import shutil
import tarfile
from dataclasses import dataclass
from pathlib import Path

from dotsim import __version__
from dotsim import dataset as ds
from dotsim.channels import stored_channels
from dotsim.dataset.layout import load_json
from dotsim.file_io import (
    TMP_PREFIX,
    atomic_write_bytes,
    atomic_write_json,
    atomic_writer,
    json_bytes,
    make_folder,
    sha256_file,
)
from dotsim.output_folder import EXPORT, check_output_folder
from dotsim.shards.format import (
    INDEX_NAME,
    PATTERN_NAME,
    PRECISIONS,
    SUMS_NAME,
    WEBDATASET_FORMAT,
    WEBDATASET_VERSION,
    encode_channel,
    sample_key,
)

PROGRESS_NAME = ".progress.json"
DEFAULT_SHARD_BYTES = 256 << 20
TAR_BLOCK = 512  # tar block: every member is a header block plus its data rounded up to blocks


def shard_file_name(n: int) -> str:
    return f"shard-{n:06d}.tar"


def tar_bytes_of(files: list[tuple[str, bytes]]) -> int:
    """Bytes the files take as tar members (header block + data padded to whole blocks)."""
    return sum(TAR_BLOCK + -(-len(data) // TAR_BLOCK) * TAR_BLOCK for _, data in files)


def _add(tar: tarfile.TarFile, name: str, data: bytes) -> None:
    info = tarfile.TarInfo(name)  # mtime 0, uid 0, mode 0o644: the same data gives the same bytes
    info.size, info.mode = len(data), 0o644
    tar.addfile(info, io.BytesIO(data))


def choose_channels(wanted: list[str] | None, meta: dict, where) -> list[str]:
    """The channels to export: `wanted` (checked against what the frames store) or all stored ones."""
    stored = list(stored_channels(meta["channels"]))
    if wanted is None:
        return stored
    for name in wanted:
        if name in ds.DERIVED_CHANNELS:
            raise ValueError(f"--channels: {name!r} is derived on read from depth (or the projector "
                             f"column); export those instead")
        if name not in stored:
            raise ValueError(f"--channels: {where} stores no channel {name!r}; it stores "
                             f"{', '.join(stored)}")
    return list(dict.fromkeys(wanted))


def frame_files(meta: dict, frame_index: int, frame: dict, source: tuple[str, str], precision: str
                ) -> list[tuple[str, bytes]]:
    """(member name, bytes) of one frame's sample, without scene.json; source = (frame file, sha256)."""
    key = sample_key(meta["scene_index"], frame_index)
    bits = meta.get("config", {}).get("sensor", {}).get("bit_depth")
    files, encoding = [], {}
    for name, array in frame.items():
        ext, data, enc = encode_channel(name, array, precision, meta["rig"]["projector"]["width"], bits)
        files.append((f"{key}.{name}.{ext}", data))
        if enc is not None:
            encoding[name] = enc
    files.append((f"{key}.frame.json", json_bytes({
        "scene_index": meta["scene_index"], "frame_index": frame_index, "split": meta["split"],
        "file": source[0], "sha256": source[1], "encoding": encoding, "rig": meta["rig"],
        "pattern": meta["pattern"]})))
    return files


@dataclass
class ExportResult:
    out: Path
    shards: list[dict]
    resumed: int = 0  # shards a rerun found done

    def line(self) -> str:
        samples = sum(s["samples"] for s in self.shards)
        size = sum(s["bytes"] for s in self.shards)
        again = f" ({self.resumed} found done by an earlier run)" if self.resumed else ""
        return (f"{samples} sample(s) in {len(self.shards)} shard(s){again}, {size / 1e6:.1f} MB "
                f"({size / max(samples, 1) / 1e3:.0f} kB a frame), in {self.out}")


class _ShardWriter:
    """Writes samples into shard-NNNNNN.tar files: a new shard when the next sample would pass
    `shard_bytes` of members or the shard has `samples_per_shard` samples (an int, or a list: shard
    k's count). A scene's scene.json goes into its first sample in each shard. After each shard,
    `on_shard(shards)` records progress."""

    def __init__(self, out: Path, shard_bytes: int | None, samples_per_shard: int | list[int] | None,
                 done: list[dict], on_shard):
        self.out, self.shard_bytes, self.samples_per_shard = out, shard_bytes, samples_per_shard
        self.shards, self.on_shard = list(done), on_shard
        self._context = self._stream = self._tar = None
        self._used = self._samples = 0
        self._scenes: set[int] = set()

    def _full(self, size: int) -> bool:
        return self.samples_per_shard is None and self._used + size > self.shard_bytes

    def add(self, scene_index: int, scene_json: tuple[str, bytes], files: list[tuple[str, bytes]]) -> None:
        with_scene = [scene_json] + files
        if self._tar is not None:
            size = tar_bytes_of(files if scene_index in self._scenes else with_scene)
            if self._full(size):
                self.close()
        if self._tar is None:
            self._context = atomic_writer(self.out / shard_file_name(len(self.shards)))
            self._stream = self._context.__enter__()
            self._tar = tarfile.open(fileobj=self._stream, mode="w", format=tarfile.USTAR_FORMAT)
            self._used = self._samples = 0
            self._scenes = set()
        if scene_index not in self._scenes:
            files, self._scenes = with_scene, self._scenes | {scene_index}
        for name, data in files:
            _add(self._tar, name, data)
        self._used += tar_bytes_of(files)
        self._samples += 1
        if self.samples_per_shard is not None and self._samples >= self._limit():
            self.close()  # now, not at the next sample: a kill then loses no finished shard

    def _limit(self) -> int:
        """The samples the shard being written holds when full."""
        if isinstance(self.samples_per_shard, list):
            return self.samples_per_shard[len(self.shards)]
        return self.samples_per_shard

    def close(self) -> None:
        if self._tar is None:
            return
        self._tar.close()
        self._context.__exit__(None, None, None)
        path = self.out / shard_file_name(len(self.shards))
        self.shards.append({"name": path.name, "sha256": sha256_file(path), "bytes": path.stat().st_size,
                            "samples": self._samples})
        self._tar = None
        self.on_shard(self.shards)

    def abort(self, error: BaseException) -> None:
        if self._tar is not None:
            self._context.__exit__(type(error), error, error.__traceback__)  # removes the temporary
            self._tar = None


def _done_shards(out: Path, plan: dict) -> list[dict]:
    """The shards an earlier run of the same plan finished and that are still intact, in order.

    Another plan's unfinished export (other options, or data that changed since) is removed: none
    of it was ever published (no index.json), and mixing the two would be wrong."""
    progress = out / PROGRESS_NAME
    done = []
    if progress.is_file():
        try:
            record = load_json(progress)
        except ds.FormatError:
            record = {}
        if record.get("plan") == plan:
            for shard in record.get("shards", []):
                path = out / shard["name"]
                if not path.is_file() or sha256_file(path) != shard["sha256"]:
                    break  # this one and every later one are written again
                done.append(shard)
        elif record:
            print(f"{out}: an unfinished export of other data or options is there; starting over")
    names = {s["name"] for s in done}
    for path in out.iterdir():
        unfinished = path.name.startswith("shard-") and path.name not in names
        if (path.name.startswith(TMP_PREFIX) or unfinished) and path.is_file():
            path.unlink()
    return done


def _plan(source: ds.Dataset, dataset_dir, split, channels, precision, shard_bytes, samples_per_shard,
          shards) -> dict:
    return {"source": {"dataset": str(Path(dataset_dir).resolve()), "split": split,
                       "index_sha256": sha256_file(Path(dataset_dir) / ds.INDEX_FILE),
                       "format_version": source.index["format_version"]},
            "channels": channels, "precision": precision,
            "sharding": {"shards": shards} if shards is not None
            else {"shard_bytes": shard_bytes} if samples_per_shard is None
            else {"samples_per_shard": samples_per_shard}}


def export_webdataset(dataset_dir: str | Path, out: str | Path, shard_bytes: int | None = None,
                      split: str | None = None, verify: bool = True, channels: list[str] | None = None,
                      precision: str = "exact", samples_per_shard: int | None = None,
                      shards: int | None = None) -> ExportResult:
    """Write the scenes of `split` (None: all) of the sealed dataset as shards in `out` (see the
    module docstring), resuming an unfinished export of the same plan there.

    Sharding: `shard_bytes` (default 256 MiB), `samples_per_shard`, or `shards` (that many shards,
    whose sample counts differ by at most one, e.g. a multiple of the loader's workers; at most one
    per sample); give at most one."""
    if sum(x is not None for x in (shard_bytes, samples_per_shard, shards)) > 1:
        raise ValueError("give one of --shard-size, --samples-per-shard and --shards")
    for name, value in (("--samples-per-shard", samples_per_shard), ("--shards", shards)):
        if value is not None and value < 1:
            raise ValueError(f"{name} {value}: at least 1")
    if precision not in PRECISIONS:
        raise ValueError(f"--precision {precision!r}: choose one of {', '.join(PRECISIONS)}")
    # a file, a read-only or missing parent, a folder that is no export: one line, first
    out = check_output_folder(out, EXPORT, "OUT", "dotsim export")
    source = ds.open_dataset(dataset_dir, verify=verify)
    scenes = source.scenes if split is None else source.split(split)
    if not scenes:
        raise ds.FormatError(f"{dataset_dir}: no scenes to export (split {split!r})")
    channels = choose_channels(channels, ds.read_scene_meta(scenes[0].path, verify=verify), scenes[0].path)
    if shards is not None:
        samples = sum(ref.frame_count for ref in scenes)
        if shards > samples:
            raise ValueError(f"--shards {shards}: {dataset_dir} has {samples} sample(s) (frames) to export"
                             f"{'' if split is None else f' in split {split!r}'}; allowed: 1 to {samples}")
        samples_per_shard = [samples // shards + (k < samples % shards) for k in range(shards)]
    if samples_per_shard is None and shard_bytes is None:
        shard_bytes = DEFAULT_SHARD_BYTES
    plan = _plan(source, dataset_dir, split, channels, precision, shard_bytes,
                 None if shards is not None else samples_per_shard, shards)
    if (out / INDEX_NAME).exists():
        index = load_json(out / INDEX_NAME)
        if index.get("plan") != plan:
            raise ds.FormatError(f"{out}: already holds a finished export of other data or options "
                                 f"(index.json); choose an empty or new folder")
        return ExportResult(out, index["shards"], resumed=len(index["shards"]))
    make_folder(out)
    done = _done_shards(out, plan)
    skip = sum(s["samples"] for s in done)
    writer = _ShardWriter(out, shard_bytes, samples_per_shard, done,
                          lambda written: atomic_write_json(out / PROGRESS_NAME, {"plan": plan,
                                                                                  "shards": written}))
    seen = 0
    try:
        for ref in scenes:
            if seen + ref.frame_count <= skip:
                seen += ref.frame_count
                continue
            meta = ds.read_scene_meta(ref.path, verify=verify)
            if not set(channels) <= set(stored_channels(meta["channels"])):
                raise ds.FormatError(f"{ref.path}: stores {list(stored_channels(meta['channels']))}, not "
                                     f"every exported channel {channels}")
            scene_json = gzip.compress(json_bytes(meta), mtime=0)  # its objects list: 0.4 MB a scene
            for k, entry in enumerate(meta["frames"]):
                seen += 1
                if seen <= skip:
                    continue
                frame = ds.read_frame(ref.path / entry["file"], verify=verify, meta=meta, channels=channels)
                files = frame_files(meta, k, frame, (entry["file"], entry["sha256"]), precision)
                key = sample_key(ref.scene_index, k)
                writer.add(ref.scene_index, (f"{key}.scene.json.gz", scene_json), files)
        writer.close()
    except BaseException as error:
        writer.abort(error)
        raise
    written = writer.shards
    pattern = ds.pattern_path(dataset_dir)
    pattern_entry = None
    if pattern.is_file():
        with atomic_writer(out / PATTERN_NAME) as stream, open(pattern, "rb") as src:
            shutil.copyfileobj(src, stream)
        pattern_entry = {"name": PATTERN_NAME, "sha256": sha256_file(out / PATTERN_NAME)}
    atomic_write_bytes(out / SUMS_NAME, "".join(f"{s['sha256']}  {s['name']}\n" for s in written).encode())
    atomic_write_json(out / INDEX_NAME, {
        "format": WEBDATASET_FORMAT, "format_version": WEBDATASET_VERSION, "dotsim_version": __version__,
        "plan": plan, "channels": channels, "precision": precision, "pattern": pattern_entry,
        "sample_count": sum(s["samples"] for s in written), "shards": written})
    (out / PROGRESS_NAME).unlink(missing_ok=True)
    return ExportResult(out, written, resumed=len(done))
