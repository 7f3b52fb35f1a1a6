"""`dotsim capture`: import recorded sensor frames as a dataset, extract a pattern from wall captures, or
fit the simulated sensor to a recording (fit-sensor)."""

from __future__ import annotations

import argparse
import io
import json
import sys
import time
from pathlib import Path

import numpy as np

from capture.devices import DEVICE_SYNTAX, device_rig_file, open_device
from capture.dots import DEFAULT_DOT_WINDOW, DEFAULT_VISIBILITY_THRESHOLD
from capture.frames import CaptureError, list_images, read_image, recorded_images
from capture.import_frames import check_capture_folder, import_frames
from capture.record import record
from capture.rectify import rectifier
from capture.wall_pattern import DEFAULT_DETECT_THRESHOLD, WallPatternError, extract_wall_pattern
from dotsim.command_options import add_no_progress, add_output
from dotsim.config_schema import ConfigError, bounds_of
from dotsim.dataset import INDEX_FILE, FormatError
from dotsim.file_io import atomic_write_bytes, check_writable_folder, make_folder
from dotsim.option_types import integer, number
from dotsim.patterns import PatternError, load_pattern, pattern_statistics
from dotsim.rig.files import CalibratedRig, RigFileError, composed_rig
from dotsim.rig.geometry import DEFAULT_MAX_DEPTH, Rig
from dotsim.rig.options import rig_from_options
from dotsim.rig.presets import DEFAULT_PRESET, PRESETS
from dotsim.rig.report import summary_line
from generator.config import OutputConfig

# The nearest depth SGBM's range is sized for when a rendering's config gives none, m.
DEFAULT_NEAREST = 0.5
# Integer depth images from OpenNI2, librealsense and the Structure SDK hold millimetres.
PNG_DEPTH_SCALE = 0.001


def load_rig(spec: str | None, scale: float = 1.0, camera_file: str | None = None) -> CalibratedRig:
    """The rig `--rig SPEC` and `--camera-file FILE` name (dotsim.rig.options.rig_from_options: a preset, a
    rig file, a camera-only calibration with the preset's projector, or a generator config whose [rig]
    describes it, at scale 1; default the preset structure_core), then scaled. The lens of a calibrated
    camera comes with it: frames are rectified to the rig camera. Raises CaptureError naming the file.
    """
    try:
        calibrated = rig_from_options(spec, camera_file)
    except ConfigError as error:
        raise CaptureError(str(error)) from None
    if scale != 1.0:
        try:
            calibrated = calibrated.scaled(scale)
        except ValueError as error:
            raise CaptureError(f"--scale: {error}") from None
    return calibrated


def device_or_given_rig(args: argparse.Namespace, device) -> CalibratedRig:
    """The rig of `capture record` and `import --bag`: --rig's (with --camera-file), else the device's
    own calibration, its camera replaced by --camera-file's when given."""
    if args.rig:
        return load_rig(args.rig, getattr(args, "scale", 1.0), args.camera_file)
    if not args.camera_file:
        return CalibratedRig(device.rig())
    try:
        return composed_rig(device.rig(), str(Path(args.camera_file).resolve()),
                            base_name=f"the calibration {device.name} reports")
    except RigFileError as error:
        raise CaptureError(f"--camera-file {error}") from None


def say_rig(calibrated: CalibratedRig) -> None:
    """The rig a capture command uses, in one line (as `dotsim generate` prints it), and its notes."""
    print(summary_line(calibrated), flush=True)
    for note in calibrated.notes:
        print(note, file=sys.stderr)


def _rig_arguments(parser: argparse.ArgumentParser, default_note: str = "", camera_file: bool = True) -> None:
    parser.add_argument("--rig", default=None,
                        help=f"rig preset ({', '.join(sorted(PRESETS))}; default {DEFAULT_PRESET}"
                        f"{default_note}), a rig "
                        "file (dotsim rig JSON, OpenCV, ROS camera_info or Kalibr calibration; "
                        "docs/GEOMETRY.md; a camera-only file gets the preset's projector, and says so) "
                        "or a generator config whose [rig] gives it (camera_file with a preset's projector, "
                        "...); the frames must have its camera resolution, and a calibrated lens "
                        "(distortion) is rectified to the rig's pinhole camera")
    if camera_file:
        parser.add_argument("--camera-file", metavar="FILE", default=None,
                            help="the IR camera from this calibration file (OpenCV's calibration sample, ROS "
                            "camera_info, Kalibr) instead of the rig's; the projector and its pose stay the "
                            "rig's (as [rig] camera_file of a generator config)")
    parser.add_argument("--scale", type=number(0.0, 1.0, low_open=True), default=1.0,
                        help="scale the rig first (Rig.scaled; for frames recorded at a reduced "
                        "resolution; default 1)")


