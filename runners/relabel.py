"""Relabel another simulator's grasps with ours: ``python -m runners.relabel FILE.h5|FILE.json --mesh-root DIR --protocol floating|tabletop --out DIR``.

FILE is an ACRONYM HDF5 or an ACRONYM / GraspGen JSON grasp file (``sagp_batched.formats.grasp_file.read_grasp_file``); its mesh
(``object/file``, relative to --mesh-root) is imported as our object at the file's scale, mass and friction, its
grasps moved into that object's link frame and labelled by our simulation in ``--protocol`` (the Panda hand
floating with the object, or reaching it on the table). Written to --out: ``relabel.h5`` (the grasps as the file
gives them, its label and ours, the share of our simulations that held, our failure reasons and phases),
``agreement.json`` and ``report.md`` (confusion matrix, Cohen's kappa, disagreements by our failure phase and by
region), ``provenance.json``. Grasps are labelled in chunks of ``--grasps-per-chunk``, each kept as it finishes:
re-running the command resumes.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sagp_batched.config import ConfigError
from sagp_batched.formats.grasp_file import GraspFileError
from sagp_batched.config.run import LABEL_PROTOCOLS
from sagp_batched.datasets.relabelling import CHUNKS_DIR, ENGINES, REPORT_FILE, InputError, check_inputs, relabel
from sagp_batched.world.objects import ObjectLoadError, ObjectSetError, UnknownObjectError

from .cli import config_or_report

# Flag -> (argparse dest, config section, config key).
SETTING_FLAGS = {
    "--out": ("out", "run", "out"),
    "--workers": ("workers", "run", "workers"),
    "--grasps-per-chunk": ("grasps_per_chunk", "dataset", "grasps_per_chunk"),
    "--protocol": ("protocol", "dataset", "protocol"),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m runners.relabel", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("grasp_file", metavar="FILE", help="an ACRONYM .h5 or an ACRONYM / GraspGen .json grasp file")
    parser.add_argument("--mesh-root", required=True, help="the folder the file's object/file is relative to")
    parser.add_argument("--protocol", required=True, choices=LABEL_PROTOCOLS, help="floating: the hand and the object alone; tabletop: the object on the table")
    parser.add_argument("--out", required=True, help="output directory (re-running into it resumes)")
    parser.add_argument("--engine", default="pybullet",
                        help=f"the simulator that labels ({', '.join(ENGINES)}; default pybullet), or a comma list of them: "
                             "every grasp labelled in each, held where all held, each one's label and agreement kept")
    parser.add_argument("--max-grasps", type=int, help="relabel this many of the file's grasps, drawn with dataset.seed (default: all)")
    parser.add_argument("--workers", type=int, help="worker processes, each with its own simulator")
    parser.add_argument("--grasps-per-chunk", type=int, help="grasps labelled and kept as one piece (labels do not depend on it)")
    parser.add_argument("--profile", default="dataset", help="profile name or a TOML path (default: dataset)")
    return parser


def say(line: str) -> None:
    print(line, file=sys.stderr)


def main(argv: list[str] | None = None) -> int:
    from sagp_batched.run_directory import RunDirectoryError
    from sagp_batched.runtime import configure_torch

    args = build_parser().parse_args(argv)
    config = config_or_report(args, SETTING_FLAGS)
    if config is None:
        return 2
    try:
        inputs = check_inputs(args.grasp_file, args.mesh_root, config, args.engine, args.max_grasps)
    except (InputError, GraspFileError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    configure_torch()
    out_dir = Path(config.run.out).expanduser()
    try:
        result = relabel(inputs, config, out_dir, say)
    except (InputError, ConfigError, ObjectSetError, ObjectLoadError, UnknownObjectError, RunDirectoryError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        say(f"\ninterrupted: finished chunks are in {out_dir / CHUNKS_DIR}; run the same command again to resume")
        return 130
    kappa = "undefined" if result["kappa"] is None else f"{result['kappa']:.3f}"
    say(f"{result['n']} grasps: agreement {100 * result['agreement']:.1f} %, kappa {kappa}; report: {out_dir / REPORT_FILE}")
    say("untested (a simulation diverged, so not compared): " + ", ".join(f"{engine} {count}" for engine, count in result["untested"].items()))
    for engine, part in result.get("by_engine", {}).items():
        say(f"  {engine} alone: agreement {100 * part['agreement']:.1f} %, kappa " + ("undefined" if part["kappa"] is None else f"{part['kappa']:.3f}"))
    return 0


if __name__ == "__main__":
    sys.exit(main())
