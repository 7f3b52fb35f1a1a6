"""Reading `dotsim export`'s WebDataset shards (dotsim/shards/writer.py writes them; numpy only).

A source of shards is an export folder (its index.json, written by dotsim.shards.writer), a shard
path, a brace pattern of shards (`shards/shard-{000000..000009}.tar`), a URL the `webdataset` library
opens (http(s)://, pipe:..., needs `pip install "dotsim[webdataset]"`), or a list of these; `resolve`
says which, and also recognises a dataset folder (dotsim.dataset) so that one argument names either
form. Local shards listed in the index.json of the export folder they lie in are checked against
their sha256 before they are read, whether the folder, their paths or a pattern named them.

Streaming: `iter_tar_samples` and `decode_sample` turn a shard into frame dicts (trainer.samples.Frames
streams them into torch). The webdataset library's own pipelines read the shards too: `decode_webdataset`
turns one of its raw samples into the same frame dict, without `meta` (each sample decodes alone from
its frame.json):

    wds.WebLoader(wds.WebDataset(urls).map(decode_webdataset).batched(4), batch_size=None, num_workers=4)

For random access (a trainer's seeded shuffle), `index_shards` lists every sample of local shards
with the byte ranges of its members, and `read_indexed` reads one sample by seeking to them;
`stage_shards` first copies shards behind URLs to a local cache.
"""

from __future__ import annotations

import gzip
import json
import os
import shutil
import tarfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from dotsim import dataset as ds
from dotsim.dataset.frames import DERIVATIONS, derivable_channels
from dotsim.dataset.layout import load_json
from dotsim.file_io import atomic_writer, sha256_bytes, sha256_file
from dotsim.rig.geometry import Rig, projector_column_to_depth
from dotsim.shards.format import (
    INDEX_NAME,
    WEBDATASET_FORMAT,
    channel_member,
    check_version,
    decode_channel,
)


@dataclass(frozen=True)
class Source:
    """What a source names: a dataset folder, or shard locations (paths or URLs) with the checksums
    an export's index.json lists for them (name -> sha256; empty when unknown)."""

    folder: Path | None
    shards: tuple[str, ...] = ()
    checksums: tuple[tuple[str, str], ...] = ()


def is_url(text: str) -> bool:
    return "://" in text and not text.startswith("file://") or text.startswith("pipe:")


def _local(text: str) -> str:
    return text.removeprefix("file://")


def _names_shards(text: str) -> bool:
    """Whether a path that is not a folder names shards (a .tar file or a brace pattern)."""
    return "{" in text or text.endswith(".tar") or Path(_local(text)).is_file()


def _expand(text: str) -> list[str]:
    """Brace expansion of a shard pattern (the braceexpand package, a dependency of webdataset;
    a pattern without braces needs nothing)."""
    if "{" not in text:
        return [text]
    try:
        from braceexpand import braceexpand
    except ImportError:
        raise ds.FormatError(f"{text}: brace patterns need braceexpand: "
                             f"pip install \"dotsim[webdataset]\"") from None
    return list(braceexpand(text))


def _export_index(folder: Path) -> dict | None:
    """The index.json of an export folder (checked), or None when `folder` holds no export."""
    index = folder / INDEX_NAME
    if not index.is_file():
        return None
    meta = load_json(index)
    if meta.get("format") != WEBDATASET_FORMAT:
        return None
    check_version(meta.get("format_version"), index)
    shards = meta.get("shards")
    if not isinstance(shards, list) or not all(isinstance(s, dict) and isinstance(s.get("name"), str)
                                               and isinstance(s.get("sha256"), str) for s in shards):
        raise ds.FormatError(f"{index}: 'shards' must be a list of {{name, sha256, ...}} entries")
    return meta


