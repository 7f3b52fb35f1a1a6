"""`dotsim view`: a scene in the Rerun viewer (rerun-sdk, the optional extra `dotsim[view]`).

What is logged (timeline `frame` = frame index; world frame z up, metres, as docs/SCENE_SPEC.md):

- `world/pose_K` (static): the rig at frame K's pose (world_from_camera), its IR camera frustum
  `world/pose_K/camera` and projector frustum `world/pose_K/projector` (placed by the rig's
  projector_translation and projector_rotation), and for a scene of a stereo pair the right
  camera's frustum `world/pose_K/camera_right` (at the rig's second_camera_translation); a capture
  without poses shows them at the origin;
- `world/pose_K/ground_truth`: the frame's ground-truth depth as points in the rig (camera) frame,
  shaded by the flood pass (as `world/camera/flood`; by the IR where a frame has no flood);
- `world/camera`: the IR camera of the current frame, its pose (world_from_camera) on the timeline and
  its Pinhole, with the frame's passes under it, so that the viewer draws them in its frustum and
  back-projects the depth into 3D: `world/camera/ir` (float values as stored), `.../ambient`,
  `.../flood` (uint8 as `dotsim show` draws them: square root of value over the frame's 99th
  percentile), `.../depth` (a DepthImage in metres), `.../visibility`, `.../edge` (0 / 255), the
  device's own depth `.../device_depth` where the scene has it (a DepthImage, 0 where the device gave
  none, as devices report it), and of a stereo pair `.../ir_right` and `.../stereo_visibility`, with
  labels `.../instance` and `.../material` (segmentation images: a colour per label) and
  `.../transparent_or_mirror`, with normals `.../normal_x` (the three components as one RGB image,
  (n + 1) / 2): the frame's channels (VIEWED, those the scene has), the IR sequence over frames;
- with a colour camera ([render] rgb; scene.json `colour_camera`): its frustum `world/pose_K/colour_camera`
  (placed by its pose on the rig), and `world/colour_camera`, the colour camera of the current frame
  (its own Pinhole and pose) with its image `world/colour_camera/rgb` (sRGB, white at its 99th
  percentile, as `dotsim show` draws it);
- with predictions (a folder of `dotsim infer` outputs, scene_SSSSSSS_frame_K.exr, for any of the
  scene's frames): the predicted cloud `world/pose_K/prediction` beside the truth (up to the rig's
  max_depth), coloured by its disparity error, and `world/camera/error`, that error as an image
  (turbo over 0..5 camera px, black where no ground truth), cleared on frames without a prediction.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from commands.show import grey_for_display, scene_path_of
from dotsim import dataset as ds
from dotsim.channels import CHANNEL, CHANNELS, NORMAL_CHANNELS
from dotsim.command_options import add_output
from dotsim.false_colour import colour_image, colourise, normal_colours
from dotsim.file_io import atomic_write_bytes
from dotsim.option_types import integer
from dotsim.pointcloud import depth_points, grey_levels
from dotsim.prediction_file import PREDICTION_ATTRIBUTE, prediction_path, prediction_source
from dotsim.rig.colour_camera import ColourCamera
from dotsim.rig.geometry import Rig, is_ground_truth

# The channels logged under camera/ (dotsim.channels): the grey ones and the masks, and depth in metres
# as a depth image (the other colour-mapped channels are what the clouds show).
VIEWED = tuple(c.name for c in CHANNELS
               if c.display in ("linear", "radiance", "mask", "labels", "normal")
               or (c.display == "colour" and c.unit == "m"))
ERROR_RANGE_PX = 5.0  # the error image's colour scale, as `dotsim eval`'s error images
FRUSTUM_DEPTH = 0.3  # metres from the centre to the drawn image plane
CAMERA = "world/camera"  # the current frame's camera: its Pinhole, with the frame's images under it
# The current frame's colour camera ([render] rgb): its own Pinhole and pose, its image under it.
COLOUR_CAMERA = "world/colour_camera"
# The channels of the colour camera (their own size), shown under COLOUR_CAMERA.
COLOUR_VIEWED = tuple(c.name for c in CHANNELS if c.camera == "colour" and c.display == "colour image")


class ViewError(ValueError):
    """The viewer cannot run (rerun-sdk missing) or its input is unusable; the message says which."""


def _rerun():
    try:
        import rerun
    except ImportError:
        raise ViewError('dotsim view needs rerun-sdk: pip install "dotsim[view]"') from None
    return rerun


def disparity_error(predicted: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """|predicted - truth| in camera px; nan where either is missing."""
    return np.abs(predicted.astype(np.float64) - truth.astype(np.float64))


def _rgb(bgr: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(bgr[..., ::-1])


def _pose(pose) -> np.ndarray:
    """A frame's world_from_camera (4 x 4); the identity where a capture has none."""
    return np.eye(4) if pose is None else np.asarray(pose, np.float64)


