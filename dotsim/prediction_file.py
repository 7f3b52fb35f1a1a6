"""`dotsim infer`'s output files: where each input's prediction goes and what the EXR holds.

Per input NAME (a dataset frame scene_SSSSSSS/frame_K.exr gives scene_SSSSSSS_frame_K, the sample key of
dotsim.shard_format; any other file its stem): NAME.exr, a single-part ZIP-compressed OpenEXR of the
float32 channels `disparity` (camera px) and `depth` (metres), nan where the network gives no estimate.
`trainer.infer` writes them; `dotsim view --predictions` finds them by name.
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

from dotsim.file_io import atomic_write_bytes
from dotsim.shard_format import sample_key


def output_name(path: Path) -> str:
    """The NAME of an input's outputs: frame_2.exr inside scene_0000007 -> scene_0000007_frame_2; other
    files keep their stem."""
    if path.parent.name.startswith("scene_") and path.stem.startswith("frame_"):
        return f"{path.parent.name}_{path.stem}"
    return path.stem


def prediction_path(predictions: Path, scene_index: int, frame_index: int) -> Path:
    """The prediction `dotsim infer --out predictions` wrote for frame `frame_index` of a dataset's scene."""
    return predictions / f"{sample_key(scene_index, frame_index)}.exr"


def write_prediction(path: Path, channels: dict[str, np.ndarray]) -> None:
    """Write a prediction EXR (atomically): the channels as float32, ZIP-compressed."""
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    pixels = {k: np.ascontiguousarray(v, np.float32) for k, v in channels.items()}
    stream = io.BytesIO()
    OpenEXR.File(header, pixels).write(stream)
    atomic_write_bytes(path, stream.getvalue())
