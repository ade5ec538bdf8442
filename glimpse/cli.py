"""``python -m glimpse`` / ``glimpse``: the commands the Makefile and users call.

  glimpse ingest VIDEO [SCENE_DIR]       a video -> a scene: frames, every person found and tracked (keypoints,
                                         masks), a preview video and a tracks report (docs/ingest.md); SCENE_DIR
                                         defaults to OUT/scenes/<video name>
  glimpse import DATASET SOURCE SCENE_DIR [--sequence S] [--cameras IN,HELD,...] [--frames A:B[:STEP]]
                                         a dataset's sequence -> a scene: zju-mocap, panoptic, emdb, hi4d, neuman
                                         (docs/datasets.md)
  glimpse validate SCENE                 check a scene against glimpse-scene/1
  glimpse tracks SCENE [--merge INTO=FROM | --swap A,B | --drop P | --rename OLD=NEW] [--frames A:B]
                                         list a scene's people, or correct them after looking at the ingest's
                                         preview (merge two ids, undo an identity switch, drop a false find);
                                         the preview is drawn again (docs/ingest.md)
  glimpse run --scene S|--video V --out O [--stage X] [--wait SECONDS]
                                         lock the run folder and run the stages that are out of date (make all),
                                         or rerun stage X (make X); a video is ingested first when it is newer
                                         than its scene or the ingest parameters changed
  glimpse batch SCENE_OR_VIDEO... --executor local|ray|slurm [--out O] [--jobs N] [--retries R]
                                         many scenes through every stage, here, on Ray or on Slurm; failed ones
                                         retried and resumed; OUT/batch.md and batch.json (docs/batch.md)
  glimpse clean-stage --scene S --out O STAGE
                                         remove one stage's output and work folder (under the run's lock)
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
  glimpse report RUN                     write RUN/report.html again from whatever stages have finished
                                         (stage 07 writes it; docs/report.md)
  glimpse view RUN [--host H] [--port P] serve a finished run in the browser: orbit, scrub time, show or hide
                                         people, play a new motion, save screenshots (docs/viewer.md)
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
from pathlib import Path

from glimpse.errors import EXIT_BAD_INPUT, EXIT_INTERRUPTED, EXIT_STAGE_FAILED, GlimpseError

EXIT_STATUSES = f"""exit statuses: 0 done; {EXIT_STAGE_FAILED} a stage failed (glimpse run); 2 the command line is wrong;
  {EXIT_BAD_INPUT} bad input (a scene, parameter, file or run folder: the message names it); {EXIT_INTERRUPTED} interrupted
  (rerun the same command: finished stages and checkpoints are kept)"""

# One example per command, shown by `glimpse COMMAND --help`.
EXAMPLES = {
    "ingest": "glimpse ingest clip.mp4 runs/scenes/clip   # then: glimpse run --scene runs/scenes/clip\n"
              '  glimpse ingest clip.mp4 runs/scenes/clip --params "ingest.start_s=62 ingest.end_s=75"   # a part',
    "import": "glimpse import zju-mocap /data/zju_mocap runs/scenes/zju_377 --sequence 377 "
              "--body-model ~/smpl/SMPL_NEUTRAL.pkl --frames 0:570",
    "validate": "glimpse validate runs/scenes/demo_small",
    "tracks": "glimpse tracks runs/scenes/clip --swap p0,p1 --frames 35:   # the ids switched at frame 35\n"
              "  glimpse tracks runs/scenes/clip --merge p0=p2                # p2 is p0, back after a long absence",
    "run": 'glimpse run --scene runs/scenes/demo_small --params "06_joint_opt.schedule_scale=0.05"\n'
           "  glimpse run --video clip.mp4                 # ingest (unless up to date), then every stage\n"
           "  glimpse run --scene S --stage 06_joint_opt   # rerun one stage (and what it needs)",
    "batch": "glimpse batch runs/scenes/* --executor local --out runs\n"
             "  glimpse batch takes/*.mp4 --executor slurm --slurm-profile cluster.yaml --out /shared/runs\n"
             "  glimpse batch /data/scenes/* --executor ray --ray-address auto --gpus-per-job 1 --out /shared/runs",
    "clean-stage": "glimpse clean-stage --scene runs/scenes/demo_small 06_joint_opt",
    "prepare": "glimpse prepare --scene runs/scenes/demo_small --whole-pipeline",
    "params": "glimpse params --scene runs/scenes/demo_small --stage 04_bg_pretrain",
    "run-dir": "glimpse run-dir --scene runs/scenes/demo_small   # -> runs/demo_small",
    "export": "glimpse export runs/demo_small --frames 12 --sh-degree 3\n"
              "  glimpse export runs/demo_small --frames 0:23 --up z --out walk_sequence   # a PLY per frame, z up",
    "render": "glimpse render runs/demo_small --camera orbit:30 --time 12 --remove p1 --out orbit.mp4\n"
              "  glimpse render runs/demo_small --motion p0=builtin:walk --out walk.mp4\n"
              "  glimpse render runs/demo_small --time 0:23 --passes rgb,alpha,depth,mask --out frames  # + frames_exr/",
    "report": "glimpse report runs/demo_small   # then open runs/demo_small/report.html in a browser",
    "view": "glimpse view runs/demo_small        # then open http://127.0.0.1:8080 ; Ctrl-C stops it\n"
            "  glimpse view runs/demo_small --host 0.0.0.0 --port 9000 --motion dance.npz",
}


def _version() -> str:
    from glimpse.pipeline.runner import code_version

    return f"glimpse {code_version()}"


class _VersionAction(argparse.Action):
    """--version, computed only when asked (it runs git)."""

    def __init__(self, option_strings, dest, **kwargs):
        super().__init__(option_strings, dest, nargs=0, help="print the version (and git commit) and exit")

    def __call__(self, parser, namespace, values, option_string=None):
        print(_version())
        parser.exit()


def _params_default() -> str:
    return os.environ.get("GLIMPSE_PARAMS", "")


def main(argv: list[str] | None = None) -> int:
    raw = argparse.RawDescriptionHelpFormatter
    parser = argparse.ArgumentParser(prog="glimpse", description=__doc__, formatter_class=raw, epilog=EXIT_STATUSES)
    parser.add_argument("--version", action=_VersionAction)
    commands = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    def command(name: str, help: str) -> argparse.ArgumentParser:
        """A command's parser: its help, then its example and the exit statuses."""
        return commands.add_parser(name, help=help, description=help, formatter_class=raw,
                                   epilog=f"example:\n  {EXAMPLES[name]}\n\n{EXIT_STATUSES}")

    p_ingest = command("ingest", "a video -> a glimpse-scene/1 folder (docs/ingest.md)")
    p_ingest.add_argument("video", type=Path)
    p_ingest.add_argument("scene", nargs="?", default="", help="the scene folder to write (replaced when the ingest "
                                                               "succeeds; default OUT/scenes/<video name>)")
    p_ingest.add_argument("--out", type=Path, default=Path("runs"), help="output root, for the default scene folder")
    p_ingest.add_argument("--params", default=_params_default(), help='overrides "ingest.key=value ..." (env GLIMPSE_PARAMS)')
    p_import = command("import", "a dataset's sequence -> a glimpse-scene/1 folder (docs/datasets.md)")
    p_import.add_argument("dataset", help="zju-mocap | panoptic | emdb | hi4d | neuman")
    p_import.add_argument("source", type=Path, help="the dataset's folder (with --sequence) or one sequence's")
    p_import.add_argument("scene", type=Path, help="the scene folder to write (replaced when the import succeeds)")
    p_import.add_argument("--sequence", default=None,
                          help="the sequence, e.g. 377 (ZJU-MoCap), 160422_ultimatum1 (Panoptic), P0/09_outdoor_walk "
                               "(EMDB), pair00/dance00 (Hi4D)")
    p_import.add_argument("--cameras", default=None, help="the input camera, then held-out ones, comma-separated "
                                                          "(indices from 0, or the dataset's names; default: the "
                                                          "protocol docs/datasets.md gives)")
    p_import.add_argument("--frames", default=None, help="A:B[:STEP] of the sequence's frames (B excluded; "
                                                         "Panoptic, Hi4D: their frame numbers; default: all)")
    p_import.add_argument("--eval-every", type=int, default=None, help="held-out images every this many imported "
                                                                       "frames (default: pipeline.yaml import.eval_every, "
                                                                       "30: HumanNeRF's protocol)")
    p_import.add_argument("--body-model", action="append", default=[], metavar="[GENDER=]PATH",
                          help="an SMPL model file the dataset's bodies belong to: PATH (neutral) or male=PATH, "
                               "female=PATH; repeatable")
    p_import.add_argument("--fps", type=float, default=None, help="frames per second, where the dataset's files "
                                                                  "do not say")
    p_val = command("validate", "check a scene folder against glimpse-scene/1")
    p_val.add_argument("scene", type=Path)
    p_tracks = command("tracks", "list a scene's people, or correct who is who (docs/ingest.md, \"Correcting the "
                                 "tracks\")")
    p_tracks.add_argument("scene", type=Path)
    edits = p_tracks.add_mutually_exclusive_group()
    edits.add_argument("--merge", metavar="INTO=FROM", help="FROM's frames become INTO's; FROM is removed")
    edits.add_argument("--swap", metavar="A,B", help="exchange A's and B's data (in --frames)")
    edits.add_argument("--drop", metavar="P", help="remove person P (or only their --frames)")
    edits.add_argument("--rename", metavar="OLD=NEW", help="give person OLD the id NEW")
    p_tracks.add_argument("--frames", default=None, metavar="A:B",
                          help="frame ids A to B, B excluded (A: to the end), for --swap and --drop")
    p_run = command("run", "run the stages that are out of date (what make all and make <stage> call)")
    p_run.add_argument("--scene", default="", help="scene folder (glimpse-scene/1); with --video, where it goes")
    p_run.add_argument("--video", default="", help="a video, ingested into the scene first when newer than it or "
                                                   "when the ingest parameters changed")
    p_run.add_argument("--out", type=Path, default=Path("runs"))
    p_run.add_argument("--stage", default=None, help="rerun this stage (and what it needs), not the whole pipeline")
    p_run.add_argument("--params", default=_params_default(), help='overrides "section.key=value ..." (env GLIMPSE_PARAMS)')
    p_run.add_argument("--wait", type=float, default=None, help="seconds to wait when another run holds the run "
                                                                "folder (default $GLIMPSE_LOCK_WAIT, else 0)")
    p_batch = command("batch", "many scenes or videos through every stage: here, on Ray or on Slurm (docs/batch.md)")
    p_batch.add_argument("sources", nargs="+", type=Path, help="scene folders and/or videos (videos are ingested)")
    p_batch.add_argument("--executor", choices=("local", "ray", "slurm"), default="local")
    p_batch.add_argument("--out", type=Path, default=Path("runs"), help="output root, on storage every worker sees")
    p_batch.add_argument("--jobs", type=int, default=None, help="local: scenes at once (default batch.jobs)")
    p_batch.add_argument("--retries", type=int, default=None, help="attempts after the first (default batch.retries)")
    p_batch.add_argument("--cpus-per-job", type=int, default=None, help="ray / slurm: CPUs per scene")
    p_batch.add_argument("--gpus-per-job", type=float, default=None, help="ray / slurm: GPUs per scene")
    p_batch.add_argument("--ray-address", default=None, help="ray: the cluster (default batch.ray.address: auto)")
    p_batch.add_argument("--slurm-profile", type=Path, default=None,
                         help="slurm: a YAML file of batch.slurm settings (partition, time_min, account, setup, ...)")
    p_batch.add_argument("--partition", default=None, help="slurm: the partition")
    p_batch.add_argument("--time-min", type=int, default=None, help="slurm: minutes per job")
    p_batch.add_argument("--params", default=_params_default(), help='overrides for every stage (and batch.*), '
                                                                     '"section.key=value ..."')
    p_clean = command("clean-stage", "remove one stage's output (make clean-stage)")
    p_clean.add_argument("--scene", required=True, type=Path)
    p_clean.add_argument("--out", type=Path, default=Path("runs"))
    p_clean.add_argument("stage")
    helps = {"prepare": "validate, resolve the parameters and write the run folder's records; print its path",
             "params": "print the resolved parameters one stage reads", "run-dir": "print the run folder's path"}
    for name in ("prepare", "params", "run-dir"):
        p = command(name, helps[name])
        p.add_argument("--scene", required=True, type=Path)
        p.add_argument("--out", type=Path, default=Path("runs"))
        p.add_argument("--params", default=_params_default(), help='overrides "section.key=value ..." (env GLIMPSE_PARAMS)')
        if name == "params":
            p.add_argument("--stage", required=True)
        if name == "prepare":
            p.add_argument("--whole-pipeline", action="store_true",
                           help="also refuse a scene the pipeline cannot run to the end (make all)")
    p_export = command("export", "a finished run's Gaussians and cameras for other tools")
    p_export.add_argument("run", type=Path, help="the run folder, OUT/<scene>")
    p_export.add_argument("--frames", "--frame", default=None, help="T | A:B | all: input frame ids, one scene PLY "
                                                                    "each (default: the middle input frame)")
    p_export.add_argument("--up", choices=("y", "z", "keep"), default="y",
                          help="turn the world so the input cameras' mean up is +y (default; splat viewers, "
                               "glTF) or +z (Blender, z-up tools), or keep the run's frame")
    p_export.add_argument("--out", type=Path, default=None, help="default: RUN/export")
    p_export.add_argument("--sh-degree", type=int, choices=(0, 1, 2, 3), default=None,
                          help="SH degree of the posed PLYs (default: as trained; 3 for INRIA's SIBR viewer)")
    p_render = command("render", "render a finished run along a camera path (docs/renders.md)")
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
    p_render.add_argument("--passes", default="rgb", help="rgb,alpha,depth,mask: beyond rgb, one OpenEXR file per "
                                                          "frame of them all (linear colour, alpha, depth in the "
                                                          "world's units, each person's visible mask) in "
                                                          "<out name>_exr/ beside the video or PNGs")
    p_report = command("report", "write a run's report.html (what stage 07 writes) from its finished stages")
    p_report.add_argument("run", type=Path, help="the run folder, OUT/<scene>")
    p_report.add_argument("--wait", type=float, default=None, help="seconds to wait when a stage holds the run "
                                                                   "folder (default $GLIMPSE_LOCK_WAIT, else 0)")
    p_view = command("view", "serve a finished run in the browser (viser; docs/viewer.md)")
    p_view.add_argument("run", type=Path, help="the run folder, OUT/<scene>")
    p_view.add_argument("--host", default=None, help="address to listen on (default: view.host, 127.0.0.1)")
    p_view.add_argument("--port", type=int, default=None, help="TCP port (default: view.port, 8080)")
    p_view.add_argument("--out", type=Path, default=None, help="where screenshots go (default: RUN/view)")
    p_view.add_argument("--motion", action="append", default=[], metavar="FILE.npz",
                        help="a motion (.npz, AMASS-style or smplx-style) offered beside the built-in ones; "
                             "repeatable")
    p_view.add_argument("--params", default=_params_default(), help='overrides "view.key=value ..." (env '
                                                                    'GLIMPSE_PARAMS)')
    args = parser.parse_args(argv)
    try:
        return _dispatch(args)
    except GlimpseError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("interrupted: rerun the same command to go on (finished stages and checkpoints are kept)",
              file=sys.stderr)
        return EXIT_INTERRUPTED


