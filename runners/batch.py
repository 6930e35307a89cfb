"""Run the grasping study: ``python -m runners.batch --n-trials 20``.

Profile values (``--profile``, default ``paper``) are overridden by the flags given here; the
resolved config, provenance and every finished trial go to ``--out``.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

from sagp_batched.config import RATING_BACKENDS, RUN_BACKENDS, Config, ConfigError
from sagp_batched.preflight import PreflightError, preflight
from sagp_batched.runtime import configure_torch
from sagp_batched.study.methods import REGISTRY
from sagp_batched.study.study_run import plan_units, run_study
from sagp_batched.world.objects import ObjectLoadError, ObjectSetError, UnknownObjectError, load_object_set

from .cli import config_or_report, workers_line

MODEL_BACKENDS = ("transformers", "openai")
# The flags that set a config value: flag -> (argparse dest, section, field).
SETTING_FLAGS = {
    "--methods": ("methods", "run", "methods"),
    "--tasks": ("tasks", "run", "tasks"),
    "--objects": ("objects", "run", "objects"),
    "--n-trials": ("n_trials", "run", "n_trials"),
    "--objects-dir": ("objects_dir", "run", "objects_dir"),
    "--out": ("out", "run", "out"),
    "--workers": ("workers", "run", "workers"),
    "--backend": ("backend", "run", "backend"),
    "--address": ("ray_address", "run", "ray_address"),
    "--trial-timeout": ("trial_timeout_s", "run", "trial_timeout_s"),
    "--export-grasps": ("export_grasps", "run", "export_grasps"),
    "--save-frames": ("save_frames", "run", "save_frames"),
    "--gui": ("gui", "run", "gui"),
    "--keep-errors": ("keep_errors", "run", "keep_errors"),
    "--rater": ("rater", "rating", "backend"),
    "--model": ("model", "rating", "model"),
    "--endpoint": ("endpoint", "rating", "endpoint"),
    "--pairs": ("n_pairs", "planner", "n_pairs"),
}


def _csv(text: str) -> list[str]:
    return [item.strip() for item in text.split(",") if item.strip()]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m runners.batch", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--profile", default="paper", help="profile name in profiles/ or a TOML path (default: paper)")
    parser.add_argument("--methods", type=_csv, help="comma list of go,sagp,vd")
    parser.add_argument("--tasks", type=_csv, help="comma list of t1,t2,t3")
    parser.add_argument("--objects", type=_csv, help="comma list of object ids, or 'all'")
    parser.add_argument("--n-trials", type=int, help="trials per (object, task)")
    parser.add_argument("--objects-dir", help="YCB directory (objects.json + URDFs), or 'pybullet_data' for the built-in set; default $SAGP_YCB_DIR, else the embedded compact YCB set")
    parser.add_argument("--out", help="run directory (re-running into it resumes)")
    parser.add_argument("--resume", action="store_true", help="finish the run in --out, failing if there is none (a plain re-run into a run directory resumes too)")
    parser.add_argument("--workers", type=int, help="trial processes, each with its own PyBullet client")
    parser.add_argument("--backend", choices=RUN_BACKENDS, help="where trials run")
    parser.add_argument("--address", dest="ray_address", help="Ray cluster address for --backend ray")
    parser.add_argument("--rater", choices=RATING_BACKENDS,
                        help="zone-rating backend (oracle: rates zones from annotated regions with the true pose, an upper bound)")
    parser.add_argument("--model", help="model id or local path (transformers) or served model name (openai)")
    parser.add_argument("--endpoint", help="OpenAI-compatible base URL, e.g. http://127.0.0.1:8000/v1")
    parser.add_argument("--pairs", type=int, dest="n_pairs", help="sampled point pairs per trial")
    parser.add_argument("--trial-timeout", type=float, dest="trial_timeout_s", help="seconds before a trial is recorded as timed out")
    parser.add_argument("--export-grasps", action="store_true", default=None, help="write every scored candidate to grasps/")
    parser.add_argument("--save-frames", action="store_true", default=None, help="save images at contact and after the lift")
    parser.add_argument("--gui", action="store_true", default=None, help="PyBullet GUI instead of DIRECT")
    parser.add_argument("--keep-errors", action="store_true", default=None,
                        help="on resume, keep trials recorded with an error instead of running them again")
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def _methods_to_run(args: argparse.Namespace, config: Config) -> tuple[list[str], dict[str, str]] | None:
    """(the methods to run, method -> why it is not run) of ``run.methods`` with this rater: a
    profile's method that needs a model the rater lacks is dropped with its reason, one asked for
    by --methods is refused. None once the refusal has been printed as an ``error:`` line."""
    methods = list(config.run.methods)
    not_run: dict[str, str] = {}
    model_less = config.rating.backend not in MODEL_BACKENDS
    needing_a_model = [m for m in methods if model_less and m in REGISTRY and REGISTRY[m].needs_model]
    if needing_a_model == methods and args.methods is None:
        print(f"error: run.methods {methods}: every method needs a model backend ({', '.join(MODEL_BACKENDS)}) and the rater "
              f"is '{config.rating.backend}': choose --rater transformers|openai or other --methods", file=sys.stderr)
        return None
    for name in needing_a_model:
        label = REGISTRY[name].label
        reason = f"needs a model backend ({', '.join(MODEL_BACKENDS)}); the rater is '{config.rating.backend}'"
        if args.methods is not None:
            print(f"error: {label} {reason}: choose --rater transformers|openai or drop {name} from --methods", file=sys.stderr)
            return None
        methods.remove(name)
        not_run[name] = reason + " (not run)"
    return methods, not_run


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    config = config_or_report(args, SETTING_FLAGS)
    if config is None:
        return 2
    try:
        objects = load_object_set(config.run.objects_dir)
        # Planned here as well as in the study so that unknown ids fail before preflight's checks take their time.
        units = plan_units(config, objects, config.run.methods)
    except (ConfigError, ObjectSetError, ObjectLoadError, UnknownObjectError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if not units:
        print(f"error: run.objects {list(config.run.objects)}: the object set {objects.source} holds only distractors", file=sys.stderr)
        return 2

    if args.resume and not (Path(config.run.out).expanduser() / "config.json").exists():
        print(f"error: --resume: {config.run.out} holds no run to resume", file=sys.stderr)
        return 2

    chosen = _methods_to_run(args, config)
    if chosen is None:
        return 2
    methods, not_run = chosen

    try:
        preflight(config)
    except PreflightError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2

    for name, reason in not_run.items():
        print(f"note: {REGISTRY[name].label} {reason}", file=sys.stderr)

    print(f"objects: {objects.source}", file=sys.stderr)
    labels = {"prior": " (an offline prior table, not a VLM)", "oracle": " (UPPER BOUND: annotated regions and the true object pose, not a model)"}
    print(f"rater: {config.rating.backend}" + labels.get(config.rating.backend, f" ({config.rating.model})"), file=sys.stderr)
    print(workers_line(args, config), file=sys.stderr)
    configure_torch()
    try:
        result = run_study(config, objects, methods, objects_dir=config.run.objects_dir,
                           progress=not args.no_progress, not_run=not_run,
                           on_note=lambda note: print(f"note: {note}", file=sys.stderr))
    except (ConfigError, ObjectSetError, ObjectLoadError, UnknownObjectError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"\ninterrupted: finished trials are in {config.run.out}; run the same command again to resume", file=sys.stderr)
        return 130
    print((result.out_dir / "summary.md").read_text())
    print(f"{result.new_records} new trial records; run directory: {result.out_dir}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