def _pinhole(rr, intrinsics):
    return rr.Pinhole(image_from_camera=intrinsics.K, resolution=[intrinsics.width, intrinsics.height],
                      camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=FRUSTUM_DEPTH)


def viewer_image(rr, frame: dict[str, np.ndarray], name: str):
    """Channel `name` of `frame` as the viewer shows it: linear ones (IR) as stored; radiance as the
    contact sheet draws it (its automatic range would show 1 / r^2 light as a few bright objects on
    black); masks 0 / 255; labels as a segmentation image (the viewer gives each label a colour);
    normals as the contact sheet's RGB; metres as a depth image (0 where nothing is hit)."""
    image = frame[name]
    display = CHANNEL[name].display
    if display == "labels":
        return rr.SegmentationImage(image.astype(np.uint16))
    if display == "normal":
        return rr.Image(_rgb(normal_colours(*(frame[axis] for axis in NORMAL_CHANNELS))))
    if display == "linear":
        return rr.Image(image.astype(np.float32), color_model="L")
    if display == "radiance":
        return rr.Image(grey_for_display(image, name), color_model="L")
    if display == "mask":
        return rr.Image(image * np.uint8(255), color_model="L")
    return rr.DepthImage(np.where(np.isfinite(image), image, 0), meter=1.0)


def log_rig(rr, rec, k: int, pose, rig: Rig, stereo: bool = False,
            colour: ColourCamera | None = None) -> None:
    """Static: the rig at pose K with its camera and projector frusta, with `stereo` its right camera's,
    and with `colour` its colour camera's."""
    pose = _pose(pose)
    base = f"world/pose_{k}"
    rec.log(base, rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3]), static=True)
    frusta = [("camera", rig.camera), ("projector", rig.projector)]
    if stereo:
        rec.log(f"{base}/camera_right", rr.Transform3D(translation=rig.second_camera_translation),
                static=True)
        frusta.append(("camera_right", rig.camera))
    for name, intr in frusta:
        if name == "projector":  # X_proj = R (X_cam - t): camera_from_projector = (R^T, t)
            rec.log(f"{base}/projector", rr.Transform3D(translation=rig.t, mat3x3=rig.R.T), static=True)
        rec.log(f"{base}/{name}", _pinhole(rr, intr), static=True)
    if colour is not None:
        rec.log(f"{base}/colour_camera", rr.Transform3D(translation=colour.translation,
                                                         mat3x3=np.array(colour.rotation)), static=True)
        rec.log(f"{base}/colour_camera", _pinhole(rr, colour.intrinsics), static=True)


def layout(rr, passes: list[str], with_predictions: bool, colour_passes: list[str] = ()):
    """The viewer's opening layout: the 3D world large, the scene's `passes` (and its colour camera's
    `colour_passes`) in a grid beside it."""
    import rerun.blueprint as rrb

    passes = passes + (["error"] if with_predictions else [])
    views = [rrb.Spatial2DView(origin=f"/{CAMERA}/{p}", name=p) for p in passes]
    views += [rrb.Spatial2DView(origin=f"/{COLOUR_CAMERA}/{p}", name=p) for p in colour_passes]
    return rrb.Blueprint(rrb.Horizontal(
        rrb.Spatial3DView(origin="/world", name=("ground truth and predictions" if with_predictions
                                                 else "ground truth") + " in the world (z up)"),
        rrb.Grid(*views),
        column_shares=[3, 2]), collapse_panels=True)


def check_prediction_of(prediction: Path, frame: Path) -> None:
    """ViewError unless `prediction` (a `dotsim infer` EXR) was predicted from `frame`: the input its
    header records is that file (or no longer exists: a dataset moved since keeps its predictions)."""
    source = prediction_source(prediction)
    if source is None:
        raise ViewError(f"{prediction}: not a `dotsim infer` prediction (no {PREDICTION_ATTRIBUTE} in its "
                        "header); --predictions takes the folder `dotsim infer` wrote")
    given = Path(str(source.get("input", "")))
    if given.is_file() and given.resolve() != frame.resolve():
        raise ViewError(f"{prediction}: predicted from {given}, not from {frame}; --predictions takes the "
                        "folder `dotsim infer` wrote for this dataset's frames")