def _dispatch(args: argparse.Namespace) -> int:
    from glimpse.pipeline.prepare import locate_run, prepare_run, run_lock

    if args.command == "ingest":
        from glimpse.ingest.config import load_ingest_config
        from glimpse.ingest.stage import default_scene_dir, ingest

        ingest(args.video, Path(args.scene) if args.scene else default_scene_dir(args.video, args.out),
               load_ingest_config(args.params))
        return 0
    if args.command == "import":
        from glimpse.config import command_params, config_from_mapping
        from glimpse.importers import import_dataset
        from glimpse.importers.common import ImportOptions, parse_body_models, parse_span
        from glimpse.importers.config import ImportConfig

        eval_every = config_from_mapping(ImportConfig, command_params("")["import"], "import").eval_every
        if args.eval_every is not None:
            if args.eval_every < 1:
                raise GlimpseError(f"--eval-every {args.eval_every}: must be at least 1")
            eval_every = args.eval_every
        options = ImportOptions(args.sequence, tuple(args.cameras.split(",")) if args.cameras else None,
                                parse_span(args.frames) if args.frames else None, eval_every,
                                parse_body_models(args.body_model), args.fps)
        scene = import_dataset(args.dataset, args.source, args.scene, options)
        print(f"imported {args.dataset} into {scene} (check it: glimpse validate {scene}; run it: "
              f"glimpse run --scene {scene})")
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
    if args.command == "tracks":
        return _tracks(args)
    if args.command == "run":
        return _run(args)
    if args.command == "batch":
        from glimpse.batch.command import batch_command

        return batch_command(args)
    if args.command == "clean-stage":
        from glimpse.pipeline.stages import named_stage

        named_stage(args.stage)
        run = locate_run(args.scene, args.out)
        with run_lock(run, f"clean-stage {args.stage}"):
            for folder in (run.stage_dir(args.stage), run.work_dir(args.stage)):
                shutil.rmtree(folder, ignore_errors=True)
        print(f"removed {run.stage_dir(args.stage)}")
        return 0
    if args.command == "export":
        from glimpse.export.run import export_run
        from glimpse.replay.finished import default_frame, load_finished_run
        from glimpse.replay.request import parse_times

        run = load_finished_run(args.run)
        frames = [default_frame(run)] if args.frames is None else parse_times(args.frames, run, "--frames")
        out = export_run(run, frames, args.out or args.run / "export", args.sh_degree, args.up)
        print(f"exported {len(frames)} frame(s) ({frames[0]}..{frames[-1]}) of {args.run} to {out}/, up {args.up} "
              f"(docs/exports.md says which viewers open what)")
        return 0
    if args.command == "render":
        from glimpse.replay.video import render_command

        out = render_command(args.run, args.camera, args.time, args.remove, not args.no_background, args.scene,
                             args.orbit_frames, args.fps, args.out or args.run / "renders" / "render.mp4",
                             args.motion, args.motion_seconds, args.passes)
        print(f"rendered {out}")
        return 0
    if args.command == "report":
        return _report(args)
    if args.command == "view":
        return _view(args)
    if args.command == "run-dir":
        print(locate_run(args.scene, args.out).root)
        return 0
    if args.command == "params":
        from glimpse.pipeline.stages import named_stage

        named_stage(args.stage)
    whole = getattr(args, "whole_pipeline", False)
    with run_lock(locate_run(args.scene, args.out, whole, args.params), f"glimpse {args.command}"):
        run, _ = prepare_run(args.scene, args.out, args.params, whole)
    if args.command == "prepare":
        print(run.root)
    else:
        print(json.dumps(json.loads(run.params_file(args.stage).read_text())["params"], indent=2))
    return 0


