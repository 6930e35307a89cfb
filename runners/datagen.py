"""Make a labelled grasp dataset: ``python -m runners.datagen --objects-dir DIR --grasps-per-object N --out DATASET``.

Every object of the set (a folder of meshes or URDFs, a YCB-layout folder, or the embedded YCB set)
is captured on the table, planned once per capture, and N of its grasps, across the planner's
verdicts, are labelled by simulation (``--mode hand``: the Panda hand alone; ``arm``: the Panda
executing the planned motion), spread over ``--workers`` (one object's grasps over all of them).
``--engines pybullet,mujoco`` labels every hand-mode grasp in both engines: the label is held in both,
each engine's own is kept in the files and the report says how far they agree.
Each finished object is written at once; re-running the command resumes. ``--agreement N`` also simulates N grasps of each of the first five objects in both modes
and reports how often the modes agree.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sagp_batched.config import ConfigError
from sagp_batched.config.run import LABEL_PROTOCOLS
from sagp_batched.config.world import GRIPPERS
from sagp_batched.preflight import PreflightError, preflight
from sagp_batched.runtime import configure_torch
from sagp_batched.world.objects import ObjectLoadError, ObjectSetError, UnknownObjectError, load_object_set

from .cli import config_or_report, workers_line

# Flag -> (argparse dest, config section, config key).
SETTING_FLAGS = {
    "--objects": ("objects", "run", "objects"),
    "--objects-dir": ("objects_dir", "run", "objects_dir"),
    "--out": ("out", "run", "out"),
    "--workers": ("workers", "run", "workers"),
    "--backend": ("backend", "run", "backend"),
    "--address": ("ray_address", "run", "ray_address"),
    "--rater": ("rater", "rating", "backend"),
    "--model": ("model", "rating", "model"),
    "--endpoint": ("endpoint", "rating", "endpoint"),
    "--pairs": ("n_pairs", "planner", "n_pairs"),
    "--gripper": ("gripper", "planner", "gripper"),
    "--grasps-per-object": ("grasps_per_object", "dataset", "grasps_per_object"),
    "--mode": ("mode", "dataset", "mode"),
    "--protocol": ("protocol", "dataset", "protocol"),
    "--engines": ("engines", "dataset", "engines"),
    "--captures": ("captures_per_object", "dataset", "captures_per_object"),
    "--grasps-per-chunk": ("grasps_per_chunk", "dataset", "grasps_per_chunk"),
}
AGREEMENT_OBJECTS = 5


def _csv(text: str) -> list[str]:
    return [item.strip() for item in text.split(",") if item.strip()]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m runners.datagen", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--profile", default="dataset", help="profile name or a TOML path (default: dataset)")
    parser.add_argument("--objects-dir", help="a folder of meshes (OBJ/STL/PLY/GLB) or URDFs, a YCB-layout folder, or 'pybullet_data'")
    parser.add_argument("--objects", type=_csv, help="comma list of object ids, or 'all' (default)")
    parser.add_argument("--grasps-per-object", type=int, help="labelled grasps per object")
    parser.add_argument("--mode", choices=("hand", "arm"), help="hand: the gripper alone; arm: the Panda executes the planned motion")
    parser.add_argument("--gripper", choices=GRIPPERS, help="the gripper planned and simulated (default: the Panda's hand, franka_panda); "
                        "a gripper no arm carries labels in hand mode")
    parser.add_argument("--protocol", choices=LABEL_PROTOCOLS,
                        help="hand mode: tabletop (the object on the table, the hand approaching) or floating "
                             "(ACRONYM's: the object alone, grasps all around it)")
    parser.add_argument("--engines", type=_csv,
                        help="hand mode: comma list of engines every grasp is labelled in (pybullet, mujoco); with two, "
                             "a grasp is held where both held it and each engine's label is kept (default: pybullet)")
    parser.add_argument("--captures", type=int, dest="captures_per_object", help="captures (placements) per object")
    parser.add_argument("--grasps-per-chunk", type=int, help="hand mode: grasps a worker simulates as one piece of work (labels do not depend on it)")
    parser.add_argument("--out", help="dataset directory (re-running into it resumes)")
    parser.add_argument("--workers", type=int, help="worker processes, each with its own PyBullet client")
    parser.add_argument("--backend", choices=("local", "ray"), help="where objects are labelled")
    parser.add_argument("--address", dest="ray_address", help="Ray cluster address for --backend ray")
    parser.add_argument("--rater", choices=("prior", "transformers", "openai"), help="zone-rating backend for the semantics")
    parser.add_argument("--model", help="model id or local path (transformers) or served model name (openai)")
    parser.add_argument("--endpoint", help="OpenAI-compatible base URL")
    parser.add_argument("--pairs", type=int, dest="n_pairs", help="sampled point pairs per capture")
    parser.add_argument("--agreement", type=int, default=0, metavar="N",
                        help=f"also simulate N grasps of each of the first {AGREEMENT_OBJECTS} objects in both modes")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def main(argv: list[str] | None = None) -> int:
    from sagp_batched.datasets.cross_engine import diverged_text
    from sagp_batched.datasets.dataset_run import dataset_object_ids, generate_dataset

    args = build_parser().parse_args(argv)
    config = config_or_report(args, SETTING_FLAGS)
    if config is None:
        return 2
    if args.agreement < 0:
        print(f"error: --agreement must be at least 0, got {args.agreement}", file=sys.stderr)
        return 2
    try:
        objects = load_object_set(config.run.objects_dir)
        object_ids = dataset_object_ids(config, objects)
        preflight(config, with_arm=config.dataset.mode == "arm")
    except (ConfigError, ObjectSetError, ObjectLoadError, UnknownObjectError, PreflightError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for path, reason in getattr(objects, "skipped", []):
        print(f"note: skipped {path}: {reason}", file=sys.stderr)
    print(f"objects: {objects.source} ({len(object_ids)} to label)", file=sys.stderr)
    print(workers_line(args, config), file=sys.stderr)
    if config.dataset.mode == "hand":
        engines = config.dataset.engines
        print(f"labels: {config.dataset.protocol} protocol in {', '.join(engines)}"
              + (" (held where every engine held; each engine's label kept)" if len(engines) > 1 else ""), file=sys.stderr)
    configure_torch()
    out_dir = Path(config.run.out).expanduser()
    try:
        result = generate_dataset(config, objects, out_dir, progress=not args.no_progress,
                                  on_note=lambda note: print(f"note: {note}", file=sys.stderr),
                                  agreement_objects=object_ids[:AGREEMENT_OBJECTS], agreement_grasps=args.agreement)
    except (ConfigError, ObjectSetError, ObjectLoadError, UnknownObjectError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"\ninterrupted: finished objects are in {out_dir}; run the same command again to resume", file=sys.stderr)
        return 130
    summary = result.manifest["summary"]
    print(f"{len(result.new_objects)} new objects; {summary['labelled']} labelled grasps, {summary['held']} held; "
          f"report: {out_dir / 'report.md'}", file=sys.stderr)
    print(f"{summary['untested']} untested grasps; {diverged_text(summary['diverged'], config.dataset.engines)}", file=sys.stderr)
    for line in summary["short"].values():
        print(f"short: {line}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