def predicted_frames(scene_path: Path, meta: dict, frames: list[int], predictions: Path) -> dict[int, Path]:
    """{frame: its prediction file} for the `frames` of the scene that have one in `predictions`, each
    checked to be this frame's (check_prediction_of) and of the scene's camera; ViewError when none
    has one or one is another's."""
    wanted = {k: prediction_path(predictions, meta["scene_index"], k) for k in frames}
    predicted = {k: path for k, path in wanted.items() if path.is_file()}
    if not predicted:
        raise ViewError(f"{predictions}: no prediction for frame(s) {frames} of scene "
                        f"{meta['scene_index']} (looked for {wanted[frames[0]].name}, ...); "
                        f"--predictions takes the folder `dotsim infer` wrote for some of its frames")
    camera = Rig.from_dict(meta["rig"]).camera
    for k, path in predicted.items():
        check_prediction_of(path, scene_path / ds.frame_name(k))
        height, width = ds.read_frame(path, verify=False, channels=("disparity",))["disparity"].shape
        if (height, width) != (camera.height, camera.width):
            raise ViewError(f"{path}: {width} x {height} px, not the scene's camera ({camera.width} x "
                            f"{camera.height}); --predictions takes the folder `dotsim infer` wrote for this "
                            "dataset's frames")
    return predicted


def log_scene(rec, scene_path: Path, frames: list[int] | None = None, predictions: Path | None = None,
              verify: bool = True) -> dict[str, int]:
    """Log a scene directory into the recording stream `rec`; returns {entity: points or pixels}."""
    rr = _rerun()
    meta = ds.read_scene_meta(scene_path, verify=verify)
    rig = Rig.from_dict(meta["rig"])
    count = len(meta["frames"])
    frames = list(range(count)) if frames is None else frames
    for k in frames:
        if not 0 <= k < count:
            raise ViewError(f"{scene_path}: no frame {k}; it has {count}")
    predicted = {} if predictions is None else predicted_frames(scene_path, meta, frames, predictions)
    passes = [name for name in VIEWED if name in meta["channels"]]
    colour_passes = [name for name in COLOUR_VIEWED if name in meta["channels"]]
    colour = ColourCamera.from_dict(meta["colour_camera"]) if meta.get("colour_camera") else None
    rec.send_blueprint(layout(rr, passes, predictions is not None, colour_passes))
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log(CAMERA, _pinhole(rr, rig.camera), static=True)
    if colour is not None:
        rec.log(COLOUR_CAMERA, _pinhole(rr, colour.intrinsics), static=True)
    sizes = {}
    for k in frames:
        log_rig(rr, rec, k, meta["poses"][k], rig, stereo="ir_right" in meta["channels"], colour=colour)
    for k in frames:
        f = ds.read_frame(scene_path / ds.frame_name(k), verify=verify, meta=meta)
        rec.set_time("frame", sequence=k)
        pose = _pose(meta["poses"][k])
        rec.log(CAMERA, rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3]))
        for name in (name for name in VIEWED if name in f):
            rec.log(f"{CAMERA}/{name}", viewer_image(rr, f, name))
        if colour is not None:
            colour_pose = colour.pose(pose)
            rec.log(COLOUR_CAMERA, rr.Transform3D(translation=colour_pose[:3, 3], mat3x3=colour_pose[:3, :3]))
            for name in (name for name in colour_passes if name in f):
                rec.log(f"{COLOUR_CAMERA}/{name}", rr.Image(_rgb(colour_image(f[name]))))
                sizes[f"{COLOUR_CAMERA}/{name}"] = int(np.prod(f[name].shape[:2]))
        # shaded by the flood pass where there is one: the IR's dots leave most points black
        grey = grey_for_display(f["flood"], "flood") if "flood" in f else grey_levels(f["ir"])
        if "depth" in f:  # a capture has no ground truth: its frames show the passes alone
            points, colours = depth_points(f["depth"], rig.camera, grey)
            cloud = rr.Points3D(points, colors=np.repeat(colours[:, None], 3, 1),
                                radii=rr.Radius.ui_points(1.5))
            rec.log(f"world/pose_{k}/ground_truth", cloud)
            sizes[f"world/pose_{k}/ground_truth"] = len(points)
        if predictions is not None and k not in predicted:
            rec.log(f"{CAMERA}/error", rr.Clear(recursive=False))  # not the error of an earlier frame
        elif predictions is not None:
            pred = ds.read_frame(predicted[k], verify=False, channels=("disparity", "depth"))
            truth = f.get("disparity", np.full_like(pred["disparity"], np.nan))
            error = disparity_error(pred["disparity"], truth)
            rec.log(f"{CAMERA}/error", rr.Image(_rgb(colourise(error, 0.0, ERROR_RANGE_PX))))
            # the predicted cloud beside the truth, coloured by its error (grey where no truth); depths
            # beyond the rig's range are left out (a few near-zero disparities would put points
            # hundreds of metres away and the viewer's camera with them)
            points, _ = depth_points(pred["depth"], rig.camera, grey, rig.max_depth)
            keep = is_ground_truth(pred["depth"], rig.max_depth)
            colours = _rgb(colourise(error, 0.0, ERROR_RANGE_PX)[keep][:, None])[:, 0]
            colours[~np.isfinite(error[keep])] = 128
            rec.log(f"world/pose_{k}/prediction", rr.Points3D(points, colors=colours,
                                                              radii=rr.Radius.ui_points(1.5)))
            sizes[f"world/pose_{k}/prediction"] = len(points)
    return sizes


