"""``python -m glimpse`` / ``glimpse``: the commands the Makefile and users call.

  glimpse ingest VIDEO SCENE_DIR         a video -> a scene: frames, every person found and tracked (keypoints,
                                         masks), a preview video and a tracks report (docs/ingest.md)
  glimpse validate SCENE                 check a scene against glimpse-scene/1
  glimpse prepare --scene S --out O [--whole-pipeline]
                                         validate, resolve parameters, write .params/.inputs; print the run folder
  glimpse params --scene S --stage X     print the resolved parameters one stage reads
  glimpse run-dir --scene S --out O      print OUT/<scene name> without preparing
  glimpse export RUN [--frame T] [--out DIR] [--sh-degree D]
                                         a finished run's scene at frame T as one 3DGS PLY, each person's
                                         canonical and posed PLYs with body and skinning, the cameras as
                                         COLMAP text (docs/exports.md)
  glimpse render RUN [--camera input|orbit[:DEG]|heldout:NAME|json:FILE|colmap:DIR] [--time T|A:B|all]
                 [--remove p1,p2] [--motion p0=walk.npz] [--no-background] [--scene SCENE] [--out video.mp4]
                                         a finished run from any camera at any time (docs/renders.md)
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from pathlib import Path

from glimpse.errors import GlimpseError


def _params_default() -> str:
    return os.environ.get("GLIMPSE_PARAMS", "")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="glimpse", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = parser.add_subparsers(dest="command", required=True)
    p_ingest = sub.add_parser("ingest", help="a video -> a glimpse-scene/1 folder (docs/ingest.md)")
    p_ingest.add_argument("video", type=Path)
    p_ingest.add_argument("scene", type=Path, help="the scene folder to write (replaced when the ingest succeeds)")
    p_ingest.add_argument("--params", default=_params_default(), help='overrides "ingest.key=value ..." (env GLIMPSE_PARAMS)')
    p_val = sub.add_parser("validate", help="check a scene folder against glimpse-scene/1")
    p_val.add_argument("scene", type=Path)
    for name in ("prepare", "params", "run-dir"):
        p = sub.add_parser(name)
        p.add_argument("--scene", required=True, type=Path)
        p.add_argument("--out", type=Path, default=Path("runs"))
        p.add_argument("--params", default=_params_default(), help='overrides "section.key=value ..." (env GLIMPSE_PARAMS)')
        if name == "params":
            p.add_argument("--stage", required=True)
        if name == "prepare":
            p.add_argument("--whole-pipeline", action="store_true",
                           help="also refuse a scene the pipeline cannot run to the end (make all)")
    p_export = sub.add_parser("export", help="a finished run's Gaussians and cameras for other tools")
    p_export.add_argument("run", type=Path, help="the run folder, OUT/<scene>")
    p_export.add_argument("--frame", type=int, default=None, help="input frame id (default: the middle one)")
    p_export.add_argument("--out", type=Path, default=None, help="default: RUN/export")
    p_export.add_argument("--sh-degree", type=int, choices=(0, 1, 2, 3), default=None,
                          help="SH degree of the posed PLYs (default: as trained; 3 for INRIA's SIBR viewer)")
    p_render = sub.add_parser("render", help="render a finished run along a camera path (docs/renders.md)")
    p_render.add_argument("run", type=Path, help="the run folder, OUT/<scene>")
    p_render.add_argument("--camera", default="input", help="input | orbit[:DEGREES] | heldout:NAME | json:FILE | "
                                                             "colmap:FOLDER (default: input)")
    p_render.add_argument("--time", default="all", help="T | A:B | all (input frame ids; default: all)")
    p_render.add_argument("--remove", default="", help="people to leave out, comma-separated pids")
    p_render.add_argument("--no-background", action="store_true", help="the people alone, on black")
    p_render.add_argument("--scene", type=Path, default=None, help="the run's scene (for heldout cameras)")
    p_render.add_argument("--orbit-frames", type=int, default=120, help="frames of an orbit at one time")
    p_render.add_argument("--motion", action="append", default=[], metavar="PID=FILE|PID=builtin:NAME",
                          help="drive a person by a motion (.npz AMASS-style or smplx-style, or a built-in: walk, "
                               "turn, wave, side_step_dance) from their place at the first time; repeatable")
    p_render.add_argument("--motion-seconds", type=float, default=4.0, help="length of a built-in motion")
    p_render.add_argument("--fps", type=float, default=25.0, help="frames per second of the video")
    p_render.add_argument("--out", type=Path, default=None, help="an .mp4, or a folder for PNG frames "
                                                                 "(default: RUN/renders/render.mp4)")
    args = parser.parse_args(argv)
    try:
        return _dispatch(args)
    except GlimpseError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


def _dispatch(args: argparse.Namespace) -> int:
    from glimpse.pipeline.prepare import prepare_run, scene_name

    if args.command == "ingest":
        from glimpse.ingest.config import load_ingest_config
        from glimpse.ingest.stage import ingest

        ingest(args.video, args.scene, load_ingest_config(args.params))
        return 0
    if args.command == "validate":
        from glimpse.errors import SceneError
        from glimpse.scene import validate_scene

        if not args.scene.is_dir():
            raise GlimpseError(f"{args.scene}: no such scene folder")
        from glimpse.scene.runnable import check_runnable

        violations = validate_scene(args.scene)
        if violations:
            raise SceneError(str(args.scene), violations)
        check_runnable(args.scene)
        print(f"{args.scene}: valid glimpse-scene/1, and the pipeline can run it")
        return 0
    if args.command == "export":
        from glimpse.export.run import export_run
        from glimpse.replay.finished import default_frame, load_finished_run

        run = load_finished_run(args.run)
        frame = default_frame(run) if args.frame is None else args.frame
        out = export_run(run, frame, args.out or args.run / "export", args.sh_degree)
        print(f"exported frame {frame} of {args.run} to {out}/ (docs/exports.md says which viewers open what)")
        return 0
    if args.command == "render":
        from glimpse.replay.video import render_command

        out = render_command(args.run, args.camera, args.time, args.remove, not args.no_background, args.scene,
                             args.orbit_frames, args.fps, args.out or args.run / "renders" / "render.mp4",
                             args.motion, args.motion_seconds)
        print(f"rendered {out}")
        return 0
    if args.command == "run-dir":
        print(args.out / scene_name(args.scene))
        return 0
    if args.command == "params":
        from glimpse.pipeline.stages import stage_spec

        try:
            stage_spec(args.stage)
        except ValueError as exc:
            raise GlimpseError(str(exc)) from None
    run, _ = prepare_run(args.scene, args.out, args.params, getattr(args, "whole_pipeline", False))
    if args.command == "prepare":
        print(run.root)
    else:
        print(json.dumps(json.loads(run.params_file(args.stage).read_text())["params"], indent=2))
    return 0


if __name__ == "__main__":
    sys.exit(main())