def resolve(source) -> Source:
    """The Source that `source` (see the module docstring) names; FormatError naming what is wrong.

    Local shards named one by one or by a pattern are checked against the index.json of the export
    folder they lie in, when there is one, as if the folder had been given."""
    if isinstance(source, Source):
        return source
    items = [str(s) for s in source] if isinstance(source, (list, tuple)) else [str(source)]
    if not items:
        raise ds.FormatError("no data source given")
    folder = Path(_local(items[0]))
    if len(items) == 1 and not is_url(items[0]) and (folder.is_dir() or not _names_shards(items[0])):
        meta = _export_index(folder) if folder.is_dir() else None
        if meta is None:
            return Source(folder=folder)  # a dataset folder; open_dataset names what is missing
        shards = tuple(str(folder / s["name"]) for s in meta["shards"])
        return Source(None, shards, tuple((str(folder / s["name"]), s["sha256"]) for s in meta["shards"]))
    shards, checksums, indexes = [], {}, {}
    for item in items:
        for name in _expand(item):
            if is_url(name):
                shards.append(name)
                continue
            path = Path(_local(name))
            if not path.is_file():
                raise ds.FormatError(f"{name}: no such shard (give a dataset or export folder, .tar "
                                     f"shards, a brace pattern of them, or URLs)")
            parent = path.resolve().parent
            if parent not in indexes:
                indexes[parent] = _export_index(parent)
            listed = {s["name"]: s["sha256"] for s in (indexes[parent] or {}).get("shards", [])}
            if path.name in listed:
                checksums[str(path)] = listed[path.name]
            shards.append(str(path))
    return Source(None, tuple(shards), tuple(checksums.items()))


def open_shard(location: str, checksums: dict[str, str] | None = None):
    """A binary stream of a shard: a local file (its sha256 checked first when `checksums` lists it)
    or a URL through webdataset.gopen."""
    if not is_url(location):
        expected = (checksums or {}).get(location)
        if expected is not None and sha256_file(location) != expected:
            raise ds.FormatError(f"{location}: sha256 differs from the one in {INDEX_NAME} (file changed "
                                 f"or corrupt)")
        return open(location, "rb")
    try:
        import webdataset
    except ImportError:
        raise ds.FormatError(f"{location}: reading URLs needs webdataset: "
                             f"pip install \"dotsim[webdataset]\"") from None
    return webdataset.gopen(location)


def _split_name(name: str) -> tuple[str, str]:
    """'scene_0000001_frame_2.ir.npy' -> ('scene_0000001_frame_2', 'ir.npy') (WebDataset's rule)."""
    base = name.rsplit("/", 1)[-1]
    key, _, ext = base.partition(".")
    return name[: len(name) - len(base)] + key, ext


def iter_tar_samples(stream, where: str) -> Iterator[tuple[str, dict[str, bytes]]]:
    """(key, {extension: bytes}) of each sample of a tar stream, members grouped by key in order."""
    key, files = None, {}
    try:
        with tarfile.open(fileobj=stream, mode="r|") as tar:
            for member in tar:
                if not member.isfile():
                    continue
                k, ext = _split_name(member.name)
                if k != key and files:
                    yield key, files
                    files = {}
                key = k
                files[ext] = tar.extractfile(member).read()
    except tarfile.TarError as e:
        raise ds.FormatError(f"{where}: not a readable tar shard ({e})") from None
    if files:
        yield key, files


def _scene_of(key: str, where: str) -> int:
    """The scene index in a sample key scene_SSSSSSS_frame_K."""
    try:
        return int(key.rsplit("/", 1)[-1].split("_")[1])
    except (IndexError, ValueError):
        raise ds.FormatError(f"{where}: sample key {key!r} is not scene_SSSSSSS_frame_K") from None


