"""`dotsim infer`'s output files: where each input's prediction goes and what the EXR holds.

Per input NAME (a dataset frame scene_SSSSSSS/frame_K.exr gives scene_SSSSSSS_frame_K, the sample key of
dotsim/shards/format.py; any other file its stem): NAME.exr, a single-part ZIP-compressed OpenEXR of the
float32 channels `disparity` (camera px) and `depth` (metres), nan where the network gives no estimate,
whose header attribute `dotsim_prediction` (JSON: the checkpoint, the input, the precision) says that
they are a network's predictions, not ground truth. `trainer.infer` writes them; `dotsim show` labels
them as predictions (prediction_source) and `dotsim view --predictions` finds them by name.
"""

from __future__ import annotations

import io
import json
from pathlib import Path

import numpy as np

from dotsim.file_io import atomic_write_bytes
from dotsim.shards.format import sample_key


def output_name(path: Path) -> str:
    """The NAME of an input's outputs: frame_2.exr inside scene_0000007 -> scene_0000007_frame_2; other
    files keep their stem."""
    if path.parent.name.startswith("scene_") and path.stem.startswith("frame_"):
        return f"{path.parent.name}_{path.stem}"
    return path.stem


def prediction_path(predictions: Path, scene_index: int, frame_index: int) -> Path:
    """The prediction `dotsim infer --out predictions` wrote for frame `frame_index` of a dataset's scene."""
    return predictions / f"{sample_key(scene_index, frame_index)}.exr"


# The header attribute that marks a prediction file, and says whose: {"checkpoint", "input", "precision"}.
PREDICTION_ATTRIBUTE = "dotsim_prediction"


def write_prediction(path: Path, channels: dict[str, np.ndarray], source: dict) -> None:
    """Write a prediction EXR (atomically): the channels as float32, ZIP-compressed, `source` (what
    predicted them from what: checkpoint, input, precision) as its PREDICTION_ATTRIBUTE."""
    import OpenEXR

    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              PREDICTION_ATTRIBUTE: json.dumps(source, sort_keys=True)}
    pixels = {k: np.ascontiguousarray(v, np.float32) for k, v in channels.items()}
    stream = io.BytesIO()
    OpenEXR.File(header, pixels).write(stream)
    atomic_write_bytes(path, stream.getvalue())


def prediction_source(path: Path) -> dict | None:
    """The PREDICTION_ATTRIBUTE of the EXR at `path` (a dict), or None for a file without it (a dataset
    frame, any other EXR). OpenEXR's errors for a file it cannot read pass through."""
    import OpenEXR

    text = OpenEXR.File(str(path)).header().get(PREDICTION_ATTRIBUTE)
    if text is None:
        return None
    try:
        source = json.loads(text)
    except ValueError:
        source = None
    return source if isinstance(source, dict) else {"written by": str(text)}


def read_prediction(path: Path) -> dict[str, np.ndarray]:
    """The channels of a prediction EXR (write_prediction's: disparity and depth, float32, nan where no
    estimate). OpenEXR's errors for a file it cannot read pass through."""
    import OpenEXR

    with OpenEXR.File(str(path), separate_channels=True) as exr:
        return {name: np.asarray(channel.pixels, np.float32) for name, channel in exr.channels().items()}