def _dataset_arguments(parser: argparse.ArgumentParser) -> None:
    """What a real-capture dataset records beside its frames (import and record alike)."""
    parser.add_argument("--split", choices=("train", "test"), default="test",
                        help="split recorded for every scene (default test)")
    parser.add_argument("--dot-window", type=integer(1), default=DEFAULT_DOT_WINDOW,
                        help="px; at least the widest gap between neighbouring dots in the image "
                        f"(default {DEFAULT_DOT_WINDOW})")
    parser.add_argument("--visibility-threshold", type=number(0.0), default=DEFAULT_VISIBILITY_THRESHOLD,
                        help="visible where the dots add more than this share of the 99th-percentile "
                        f"brightness (default {DEFAULT_VISIBILITY_THRESHOLD})")
    parser.add_argument("--pattern", type=Path,
                        help="the sensor's pattern image (e.g. from `dotsim capture pattern`), copied to "
                        "DATASET/pattern.png and referenced by every scene")
    parser.add_argument("--scenes-per-shard", type=integer(**bounds_of(OutputConfig, "scenes_per_shard")),
                        default=100, help="scenes per shard (default 100)")


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    parser = subparsers.add_parser(
        "capture",
        help="import real sensor frames as a dataset, or extract a dot pattern from wall captures",
        description="Tools for real sensor recordings, saved by the sensor's own SDK as greyscale "
        "8/16-bit PNG or EXR frames (docs/CAPTURE.md says how to record them).",
    )
    actions = parser.add_subparsers(dest="capture_command", metavar="ACTION", required=True)

    imp = actions.add_parser(
        "import",
        help="write projector-on/off frame pairs into the dotsim dataset format (no ground truth)",
        description="Read projector-on and projector-off frames, pair them in natural sort order "
        "(frame_2 before frame_10; the counts must be equal), check every file (readable, greyscale, "
        "the rig camera's size, one sample type) before writing anything, and write a sealed "
        "dataset: channels ir (projector on), ambient (projector off) and visibility (from their "
        "difference), values = raw / white level. scene.json says has_ground_truth: false and "
        "lists every source file with its sha256. A rerun resumes; other files into the same "
        "--out are refused. Or read a RealSense recording (--bag): its left IR frames paired on/off by "
        "the emitter state each frame recorded (every frame as ir when only one state was recorded), "
        "its depth as device_depth, and by default the rig of its recorded calibration, as `capture "
        "record` stores a live sensor; --stereo also its right IR frames (infrared 2) as ir_right. "
        "With --on, --right adds the right IR camera's projector-on frames of a stereo pair as ir_right.",
    )
    source = imp.add_mutually_exclusive_group(required=True)
    source.add_argument("--on", metavar="DIR_OR_GLOB",
                        help="projector-on frames: a folder of .png/.exr files, one file, or a quoted glob")
    source.add_argument("--bag", type=Path, metavar="FILE",
                        help="a RealSense recording: .bag (RealSense Viewer, SDK up to 2.55) or .db3 (SDK "
                        "2.56 on); needs dotsim[realsense]")
    imp.add_argument("--off", metavar="DIR_OR_GLOB", help="projector-off frames, likewise (with --on)")
    imp.add_argument("--right", metavar="DIR_OR_GLOB",
                     help="the right IR camera's projector-on frames of a stereo pair, likewise (with --on; "
                     "paired with --on in the same order, the same count), stored as ir_right; the rig's "
                     "second camera must be the right one (realsense_d415, realsense_d435, structure_core, "
                     "or a rig file with second_camera_translation = [B, 0, 0])")
    imp.add_argument("--stereo", action="store_true",
                     help="with --bag: the recording's right IR frames (infrared 2) too, as ir_right")
    _rig_arguments(imp, "; with --bag: the recording's own calibration")
    add_output(imp, "dataset folder to write", metavar="DATASET", type=Path)
    imp.add_argument("--frames-per-scene", type=integer(1), default=4,
                     help="consecutive frame pairs per scene; must divide the pair count (default 4)")
    imp.add_argument("--white-level", type=number(0.0, low_open=True),
                     help="raw value stored as 1.0 (default: full scale of the files: 255, 65535, "
                     "or 1 for EXR; e.g. 1023 for 10-bit data in 16-bit PNGs)")
    imp.add_argument("--settings", type=Path,
                     help="JSON file of capture settings (exposure, gain, sensor serial, ...) copied into "
                     "every scene.json")
    _dataset_arguments(imp)
    add_no_progress(imp)
    imp.set_defaults(func=_import)

    pat = actions.add_parser(
        "pattern",
        help="extract the projector's dot pattern from captures of a flat wall",
        description="Average the projector-on wall captures (minus the projector-off ones), detect "
        "the dots with sub-pixel centres, trace each to the projector image through the rig "
        "(camera ray -> wall at the given depth -> projector pixel), and draw them as Gaussian "
        "dots at the projector's resolution. Writes OUTPUT (16-bit PNG), OUTPUT.csv (projector "
        "and camera centres of every dot) and OUTPUT.json (statistics, sources, settings), and "
        "prints the statistics. Only the part of the projector's field the camera sees is recovered.",
    )
    pat.add_argument("--wall", required=True, nargs="+", metavar="IMG",
                     help="projector-on wall captures: files, folders or quoted globs (averaged), or a "
                     "dataset from `capture record` (its ir frames)")
    pat.add_argument("--off", nargs="+", metavar="IMG", default=[],
                     help="projector-off captures of the same wall (averaged and subtracted), or a "
                     "recorded dataset (its ambient frames); leave out in a dark room")
    depth = pat.add_mutually_exclusive_group(required=True)
    depth.add_argument("--distance", type=number(0.0, low_open=True), metavar="Z",
                       help="planar distance of the wall in metres (wall facing the camera squarely)")
    depth.add_argument("--depth-map", type=Path, metavar="FILE",
                       help="the wall's planar depth map at the camera resolution (PNG in millimetres or "
                       "EXR in metres; 0 = no reading), e.g. the sensor's own, for a tilted wall")
    pat.add_argument("--depth-scale", type=number(0.0, low_open=True),
                     help="metres per depth-map unit (default 0.001 for PNG, 1 for EXR)")
    _rig_arguments(pat)
    pat.add_argument("--dot-sigma", type=number(0.0, low_open=True),
                     help="Gaussian std of the pattern's dots in projector px (default: measured "
                     "from the captures)")
    pat.add_argument("--dot-window", type=integer(1), default=DEFAULT_DOT_WINDOW,
                     help="px; at least the widest gap between neighbouring dots in the image: sets "
                     f"the local brightness scale (default {DEFAULT_DOT_WINDOW})")
    pat.add_argument("--detect-threshold", type=number(0.0, 1.0), default=DEFAULT_DETECT_THRESHOLD,
                     help="keep local maxima above this share of the local dot brightness "
                     f"(default {DEFAULT_DETECT_THRESHOLD})")
    add_output(pat, "output pattern .png", metavar="PNG", old=("--output",), dest="output", type=Path)
    pat.set_defaults(func=_pattern)

    rec = actions.add_parser(
        "record",
        help="record a live sensor (RealSense, OpenNI2, OpenCV camera or video) as a dataset",
        description="Record --scenes x --frames poses from a live sensor into a sealed dataset in "
        "the format of `capture import`: per pose the IR frame with the projector on and, where the "
        "device can switch it (RealSense, OpenNI2), the same pose with it off (channels ir, ambient, "
        "visibility), and the device's own depth where it has one (channel device_depth, never "
        "ground truth). Auto exposure is switched off. scene.json records the device (model, "
        "serial, stream), its exposure settings, and each frame's number and timestamp. Ctrl-C, "
        "SIGTERM, SIGHUP or an unplugged device ends the recording and keeps every complete frame. A "
        "live preview shows when a display and an OpenCV with windows are there.",
    )
    _device_arguments(rec)
    add_output(rec, "new dataset folder", metavar="DATASET", type=Path)
    rec.add_argument("--scenes", type=integer(1), default=1, help="scenes to record (default 1)")
    rec.add_argument("--frames", type=integer(1), default=4, help="poses per scene (default 4)")
    rec.add_argument("--rig", help="rig preset, rig file or generator config (as for import) for the frames "
                     "(default: the device's own calibration, as `capture info` writes it; required for "
                     "opencv devices); a calibrated lens is rectified to the rig's pinhole camera")
    rec.add_argument("--camera-file", metavar="FILE", default=None,
                     help="the IR camera from this calibration file (OpenCV's calibration sample, ROS "
                     "camera_info, Kalibr) instead of the rig's or the device's; the projector and its pose "
                     "stay theirs")
    rec.add_argument("--exposure", type=number(0.0, low_open=True),
                     help="fixed exposure in the device's units (default: as set)")
    rec.add_argument("--gain", type=number(0.0, low_open=True),
                     help="fixed gain in the device's units (default: as set)")
    rec.add_argument("--settle", type=integer(0), default=3,
                     help="frames dropped after switching the projector when the frames do not report its "
                     "state (default 3)")
    rec.add_argument("--pause", type=number(0.0), default=0.0,
                     help="seconds between poses, to move the sensor or the scene (default 0)")
    rec.add_argument("--white-level", type=number(0.0, low_open=True),
                     help="raw value stored as 1.0 (default: the stream's full scale: 255 for 8-bit, 65535 "
                     "for RealSense y16, the stream maximum for OpenNI2; e.g. 1023 for 10-bit data)")
    rec.add_argument("--stereo", action="store_true",
                     help="RealSense: record the right IR stream (infrared 2) too, as ir_right, with its "
                     "extrinsics; the rig's second camera must be the right one (the device's own rig is)")
    _dataset_arguments(rec)
    rec.add_argument("--no-preview", action="store_true", help="no live preview window")
    add_no_progress(rec)
    rec.set_defaults(func=_record)

    info = actions.add_parser(
        "info",
        help="write a device's rig file (its calibration) and print what it offers",
        description="Open the device, read its IR camera's calibration and write it as a dotsim rig "
        "file ({\"rig\": ..., \"device\": ...}; `[rig] file` and `--rig` read it). A RealSense's "
        "projector is placed at its right IR camera; OpenNI2 reports only fields of view "
        "(docs/CAPTURE.md says what each device gives).",
    )
    _device_arguments(info)
    info.add_argument("--max-depth", type=number(**bounds_of(Rig, "max_depth")), default=DEFAULT_MAX_DEPTH,
                      help=f"max_depth of the rig, m (default {DEFAULT_MAX_DEPTH:g})")
    add_output(info, "rig file to write (.json)", metavar="JSON", old=("--output",), dest="output", type=Path)
    info.set_defaults(func=_info)

    fit = actions.add_parser(
        "fit-sensor",
        help="fit the simulated sensor to a recording: noise, levels, dot size, speckle; a [sensor] table",
        description="Measure a recording of a still scene the way camera characterisation does (EMVA 1288's "
        "photon transfer: temporal variance against mean level gives read and shot noise; black level, "
        "saturation, bit depth), its dots (FWHM of isolated dots on flat regions, their brightness spread: "
        "laser speckle; peak signal-to-noise ratio; dots per area by depth where depth is known) and the "
        "ambient light over the projector's (with projector-off frames); print them with their standard "
        "errors and write a [sensor] table to paste into a generator config (OUTPUT.toml; with projector-off "
        "frames a [lighting] table too: the ambient_ratio range of the scenes) and a drawing "
        "(OUTPUT.png). Clipped samples (at or above where the sensor saturates) are left out of every "
        "statistic, with their count. At least 4 frames of the still scene (16 or more recommended); with "
        "one frame the noise comes from flat regions of it (spatial statistics), and it says so. With "
        "--compare, the same statistics of a rendering of your config side by side, blur_sigma and "
        "speckle_contrast set so its dots match the recording's, and a one-frame recording's noise freed of "
        "what its flat regions' texture adds, calibrated on the rendering (render it lit as the recorded "
        "room) (docs/CAPTURE.md \"Fitting the sensor\").",
    )
    fit.add_argument("recording", nargs="+", metavar="RECORDING",
                     help="projector-on frames of a still scene: image files, folders or quoted globs "
                     "(8/16-bit PNG or EXR, raw sensor values); or one dataset from `capture record` / "
                     "`capture import` (each scene a still scene; ir on, ambient off) or a static rendering "
                     "of `dotsim generate`")
    fit.add_argument("--off", nargs="+", metavar="IMG", default=[],
                     help="projector-off frames of the same still scene (image recordings; a dataset's are "
                     "its ambient frames): the ambient light, and more levels for the noise")
    fit.add_argument("--white-level", type=number(0.0, low_open=True),
                     help="raw value of full scale (default: the files' full scale: 255, 65535, or 1 for "
                     "EXR; e.g. 1023 for 10-bit data in 16-bit PNGs: 16-bit files whose values fit in 12 "
                     "bits are refused without it); at least the data's maximum")
    fit.add_argument("--compare", type=Path, metavar="DATASET",
                     help="a rendering of your config with still scenes (`dotsim generate` with [motion] "
                     "translation = 0 and rotation = 0) with the recording's rig, at any scale (its camera "
                     "is checked: field of view, or aspect ratio for image files): its statistics beside "
                     "the recording's, and blur_sigma and speckle_contrast fitted against it (and "
                     "projector_aperture and projector_focus from the dots' widths against depth where the "
                     "recording has depth)")
    fit.add_argument("--speckle-grain", type=number(0.0, 100.0, low_open=True),
                     help="the speckle grain assumed, full-resolution px ([sensor] speckle_grain; default: "
                     "the --compare rendering's, else 2)")
    add_output(fit, "the [sensor] table to write (.toml); the drawing goes beside it (.png)",
               metavar="SENSOR.toml", old=("--output",), dest="output", type=Path)
    fit.set_defaults(func=_fit_sensor)

    compare = actions.add_parser(
        "compare",
        help="a realism report: a recording beside a rendering of the config for its sensor, statistic by "
        "statistic, and a picture",
        description="Measure a recording of a still scene and a still rendering of your config the same way "
        "(fit-sensor's statistics, plus from one frame the ambient light over the projector's and the share "
        "of pixels OpenCV's SGBM leaves unmatched: left against right IR for a stereo pair, against the "
        "reference pattern for a mono sensor) and print one table: each statistic for both and their ratio, "
        "rendering over recording, in the recording's pixels (a one-frame recording beside the rendering's "
        "frames each alone; one-frame statistics averaged over the scenes). Writes the table (OUTPUT.json) "
        "and a picture "
        "(OUTPUT.png): crops of both frames at the same scale side by side, the noise against level, the "
        "dots' FWHM and peak SNR histograms (docs/CAPTURE.md \"How real a rendering looks\").",
    )
    compare.add_argument("recording", nargs="+", metavar="RECORDING",
                         help="as fit-sensor's: image files, folders or quoted globs of one still scene, or "
                         "one dataset of `capture import` / `capture record`")
    compare.add_argument("rendering", type=Path, metavar="DATASET",
                         help="a still rendering of your config with the recording's rig, at any [rig] scale "
                         "(`dotsim generate` with [motion] translation = 0 and rotation = 0)")
    compare.add_argument("--off", nargs="+", metavar="IMG", default=[],
                         help="projector-off frames of the recording's still scene (image recordings)")
    compare.add_argument("--white-level", type=number(0.0, low_open=True),
                         help="raw value of full scale of image recordings (as fit-sensor's)")
    compare.add_argument("--pattern", type=Path, metavar="PNG",
                         help="a mono recording's reference pattern in its camera's pixels (the pattern "
                         "as seen from infinity, the frame's size) for SGBM; a dataset's is its pattern.png "
                         "seen through its rig")
    compare.add_argument("--right", nargs="+", metavar="IMG", default=[],
                         help="a stereo recording's right IR frames (image recordings; a dataset's are its "
                         "ir_right): SGBM then matches left against right")
    compare.add_argument("--num-disparities", type=integer(16),
                         help="SGBM's disparity range in the rendering's px, a multiple of 16 (default: what "
                         "the rendering's nearest [scene] distance needs through its rig); the recording's "
                         "is scaled to its pixels")
    add_output(compare, "the report's picture (.png); the table goes beside it (.json)", metavar="REPORT.png",
               dest="output", type=Path)
    compare.set_defaults(func=_compare)