def decode_sample(key: str, files: dict[str, bytes], channels=None, where: str = "",
                  metas: dict[int, dict] | None = None) -> dict:
    """A frame dict from a sample's files (any export format version); channels: keep only these.

    `metas` (scene index -> scene.json dict) supplies the metadata of a 2.x sample that does not carry
    it (it is stored once per scene and shard) and learns it from one that does. The derived channels
    (`disparity`, `stereo_disparity`) come on read as from a dataset folder: from depth, or, when the
    sample has no depth, from the depth its projector column gives (at the column's stored precision)."""
    where = f"{where}: sample {key}"
    metas = {} if metas is None else metas
    scene = _scene_of(key, where)
    own = _own_scene_json(files)
    if own is not None:
        metas[scene] = own
    if scene not in metas:
        raise ds.FormatError(f"{where} has no scene.json, nor has an earlier sample of its scene in "
                             f"this shard")
    return {**_decode_frame(key, files, channels, where, metas[scene]), "meta": metas[scene]}


def decode_webdataset(sample: dict, channels=None) -> dict:
    """One raw sample of the webdataset library ({"__key__": KEY, "__url__": shard, "ir.png": bytes,
    "frame.json": bytes, ...}, as `webdataset.WebDataset(urls)` yields it without `.decode()`) as the
    frame dict trainer.samples.Frames yields, without `meta`: the channels (PNG codes decoded as its
    frame.json says, .npy.gz unpacked, `disparity` derived) and key, scene_index, frame_index, split.
    It needs no other sample: frame.json carries the rig and the codecs, so it suits a shuffled
    pipeline, in which a scene's scene.json.gz (in its first sample per shard only) may come later,
    or in another worker.
    FormatError naming the shard and the sample."""
    key = sample.get("__key__")
    if not isinstance(key, str):
        raise ds.FormatError(f"{sample.get('__url__', '?')}: a sample without __key__ (not a raw "
                             f"webdataset sample: leave out .decode() before this map)")
    files = {ext: data for ext, data in sample.items() if not ext.startswith("__")}
    where = f"{sample.get('__url__', '')}: sample {key}"
    return _decode_frame(key, files, channels, where, _own_scene_json(files))


def _own_scene_json(files: dict[str, bytes]) -> dict | None:
    """The scene.json a sample carries itself (format 1.0: every sample; 2.0: a scene's first per shard)."""
    if "scene.json" not in files and "scene.json.gz" not in files:
        return None
    return json.loads(files.get("scene.json") or gzip.decompress(files["scene.json.gz"]))


def _decode_frame(key: str, files: dict[str, bytes], channels, where: str, meta: dict | None) -> dict:
    """The channels of one sample and its key, scene_index, frame_index and split; the rig (for the
    derived channels) from its frame.json, else from its scene's `meta`."""
    if "frame.json" not in files:
        raise ds.FormatError(f"{where} has no frame.json (not a dotsim export)")
    info = json.loads(files["frame.json"])
    encoding = info.get("encoding", {})
    names = [n for n in ds.FRAME_CHANNELS if channel_member(files, n)]
    derivable = derivable_channels(names, "depth" in names or "projector_column" in names)
    wanted = names + derivable if channels is None else list(channels)
    missing = [c for c in wanted if c not in names and c not in derivable]
    if missing:
        raise ds.FormatError(f"{where} has no channel(s) {missing}; it has {names}")
    decoded: dict[str, np.ndarray] = {}

    def channel(name: str) -> np.ndarray:
        if name not in decoded:
            member = channel_member(files, name)
            decoded[name] = decode_channel(name, member[len(name) + 1:], files[member],
                                           encoding.get(name), where)
        return decoded[name]

    out = {"key": key, "scene_index": info["scene_index"], "frame_index": info["frame_index"],
           "split": info["split"]}
    for name in wanted:
        if name in names:
            out[name] = channel(name)
            continue
        rig_dict = info.get("rig") or (meta or {}).get("rig")
        if rig_dict is None:
            raise ds.FormatError(f"{where}: {name!r} is derived from the rig, which neither its frame.json "
                                 f"nor a scene.json gives")
        rig = Rig.from_dict(rig_dict)
        # a training export may hold the projector column instead of depth: depth follows from it
        depth = (channel("depth") if "depth" in names
                 else projector_column_to_depth(channel("projector_column"), rig))
        try:
            out[name] = DERIVATIONS[name](depth, rig)
        except ValueError as error:  # a stereo channel of a rig without a stereo pair
            raise ds.FormatError(f"{where}: channel {name!r}: {error}") from None
    return out


