"""How real dotsim's Kinect rendering looks beside a real Kinect v1 frame: `dotsim capture compare` on the
vendored capture (tests/data/real/kinect_v1_ctd: its README gives source and licence) and still
renderings of the config docs/CONFIG.md gives for the Kinect (dotsim/configs/kinect.toml) through the
capture's rig (its rig.json: the centre 640 x 512 of the 1280 x 1024 IR mode), with the config's
[sensor], with the [sensor] table fit-sensor fits to the real frame (its noise from the frame alone,
then with --compare against a still rendering of the config with that noise and no blur or speckle of
its own, lit as below: blur_sigma, speckle_contrast, and the noise with the one-frame estimate's bias
taken out), and with that table in a room lit to the real frame's ambient / projector ratio
([lighting] ambient_ratio, the one-frame estimate of the first report) by a panel under the ceiling,
evenly as the real room is lit ([lighting] ceiling_light, no lamps), and lit again to that ratio
times the real frame's one-frame estimate over the lit rendering's (so that one estimator reads alike
on both). The scenes stand where the real frame's surfaces do: their objects' centres within its
5th-95th percentile depth (SGBM against its pattern), before a back wall at the far end
(--scene-depths config: the config's scenes, 0.5-8 m). Prints each table (statistic, recording,
rendering, ratio) and writes the pictures. A rerun with the same --out resumes the renderings
(generate refuses a folder of another config's).

    python -m bench.realism_report [--scale 0.5] [--scenes 1] [--samples 4] [--threads 1] [--out DIR]

Still scenes ([motion] translation = 0 and rotation = 0: a scene's 4 frames differ by the sensor's
noise alone), built-in primitives instead of the asset cache unless --assets cache.
"""

from __future__ import annotations

import argparse
import json
import tempfile
import tomllib
from pathlib import Path

REAL = Path(__file__).resolve().parents[1] / "tests" / "data" / "real" / "kinect_v1_ctd"
CONFIG = "kinect"
STILL = {"motion": {"translation": 0.0, "rotation": 0.0}}
# The nearest depth SGBM searches the real frame for (m): the Kinect's near limit, about 0.5 m.
NEAREST = 0.5
# A room lit evenly from above, as the real frame's room is (its wall's ambient even across the view):
# the ceiling panel instead of the config's lamps (docs/RENDERING.md "Even ambient light"); its power
# is immaterial, the ambient being scaled to the ratio.
EVEN_LIGHT = {"extra_lights": [0, 0], "ceiling_light": [100.0, 100.0]}


def recording_depth_range() -> tuple[float, float]:
    """The 5th and 95th percentile depth of the real frame (capture.realism.matched_depths: SGBM with
    LCN against its pattern, which is in the frame's camera pixels), m."""
    import numpy as np

    from capture.realism import matched_depths
    from dotsim.images import read_grey_image
    from dotsim.rig.files import load_rig_file
    from trainer.sgbm import num_disparities_for

    rig = load_rig_file(REAL / "rig.json").rig
    frame, pattern = (read_grey_image(REAL / name).relative() for name in ("ir.png", "pattern.png"))
    depths = matched_depths(frame, pattern, rig.camera.fx, rig.baseline, num_disparities_for(rig, NEAREST))
    low, high = np.percentile(depths, [5, 95])
    return round(float(low), 2), round(float(high), 2)