def _size(text: str) -> tuple[int, int]:
    width, _, height = text.partition("x")
    if not (width.isdigit() and height.isdigit() and int(width) > 0 and int(height) > 0):
        raise argparse.ArgumentTypeError(f"{text!r} is not WIDTHxHEIGHT in pixels, e.g. 848x480")
    return int(width), int(height)


def _device_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--device", required=True, metavar="DEVICE",
                        help=f"the sensor: {DEVICE_SYNTAX} (RealSense needs the extra dotsim[realsense], "
                        "OpenNI2 dotsim[openni2])")
    parser.add_argument("--size", type=_size, metavar="WxH", help="IR stream size (default: the device's)")
    parser.add_argument("--fps", type=integer(1), help="IR stream frame rate (default: the device's)")
    parser.add_argument("--ir-format", choices=("y8", "y16"), default="y8",
                        help="RealSense IR format (y16: full bit depth; default y8)")


def _open(args: argparse.Namespace, **fixed):
    return open_device(args.device, size=args.size, fps=args.fps, ir_format=args.ir_format, **fixed)


def _fail(action: str, error: Exception) -> int:
    print(f"dotsim capture {action}: error: {error}", file=sys.stderr)
    return 2


def _read_json(path: Path, what: str) -> dict:
    try:
        value = json.loads(path.read_text())
    except OSError as error:
        raise CaptureError(f"{what} {path}: cannot read ({error.strerror})") from None
    except ValueError as error:
        raise CaptureError(f"{what} {path}: not valid JSON ({error})") from None
    if not isinstance(value, dict):
        raise CaptureError(f"{what} {path}: expected a JSON object, found {type(value).__name__}")
    return value