def _tracks(args: argparse.Namespace) -> int:
    from glimpse.ingest.config import load_ingest_config
    from glimpse.ingest.corrections import correct, people_table, suspected_switches
    from glimpse.scene.people_edit import Edit, parse_frame_range

    if not args.scene.is_dir():
        raise GlimpseError(f"{args.scene}: no such scene folder")
    frames = parse_frame_range(args.frames) if args.frames else None
    forms = {"merge": ("=", "INTO=FROM"), "swap": (",", "A,B"), "drop": (None, "P"), "rename": ("=", "OLD=NEW")}
    given = [(kind, getattr(args, kind)) for kind in forms if getattr(args, kind)]
    if frames is not None and (not given or given[0][0] not in ("swap", "drop")):
        raise GlimpseError("--frames goes with --swap or --drop")
    if given:
        kind, text = given[0]
        separator, form = forms[kind]
        people = (text,) if separator is None else tuple(part.strip() for part in text.split(separator))
        if len(people) != (1 if separator is None else 2) or not all(people):
            raise GlimpseError(f"--{kind} {text!r}: give {form}")
        for line in correct(args.scene, Edit(kind, people, frames), load_ingest_config().keypoint_min_confidence):
            print(line)
    print(people_table(args.scene))
    for line in suspected_switches(args.scene):
        print(line)
    return 0