def view(path, scene_index: int | None = None, frame: int | None = None, predictions=None,
         save: str | Path | None = None, verify: bool = True) -> dict[str, int]:
    """Log the scene PATH names (commands.show.scene_path_of) and write it to `save` (.rrd,
    atomically) or, without `save`, spawn the Rerun viewer on it."""
    rr = _rerun()
    if Path(path).is_file():
        raise ViewError(f"{path}: give a dataset or scene directory (the view needs scene.json)")
    scene_path = scene_path_of(path, scene_index)
    if predictions is not None and not Path(predictions).is_dir():
        raise ViewError(f"{predictions}: no such folder (--predictions takes `dotsim infer`'s --out)")
    if save is not None and Path(save).suffix != ".rrd":
        raise ViewError(f"{save}: a recording is written as .rrd")
    if predictions is not None:  # refused before a recording stream exists (one left open hangs the next)
        meta = ds.read_scene_meta(scene_path, verify=verify)
        predicted_frames(scene_path, meta, list(range(len(meta["frames"]))) if frame is None else [frame],
                         Path(predictions))
    rec = rr.RecordingStream("dotsim", recording_id=str(scene_path.resolve()))
    # A recording to save is kept in memory and written by the atomic writer, which names a full
    # disk or an unusable folder (Rerun's own file sink leaves a truncated file and says nothing).
    recording = rec.memory_recording() if save is not None else None
    if recording is None:
        rec.spawn()
    sizes = log_scene(rec, scene_path, None if frame is None else [frame],
                      None if predictions is None else Path(predictions), verify)
    rec.flush(blocking=True)
    if recording is not None:
        atomic_write_bytes(save, recording.drain_as_bytes())
    return sizes


def run(args: argparse.Namespace) -> int:
    sizes = view(args.path, args.scene, args.frame, args.predictions, args.save, not args.no_verify)
    where = f"wrote {args.save}" if args.save else "sent to the Rerun viewer"
    clouds = ", ".join(f"{k} {v}" for k, v in sizes.items())
    print(f"{where}: points per cloud: {clouds}" if clouds else
          f"{where}: the passes alone (no depth: a capture has no ground-truth cloud)")
    return 0


def add_parser(subparsers) -> argparse.ArgumentParser:
    parser = subparsers.add_parser(
        "view", help="a scene in the Rerun 3D viewer: passes, GT point clouds, frusta, predictions",
        description="Show a scene in Rerun (pip install \"dotsim[view]\"): the IR sequence, ambient, flood, "
        "depth, visibility and edge masks (and of a stereo pair the right IR and its mask) over the `frame` "
        "timeline; the ground-truth depth as a point cloud in the rig frame at each of the scene's poses "
        "(world frame, z up); the camera and projector frusta at every pose (and the right camera's of a "
        "stereo pair); with --predictions, the predicted cloud beside the truth and the disparity error "
        "image. Without -o it spawns the viewer; -o OUT.rrd writes a recording instead (open it "
        "with `rerun OUT.rrd`, or `rerun --web-viewer OUT.rrd` in a browser).")
    parser.add_argument("path", metavar="DIR", help="dataset dir (first scene, or --scene N) or scene dir")
    parser.add_argument("--scene", type=integer(0), default=None, metavar="N",
                        help="scene index in a dataset")
    parser.add_argument("--frame", type=integer(0), default=None, metavar="K",
                        help="only frame K (default: all)")
    parser.add_argument("--predictions", default=None, metavar="EVAL_DIR",
                        help="folder of `dotsim infer` outputs for any of the scene's frames "
                        "(scene_SSSSSSS_frame_K.exr)")
    add_output(parser, "write a recording (.rrd); spawn no viewer", metavar="OUT.rrd", required=False,
               old=("--save",), dest="save")
    parser.add_argument("--no-verify", action="store_true", help="skip sha256 checks of the files read")
    parser.set_defaults(func=run, errors={ViewError: 1, ds.FormatError: 1})
    return parser