def _import(args: argparse.Namespace) -> int:
    try:
        check_capture_folder(args.out, "dotsim capture import")  # before any frame is read
    except CaptureError as error:
        return _fail("import", error)
    if args.bag is not None:
        return _import_recording(args)
    start = time.perf_counter()
    try:
        if args.off is None:
            raise CaptureError("--on needs --off (the projector-off frames), or import a recording: --bag")
        if args.stereo:
            raise CaptureError("--stereo is for --bag; with --on, give the right camera's frames: --right")
        calibrated = load_rig(args.rig, args.scale, args.camera_file)
        say_rig(calibrated)
        rig = calibrated.rig
        settings = _read_json(args.settings, "--settings") if args.settings else {}
        pattern = None
        if args.pattern:
            pattern = load_pattern(args.pattern, expected_shape=(rig.projector.height, rig.projector.width))
        summary = import_frames(args.on, args.off, rig, args.out, frames_per_scene=args.frames_per_scene,
                                split=args.split, white_level=args.white_level, dot_window=args.dot_window,
                                visibility_threshold=args.visibility_threshold, capture_settings=settings,
                                pattern=pattern, scenes_per_shard=args.scenes_per_shard, lens=calibrated.lens,
                                progress=not args.no_progress, right_spec=args.right)
    except (CaptureError, PatternError, FormatError, ValueError) as error:
        return _fail("import", error)
    print(f"imported {summary['frames']} frame pairs as {summary['scenes']} scene(s) into "
          f"{summary['dataset']} ({summary['written']} written, {summary['skipped']} already there) in "
          f"{time.perf_counter() - start:.1f} s")
    return 0