def still_config(scale: float, samples: int, threads: int, assets: str, sensor: dict | None,
                 ambient_ratio: float | None = None, depths: tuple[float, float] | None = None):
    """The Kinect config through the capture's rig at [rig] scale `scale`, still, with `sensor` over
    its [sensor] table (None: the config's own), unless `ambient_ratio` is None (the config's lighting)
    lit evenly (EVEN_LIGHT) with [lighting] ambient_ratio fixed at `ambient_ratio`, and unless `depths`
    is None (the config's scenes) its objects' centres drawn within `depths` before a back wall at
    their far end (the recording's depths: recording_depth_range)."""
    from generator.config import config_from_dict, load_config

    data = load_config(CONFIG).to_dict()
    data.pop("source")
    data["rig"] = {**data["rig"], "file": str(REAL / "rig.json"), "scale": scale}
    data["render"] = {**data["render"], "samples": samples, "threads": threads}
    data["motion"] = {**data["motion"], **STILL["motion"]}
    if assets == "primitives":
        data["assets"] = {"source": "primitives"}
    if depths is not None:
        # a room deep enough for the camera to stand before that wall (the schema's rule)
        room = [max(size, 1.5 * depths[1]) for size in data["scene"]["room_size"]]
        data["scene"] = {**data["scene"], "distance": list(depths), "back_wall_distance": [depths[1]] * 2,
                         "room_size": room}
    if sensor is not None:
        data["sensor"] = {**data["sensor"], **sensor}
    if ambient_ratio is not None:
        data["lighting"] = {**data["lighting"], "ambient_ratio": [ambient_ratio, ambient_ratio], **EVEN_LIGHT}
    return config_from_dict(data, source=f"{CONFIG} (still, rig {REAL / 'rig.json'}, scale {scale:g})")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m bench.realism_report",
                                     description=__doc__.split("\n\n")[0])
    parser.add_argument("--scale", type=float, default=0.5,
                        help="[rig] scale of the renderings (default 0.5: 320 x 256)")
    parser.add_argument("--scenes", type=int, default=1, help="still scenes of 4 frames each (default 1)")
    parser.add_argument("--samples", type=int, default=4, help="Cycles samples (default 4)")
    parser.add_argument("--threads", type=int, default=1, help="render threads (default 1; 0: all cores)")
    parser.add_argument("--assets", choices=("primitives", "cache"), default="primitives",
                        help="scene objects: built-in primitives (default) or the config's asset cache")
    parser.add_argument("--out", type=Path, help="keep renderings and reports here (default: a temporary "
                        "folder); a rerun with the same folder resumes the renderings")
    parser.add_argument("--scene-depths", choices=("recording", "config"), default="recording",
                        help="where the scenes' objects stand: within the real frame's 5th-95th percentile "
                        "depth, before a back wall at its far end (default), or as the config draws them")
    args = parser.parse_args(argv)

    from commands.cli import main as dotsim
    from generator.driver import generate

    def render(name: str, sensor: dict | None, lit: float | None) -> Path:
        """A still rendering at the chosen depths into FOLDER/rendering_NAME (resumed where it is; a
        folder holding another config's scenes is refused by generate, naming it)."""
        rendering = folder / f"rendering_{name}"
        config = still_config(args.scale, args.samples, args.threads, args.assets, sensor, lit, depths)
        generate(config, rendering, "train", args.scenes, seed=1, workers=1, progress=False)
        return rendering

    def compare(name: str, rendering: Path, what: str) -> list[dict] | None:
        """`capture compare` of the real frame and the rendering, printed; its rows (None: it failed)."""
        print(f"\n== the Kinect config's rendering, [sensor] {what}")
        report = folder / f"realism_{name}.png"
        if dotsim(["capture", "compare", str(REAL / "ir.png"), str(rendering), "--pattern",
                   str(REAL / "pattern.png"), "-o", str(report)]) != 0:
            return None
        rows = json.loads(report.with_suffix(".json").read_text())["rows"]
        off = [abs(row["ratio"] - 1) for row in rows if row["ratio"] is not None]
        within = sum(value <= 0.25 for value in off)
        print(f"{within} of {len(off)} statistics within 25% of the real frame's")
        return rows

    def ambient(rows: list[dict]) -> tuple[float, float]:
        """(the real frame's, the rendering's) one-frame ambient / projector ratio."""
        return next((row["recording"], row["rendering"]) for row in rows
                    if row["statistic"].startswith("ambient"))

    with tempfile.TemporaryDirectory(prefix="dotsim-realism-") as tmp:
        folder = args.out or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        depths = recording_depth_range() if args.scene_depths == "recording" else None
        if depths is not None:
            print(f"the real frame's depths (SGBM with LCN against its pattern), 5th-95th percentile: "
                  f"{depths[0]:g}-{depths[1]:g} m: [scene] distance = [{depths[0]:g}, {depths[1]:g}], "
                  f"back_wall_distance = [{depths[1]:g}, {depths[1]:g}]")
        rows = compare("config", render("config", None, None), "of the config")
        if rows is None:
            return 1
        # the real frame's ambient / projector ratio, by the one-frame estimate (it has no projector-off
        # frame to fit it from): the rooms below are lit evenly from the ceiling to it
        ratio = ambient(rows)[0]
        # fitted as docs/CAPTURE.md "Fitting the sensor" says: the noise from the frame alone, then the
        # camera's blur and the speckle against a still rendering of the config with that noise and
        # neither blur nor speckle of its own (the projector's defocus is the config's), lit as the real
        # room is, so that its single frames also tell the one-frame noise estimate's bias
        noise = folder / "kinect_noise.toml"
        if dotsim(["capture", "fit-sensor", str(REAL / "ir.png"), "-o", str(noise)]) != 0:
            return 1
        unblurred = {**tomllib.loads(noise.read_text())["sensor"], "blur_sigma": 0.0, "speckle_contrast": 0.0}
        reference = render("reference", unblurred, ratio)
        fitted = folder / "kinect_fitted.toml"
        if dotsim(["capture", "fit-sensor", str(REAL / "ir.png"), "--compare", str(reference),
                   "-o", str(fitted)]) != 0:
            return 1
        table = tomllib.loads(fitted.read_text())["sensor"]
        status = 0 if compare("fitted", render("fitted", table, None), "fitted") else 1
        rows = compare("fitted_lit", render("fitted_lit", table, ratio),
                       f"fitted, lit from the ceiling to [lighting] ambient_ratio = {ratio:.3g}")
        if rows is None:
            return 1
        # lit again to that ratio scaled by the real frame's estimate over the rendering's, so that the same
        # one-frame estimate reads alike on both (it counts the scene's texture and misses the light of
        # clipped dots, biases a target ratio does not see), as --compare fits the blur on both sides
        real, rendered = ambient(rows)
        matched = ratio * real / rendered
        if compare("fitted_lit_matched", render("fitted_lit_matched", table, matched),
                   f"fitted, lit from the ceiling to [lighting] ambient_ratio = {matched:.3g}") is None:
            status = 1
    return status


if __name__ == "__main__":
    raise SystemExit(main())