def _run(args: argparse.Namespace) -> int:
    """``glimpse run``: ingest the video when the scene is not up to date with it, then let make run the stages;
    make's status is returned."""
    from glimpse.pipeline.make import run_stages

    if not args.scene and not args.video:
        raise GlimpseError("glimpse run needs --scene SCENE_DIR or --video VIDEO")
    scene = Path(args.scene) if args.scene else None
    if args.video:
        from glimpse.ingest.config import load_ingest_config
        from glimpse.ingest.stage import default_scene_dir, ingest, why_ingest_again

        video = Path(args.video)
        if not video.is_file():
            raise GlimpseError(f"{video}: no such video file")
        scene = scene or default_scene_dir(video, args.out)
        config = load_ingest_config(args.params)
        reason = why_ingest_again(video, scene, config)
        if reason is not None:
            if (scene / "scene.yaml").is_file():
                print(f"{scene}: {reason}; ingesting {video} again (corrections made with glimpse tracks are not "
                      f"carried over; make all SCENE={scene} runs the scene as it is)")
            ingest(video, scene, config)
    stages_dir = os.environ.get("GLIMPSE_STAGES_DIR") or None
    status = run_stages(scene, args.out, args.params, args.stage, sys.executable,
                        Path(stages_dir) if stages_dir else None, args.wait)
    return EXIT_STAGE_FAILED if status else 0