def _import_recording(args: argparse.Namespace) -> int:
    """`capture import --bag`: a RealSense recording played back through `capture record`'s writer."""
    from capture.devices.realsense import RealSenseRecording

    start = time.perf_counter()
    try:
        if args.off is not None or args.settings is not None or args.right is not None:
            raise CaptureError("--bag: leave out --off, --right and --settings (the recording's emitter "
                               "states pair its frames, --stereo adds its right IR frames, and its options "
                               "are stored from the file)")
        pattern = load_pattern(args.pattern) if args.pattern else None
        with RealSenseRecording(args.bag, stereo=args.stereo) as device:
            calibrated = device_or_given_rig(args, device)
            say_rig(calibrated)
            if device.poses == 0:
                raise CaptureError(f"--bag {args.bag}: holds no complete pose (an IR frame, and an off frame "
                                   "after an on frame when the emitter switched)")
            scenes = -(-device.poses // args.frames_per_scene)
            summary = record(device, calibrated.rig, args.out, lens=calibrated.lens, scenes=scenes,
                             frames_per_scene=args.frames_per_scene, split=args.split, settle=0,
                             white_level=args.white_level, pattern=pattern, dot_window=args.dot_window,
                             visibility_threshold=args.visibility_threshold,
                             scenes_per_shard=args.scenes_per_shard, progress=False, preview=False)
    except (CaptureError, PatternError, FormatError, ValueError) as error:
        return _fail("import", error)
    if summary["frames"] < device.poses:
        return _fail("import", CaptureError(f"--bag {args.bag}: stopped after {summary['frames']} of "
                                            f"{device.poses} poses ({summary['stopped']}); kept those"))
    print(f"imported {summary['frames']} poses of {args.bag} as {summary['scenes']} scene(s) into "
          f"{summary['dataset']} (channels {', '.join(summary['channels'])}) in "
          f"{time.perf_counter() - start:.1f} s")
    return 0


def read_depth_map(path: Path, scale: float | None) -> np.ndarray:
    """A depth image as planar depth in metres (float64); 0 / non-finite -> nan (no reading)."""
    image = read_image(path)
    if scale is None:
        scale = 1.0 if image.pixels.dtype == np.float32 else PNG_DEPTH_SCALE
    if not (np.isfinite(scale) and scale > 0):
        raise CaptureError(f"--depth-scale must be a positive number, got {scale}")
    depth = image.pixels.astype(np.float64) * scale
    return np.where(np.isfinite(depth) & (depth > 0), depth, np.nan)


def _load_wall_images(specs: list[str], what: str, channel: str) -> list:
    """Images of files, folders or globs; a dataset folder (from `capture record`) gives its frames'
    `channel` (ir for --wall, ambient for --off)."""
    images = []
    for spec in specs:
        if (Path(spec) / INDEX_FILE).is_file():
            images += recorded_images(Path(spec), channel)
        else:
            images += [read_image(path) for path in list_images(spec, what=what)]
    return images


def _pattern(args: argparse.Namespace) -> int:
    check_writable_folder(args.output.parent, "-o")  # before the captures are read
    start = time.perf_counter()
    try:
        if args.output.suffix.lower() != ".png":
            raise CaptureError(f"-o {args.output}: the pattern is written as a .png file")
        calibrated = load_rig(args.rig, args.scale, args.camera_file)
        say_rig(calibrated)
        rig = calibrated.rig
        on = _load_wall_images(args.wall, "--wall", "ir")
        off = _load_wall_images(args.off, "--off", "ambient")
        for image in on + off:
            if image.shape != on[0].shape:
                raise CaptureError(f"{image.path}: {image.shape[1]} x {image.shape[0]} px, but "
                                   f"{on[0].path} is {on[0].shape[1]} x {on[0].shape[0]} px")
        if args.depth_map is not None:
            wall_depth = read_depth_map(args.depth_map, args.depth_scale)
        else:
            wall_depth = args.distance
        rectify = rectifier(calibrated.lens, rig.camera)
        on_images, off_images = ([image.relative() if rectify is None else rectify.image(image.relative())
                                  for image in images] for images in (on, off))
        result = extract_wall_pattern(on_images, off_images, rig, wall_depth, dot_sigma=args.dot_sigma,
                                      window=args.dot_window, detect_threshold=args.detect_threshold)
        statistics = pattern_statistics(result.pattern)
    except (CaptureError, WallPatternError, PatternError, ValueError) as error:
        return _fail("pattern", error)
    csv = io.StringIO()
    csv.write("x_projector,y_projector,x_camera,y_camera\n")
    np.savetxt(csv, np.hstack([result.projector_centres, result.camera_centres]), fmt="%.4f", delimiter=",")
    record = {
        "pattern": {"file": args.output.name, "sha256": result.pattern.sha256, "width": result.pattern.width,
                    "height": result.pattern.height, "params": result.pattern.params},
        "extraction": result.stats,
        "statistics": statistics,
        "rig": rig.to_dict(),
        "wall": ({"depth_map": str(args.depth_map.resolve()), "depth_scale": args.depth_scale}
                 if args.depth_map is not None else {"distance": args.distance}),
        "sources": {"on": [{"path": str(i.path.resolve()), "sha256": i.sha256} for i in on],
                    "off": [{"path": str(i.path.resolve()), "sha256": i.sha256} for i in off]},
        "settings": {"dot_window": args.dot_window, "detect_threshold": args.detect_threshold},
    }
    # the centres and the record first: the pattern file appearing means the set is complete
    make_folder(args.output.parent)
    atomic_write_bytes(args.output.with_suffix(".csv"), csv.getvalue().encode())
    atomic_write_bytes(args.output.with_suffix(".json"), (json.dumps(record, indent=2) + "\n").encode())
    result.pattern.save_png(args.output)
    stats = result.stats
    print(f"{len(on)} on / {len(off)} off capture(s): {stats['dots_detected']} dots detected, "
          f"{stats['dots_in_projector']} kept ({stats['dots_on_border']} cut by the image border), "
          f"dot sigma {stats['dot_sigma']:.2f} projector px (measured {stats['dot_sigma_measured']:.2f})")
    s = statistics
    print(f"pattern {s['width']}x{s['height']}: {s['dot_count']} dots, density {s['density']:.5f} dots/px, "
          f"spacing mean {s['mean_spacing']:.2f} / min {s['min_spacing']:.2f} px, row windows "
          f"{s['window']} px unique {100 * s['row_window_uniqueness']:.1f}% "
          f"(empty {100 * s['flat_window_share']:.1f}%)")
    print(f"wrote {args.output}, {args.output.with_suffix('.csv').name}, "
          f"{args.output.with_suffix('.json').name} in {time.perf_counter() - start:.1f} s")
    return 0


def _record(args: argparse.Namespace) -> int:
    start = time.perf_counter()
    try:
        check_capture_folder(args.out, "dotsim capture record")  # before the device is opened
        pattern = load_pattern(args.pattern) if args.pattern else None
        with _open(args, exposure=args.exposure, gain=args.gain, stereo=args.stereo) as device:
            calibrated = device_or_given_rig(args, device)
            say_rig(calibrated)
            summary = record(device, calibrated.rig, args.out, lens=calibrated.lens, scenes=args.scenes,
                             frames_per_scene=args.frames,
                             split=args.split, settle=args.settle, pause_s=args.pause,
                             white_level=args.white_level, pattern=pattern,
                             dot_window=args.dot_window, visibility_threshold=args.visibility_threshold,
                             scenes_per_shard=args.scenes_per_shard, progress=not args.no_progress,
                             preview=not args.no_preview)
    except (CaptureError, PatternError, FormatError, ValueError) as error:
        return _fail("record", error)
    kept = (f"{summary['frames']} frame(s) as {summary['scenes']} scene(s) into {summary['dataset']} "
            f"(channels {', '.join(summary['channels'])}) in {time.perf_counter() - start:.1f} s")
    if summary["stopped"]:
        print(f"dotsim capture record: stopped: {summary['stopped']}; kept every complete frame: {kept}",
              file=sys.stderr)
        return 128 + summary["signal"] if summary["signal"] else 1
    print(f"recorded {kept}")
    return 0


def _fit_sensor(args: argparse.Namespace) -> int:
    from capture.fit_report import draw_report, report_text, sensor_toml
    from capture.sensor_fit import fit, measure
    from capture.static_recording import comparison_notes, open_recording
    from dotsim.images import write_image

    start = time.perf_counter()
    try:
        if args.output.suffix.lower() != ".toml":
            raise CaptureError(f"-o {args.output}: the [sensor] table is written as a .toml file")
        if not args.output.parent.is_dir():
            raise CaptureError(f"-o {args.output}: folder {args.output.parent} does not exist")
        check_writable_folder(args.output.parent, "-o")
        recording = open_recording(args.recording, args.off, args.white_level)
        rendering = open_recording([str(args.compare)]) if args.compare is not None else None
        if rendering is not None and rendering.kind != "rendered":
            raise CaptureError(f"--compare {args.compare}: a recording, not a rendering of `dotsim generate`")
        notes = comparison_notes(recording, rendering, f"--compare {args.compare}") if rendering else []
        stats = measure(recording)
        stats.notes.extend(notes)
        reference = measure(rendering) if rendering is not None else None
        fitted = fit(stats, reference, args.speckle_grain)
    except (CaptureError, ConfigError) as error:
        return _fail("fit-sensor", error)
    header = (f"dotsim capture fit-sensor {' '.join(args.recording)}"
              + (f" --compare {args.compare}" if args.compare else "")
              + ": the simulated sensor fitted to this recording; paste into a generator config")
    # the drawing first: the table appearing means both are there
    drawing = write_image(args.output.with_suffix(".png"), draw_report(stats, reference))
    atomic_write_bytes(args.output, sensor_toml(fitted, header).encode())
    print(report_text(stats, fitted, reference))
    print(f"wrote {args.output} and {drawing} in {time.perf_counter() - start:.1f} s")
    return 0


def _compare(args: argparse.Namespace) -> int:
    from capture import realism
    from capture.sensor_fit import measure, single_frame_statistics
    from capture.static_recording import comparison_notes, open_recording
    from dotsim.images import write_image
    from trainer.sgbm import num_disparities_for

    start = time.perf_counter()
    try:
        if args.output.suffix.lower() != ".png":
            raise CaptureError(f"-o {args.output}: the report's picture is written as a .png file")
        if not args.output.parent.is_dir():
            raise CaptureError(f"-o {args.output}: folder {args.output.parent} does not exist")
        check_writable_folder(args.output.parent, "-o")
        for path in (args.output, args.output.with_suffix(".json")):  # files of its own, never a folder
            if path.is_dir():
                raise CaptureError(f"-o {args.output}: {path} is a folder; allowed: a file name (the "
                                   "report's .png, its .json table beside it)")
        if args.num_disparities is not None and args.num_disparities % 16:
            raise CaptureError(f"--num-disparities {args.num_disparities}: allowed: a multiple of 16")
        recording = open_recording(args.recording, args.off, args.white_level)
        rendering = open_recording([str(args.rendering)])
        if rendering.kind != "rendered":
            raise CaptureError(f"DATASET {args.rendering}: a recording, not a rendering of `dotsim generate`")
        notes = comparison_notes(recording, rendering, f"DATASET {args.rendering}")
        real_stats = measure(recording)
        # a one-frame recording's noise is estimated from one frame: the rendering's is too, each of its
        # frames alone, and its looks are of one frame (one frame's noise, not a mean's)
        one_frame = real_stats.method == "spatial"
        rendered_stats = measure(rendering)
        if one_frame:
            try:
                rendered_stats = single_frame_statistics(rendered_stats)
                notes.append("the recording has one frame per scene: the rendering is measured as one-frame "
                             "recordings are, each of its frames alone")
            except CaptureError as error:  # its looks below are still of one frame
                notes.append(f"the recording has one frame per scene, but the rendering's single frames "
                             f"cannot be measured so ({error}; a dark room?): its noise and dots are "
                             "measured over its frames, not as the recording's")
        frames, reference, rights, rig, nearest = realism.dataset_frames(args.rendering, one_frame)
        rendered_range = args.num_disparities or num_disparities_for(rig, nearest or DEFAULT_NEAREST)
        ratio = recording.size[0] / rendering.size[0]
        real_range = 16 * max(1, -(-round(rendered_range * ratio) // 16))
        # one window for both, the recording's, in each one's pixels
        reach = realism.dot_reach(real_stats)
        rendered_reach = max(3, round(reach / ratio))
        rendered_look = realism.scenes_look(frames, rendered_range, reference, rights,
                                            rendered_reach + 1 - rendered_reach % 2)
        if recording.kind == "images":
            real_frames = [np.mean(next(recording.scenes()).on, axis=0)]
            real_reference = read_image(args.pattern).relative() if args.pattern else None
            real_rights = None if not args.right else [np.mean(
                [read_image(p).relative(args.white_level) for spec in args.right
                 for p in list_images(spec, what="--right")], axis=0)]
        else:
            if args.pattern or args.right:
                raise CaptureError(f"{recording.name}: a dataset: its pattern.png and ir_right are used "
                                   "(leave --pattern and --right out)")
            real_frames, real_reference, real_rights, _, _ = realism.dataset_frames(Path(recording.name),
                                                                                     one_frame)
        real_look = realism.scenes_look(real_frames, real_range, real_reference, real_rights, reach)
    except (CaptureError, ConfigError, FormatError) as error:
        return _fail("compare", error)
    table = realism.rows(real_stats, real_look, rendered_stats, rendered_look)
    picture = write_image(args.output, realism.draw(real_stats, real_look, rendered_stats, rendered_look))
    record = {"recording": recording.name, "rendering": str(args.rendering), "notes": notes,
              "num_disparities": {"recording": real_range, "rendering": rendered_range},
              "noise_measured": {"recording": real_stats.method, "rendering": rendered_stats.method},
              "rows": [{"statistic": name, "recording": real, "rendering": rendered,
                        "ratio": None if real in (None, 0) or rendered is None else rendered / real}
                       for name, real, rendered in table]}
    table_file = args.output.with_suffix(".json")
    atomic_write_bytes(table_file, (json.dumps(record, indent=2) + "\n").encode())
    print(f"recording: {recording.name} ({recording.size[0]} x {recording.size[1]} px); rendering: "
          f"{args.rendering} ({rendering.size[0]} x {rendering.size[1]} px)")
    print(realism.table_text(table))
    for note in notes + real_stats.notes:
        print(f"note: {note}")
    print(f"wrote {picture} and {table_file} in {time.perf_counter() - start:.1f} s")
    return 0


def _info(args: argparse.Namespace) -> int:
    check_writable_folder(args.output.parent, "-o")  # before the device is opened
    try:
        if args.output.suffix.lower() != ".json":
            raise CaptureError(f"-o {args.output}: the rig file is written as .json")
        with _open(args) as device:
            rig, data = device_rig_file(device, args.max_depth)
    except (CaptureError, ValueError) as error:
        return _fail("info", error)
    make_folder(args.output.parent)
    atomic_write_bytes(args.output, data)
    camera = rig.camera
    print(f"{device.name}: IR {camera.width}x{camera.height} px, fx {camera.fx:.2f} fy {camera.fy:.2f}, "
          f"principal point ({camera.cx:.2f}, {camera.cy:.2f}); projector at "
          f"{[round(v, 5) for v in rig.projector_translation]} m; projector switch "
          f"{'yes' if device.can_switch_emitter else 'no'}, depth {'yes' if device.has_depth else 'no'}")
    print(f"wrote {args.output}")
    return 0
