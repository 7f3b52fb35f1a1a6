"""The dotsim dataset format: writer, reader, shards, checksums (specified in docs/FORMAT.md).

Layout::

    DATASET/index.json                      written by seal_dataset (shards, counts, checksums)
    DATASET/dataset.json                    layout (scenes_per_shard), written with the first scene
    DATASET/<other files>                   dataset-level files, e.g. pattern.png (write_dataset_file)
    DATASET/shard_00000/shard.json          written by seal_dataset (sha256 of every file)
    DATASET/shard_00000/scene_0000000/scene.json      metadata, written last (lists frame sha256)
    DATASET/shard_00000/scene_0000000/frame_0.exr     one EXR per frame, channels FRAME_CHANNELS

Integrity is a chain: index.json holds the sha256 of every shard.json, shard.json the sha256 of
every file of its scenes, scene.json the sha256 of its frames. Every write goes to a temporary
name (``.tmp-...-<pid>``, dotsim.file_io) and is renamed into place, so a reader never sees half
a file or half a scene; a rerun tells complete scenes (the final directory exists) from leftovers.

Modules, one idea each (this package re-exports their public names):

- layout: names and paths, FormatError, the format version, dataset.json, listing shards/scenes
- frames: the EXR frame codec, FRAME_CHANNELS, and the channels derived on read (disparity)
- scene_meta: scene.json's required keys and its validation
- writer: write_scene, write_dataset_file, and resume (is_scene_complete, remove_partial_scenes,
  remove_partial_scenes_in_range, remove_scene)
- seal: seal_dataset (shard.json, index.json), incremental, rerunnable at any time
- reader: open_dataset, read_scene, read_frame, dataset_summary
- verify: verify_dataset (every checksum, the seal against the disk) and repair_dataset

The dataset's pattern file (store_pattern, pattern_entry) lives in dotsim.pattern_store.
"""

from dotsim.dataset.frames import (
    DERIVED_CHANNELS,
    EXR_COMPRESSION,
    EXR_COMPRESSIONS,
    FRAME_CHANNELS,
    MASK_CHANNELS,
    RENDERED_CHANNELS,
    decode_frame,
    encode_frame,
    ground_truth_disparity,
    write_frame_file,
)
from dotsim.dataset.layout import (
    DEFAULT_SCENES_PER_SHARD,
    FORMAT_VERSION,
    INDEX_FILE,
    LAYOUT_FILE,
    PATTERN_FILE,
    SCENE_FILE,
    SHARD_FILE,
    FormatError,
    check_format_version,
    complete_scenes,
    frame_name,
    pattern_path,
    read_layout,
    scene_dir,
    scene_name,
    shard_name,
)
from dotsim.dataset.reader import (
    Dataset,
    Scene,
    SceneRef,
    dataset_summary,
    open_dataset,
    read_frame,
    read_scene,
    read_scene_meta,
)
from dotsim.dataset.scene_meta import (
    CAPTURED,
    REQUIRED_META_KEYS,
    WRITER_META_KEYS,
    camera_size,
    holds_captures,
    parse_scene_meta,
    scene_shapes,
)
from dotsim.dataset.seal import DatasetChangingError, SealResult, seal_dataset
from dotsim.dataset.verify import Problem, RepairResult, VerifyReport, repair_dataset, verify_dataset
from dotsim.dataset.writer import (
    is_scene_complete,
    leftovers,
    remove_partial_scenes,
    remove_partial_scenes_in_range,
    remove_scene,
    write_dataset_file,
    write_scene,
)

# Temporary names (a writer's leftovers after a crash) are part of the layout; the writer is
# dotsim.file_io's.
from dotsim.file_io import TMP_PREFIX

__all__ = [
    "CAPTURED", "DEFAULT_SCENES_PER_SHARD", "DERIVED_CHANNELS", "EXR_COMPRESSION", "EXR_COMPRESSIONS",
    "FORMAT_VERSION", "FRAME_CHANNELS",
    "INDEX_FILE",
    "LAYOUT_FILE", "RENDERED_CHANNELS", "MASK_CHANNELS", "PATTERN_FILE", "REQUIRED_META_KEYS", "SCENE_FILE",
    "SHARD_FILE",
    "TMP_PREFIX", "WRITER_META_KEYS", "Dataset", "DatasetChangingError", "FormatError", "Problem",
    "RepairResult", "Scene", "SceneRef", "SealResult", "VerifyReport", "camera_size",
    "check_format_version", "complete_scenes", "dataset_summary", "decode_frame", "encode_frame",
    "frame_name", "ground_truth_disparity", "holds_captures", "is_scene_complete", "leftovers",
    "open_dataset", "parse_scene_meta",
    "pattern_path", "read_frame", "read_layout", "read_scene", "read_scene_meta", "remove_partial_scenes",
    "remove_partial_scenes_in_range", "remove_scene", "repair_dataset", "scene_dir", "scene_name",
    "scene_shapes", "seal_dataset", "shard_name", "verify_dataset", "write_dataset_file",
    "write_frame_file", "write_scene",
]