def _report(args: argparse.Namespace) -> int:
    """``glimpse report``: the report section the run's stage 07 recorded (else pipeline.yaml's), under the
    run folder's lock."""
    from glimpse.config import config_from_mapping, load_pipeline_yaml
    from glimpse.pipeline.prepare import RunPaths, run_lock
    from glimpse.report.config import ReportConfig
    from glimpse.report.page import write_report
    from glimpse.report.run_record import read_run

    read_run(args.run)  # refuses a folder that is not a run before anything is written there
    defaults = load_pipeline_yaml(resolve_auto=False)
    manifest = args.run / "07_eval" / "manifest.json"
    recorded = json.loads(manifest.read_text()).get("params", {}) if manifest.is_file() else {}
    config = config_from_mapping(ReportConfig, recorded.get("report", defaults["report"]), "report")
    with run_lock(RunPaths(args.run), "glimpse report", args.wait):
        path = write_report(args.run, config, defaults)
    print(f"wrote {path}")
    return 0


def _view(args: argparse.Namespace) -> int:
    """``glimpse view``: serve until Ctrl-C (which ends it normally, status 0)."""
    import time

    import torch

    from glimpse.config import command_params, config_from_mapping
    from glimpse.replay.finished import load_finished_run
    from glimpse.view.config import ViewConfig
    from glimpse.view.server import ViewerServer
    from glimpse.view.session import ViewSession

    config = config_from_mapping(ViewConfig, command_params(args.params)["view"], "view")
    for path in args.motion:
        if not Path(path).is_file():
            raise GlimpseError(f"--motion {path}: no such file")
    session = ViewSession(load_finished_run(args.run), config, torch.device("cpu"))
    viewer = ViewerServer(session, args.out or args.run / "view", args.host or config.host,
                          config.port if args.port is None else args.port, tuple(args.motion))
    print(f"viewing {args.run} at http://{args.host or config.host}:{viewer.port} (Ctrl-C stops)", flush=True)
    try:
        while True:
            time.sleep(1.0)
    except KeyboardInterrupt:
        print("viewer stopped")
    finally:
        viewer.stop()
    return 0


if __name__ == "__main__":
    sys.exit(main())