def default_cache_dir() -> Path:
    """Where shards behind URLs are copied for random access: $DOTSIM_CACHE, else ~/.cache/dotsim."""
    return Path(os.environ.get("DOTSIM_CACHE") or Path.home() / ".cache" / "dotsim") / "shards"


def stage_shards(source, cache_dir: str | Path | None = None) -> Source:
    """`source` with every shard behind a URL copied to a local file in cache_dir (default
    default_cache_dir()), named after the URL, kept for the next run; local shards stay as they are."""
    src = resolve(source)
    if src.folder is not None or not any(is_url(s) for s in src.shards):
        return src
    cache = Path(cache_dir) if cache_dir is not None else default_cache_dir()
    cache.mkdir(parents=True, exist_ok=True)
    local = []
    for location in src.shards:
        if is_url(location):
            path = cache / f"{sha256_bytes(location.encode())[:16]}-{location.rstrip('/').rsplit('/', 1)[-1]}"
            if not path.is_file():
                with open_shard(location) as stream, atomic_writer(path) as out:
                    shutil.copyfileobj(stream, out, 1 << 20)
            location = str(path)
        local.append(location)
    return Source(None, tuple(local), src.checksums)


@dataclass(frozen=True)
class IndexedSample:
    """Where one sample lies in a local shard: member extension -> (data offset, size)."""

    shard: str
    key: str
    members: tuple[tuple[str, int, int], ...]


def index_shards(source) -> list[IndexedSample]:
    """Every sample of the local shards of `source`, in order, with its members' byte ranges (reads
    the tar headers only; checks sha256 where an export's index.json lists it)."""
    src = resolve(source)
    if src.folder is not None:
        raise ds.FormatError(f"{src.folder}: a dataset folder, not shards")
    checksums = dict(src.checksums)
    samples = []
    for location in src.shards:
        if is_url(location):
            raise ds.FormatError(f"{location}: random access needs local shards (copy them, or stream "
                                 f"with trainer.samples.Frames)")
        with open_shard(location, checksums) as stream:
            try:
                members = tarfile.open(fileobj=stream, mode="r:").getmembers()
            except tarfile.TarError as e:
                raise ds.FormatError(f"{location}: not a readable tar shard ({e})") from None
        by_key: dict[str, list] = {}
        for m in members:
            if m.isfile():
                key, ext = _split_name(m.name)
                by_key.setdefault(key, []).append((ext, m.offset_data, m.size))
        scene_json: dict[int, tuple] = {}  # format 2.x: once per scene and shard, in its first sample
        for key, found in by_key.items():
            scene = _scene_of(key, location)
            own = next((member for member in found if member[0] in ("scene.json", "scene.json.gz")), None)
            if own is not None:
                scene_json.setdefault(scene, own)
            elif scene in scene_json:
                found.append(scene_json[scene])
            samples.append(IndexedSample(location, key, tuple(found)))
    return samples


def read_indexed(sample: IndexedSample, channels=None) -> dict:
    """Read one indexed sample (decode_sample's dict) by seeking to its members."""
    wanted = None
    if channels is not None:  # the members holding these channels (disparity: what it derives from)
        stored = {ext.split(".")[0] for ext, _, _ in sample.members}
        wanted = {c for c in channels if c in stored} | {"scene", "frame"}
        if set(channels) & set(ds.DERIVED_CHANNELS):
            wanted.add("depth" if "depth" in stored else "projector_column")
    files = {}
    with open(sample.shard, "rb") as f:
        for ext, offset, size in sample.members:
            if wanted is None or ext.split(".")[0] in wanted:
                f.seek(offset)
                files[ext] = f.read(size)
    return decode_sample(sample.key, files, channels, sample.shard)
