"""Benchmark dataset generation: labelled grasps per second per core, by mode and worker count, with the stage breakdown.

    python -m runners.bench_dataset --json OUT.json [--objects-dir DIR] [--object 025_mug[,...]]
        [--hand-grasps 400] [--label-engines pybullet,mujoco] [--protocols tabletop,floating] [--arm-grasps 60]
        [--workers 1,2] [--repeats 3] [--pairs N] [--shared-world-pairs 1,4,16] [--gripper NAME]

Every case is the real dataset run of the objects into a fresh directory (one plan per capture, the
grasps spread over the workers): hand mode in each engine and protocol, arm mode in PyBullet; medians
over ``--repeats``, the cases interleaved within each repeat. The per-core rate is labelled grasps /
(wall time x workers); the busy rate is labelled grasps / the workers' summed stage seconds. The
projection to ``--project-objects`` x ``--project-grasps`` uses each hand-mode case's busy rate at the
most workers measured: a long run keeps every core busy.

    python -m runners.bench_dataset --fidelity --out DIR [--objects-dir DIR] [--objects a,b] [--grasps 60]
        [--perturbed-simulations K]

measures instead how far the labels can be trusted (``benchmarks.label_fidelity``): hull fidelity, label
stability across resting poses and re-simulation, floating against tabletop, designed grasps on a box and
labels/s per core, written to ``label_fidelity.json``, ``label_fidelity.md`` and ``provenance.json`` in --out.
Objects: --objects, else a few of the embedded YCB set, else (with --objects-dir) every target object there.

    python -m runners.bench_dataset --analytic --out DIR [--gripper NAME] [--label-engines pybullet,mujoco]
        [--protocols tabletop,floating]

labels grasps whose outcome is known on paper instead (``benchmarks.analytic_grasps``): a box, a bar and a
cylinder either side of the thresholds the contact model gives, in each engine and protocol, written to
``analytic_grasps.json``, ``analytic_grasps.md`` and ``provenance.json`` in --out (``--json FILE``: the JSON there too).
    python -m runners.bench_dataset --fixed-set SET.npz --out DIR [--objects a,b] [--grasps 63] [--label-engines pybullet,mujoco]
        [--fixed-protocol floating] [--labelling-overrides '{"early_stop_distance_m": 0}'] [--reference DIR]

labels a fixed grasp set instead (``benchmarks.fixed_labels``), planned on --objects (default: eight YCB
objects) and saved to SET.npz the first time, in each engine with [labelling] overridden, into
``fixed_labels.json`` in --out; with --reference (an earlier run's --out) it counts the labels that changed.

    python -m runners.bench_dataset --engines --out DIR [--objects-dir DIR] [--objects a,b] [--grasps 60]
        [--perturbed-simulations K] [--mujoco-variants '[{}, {"substeps": 2}]']

compares the engines instead (``benchmarks.engine_agreement``): the same planned grasps labelled by PyBullet and by
MuJoCo under each variant of ``[labelling.mujoco]`` (a JSON list of override tables; default: the profile's),
their agreement and kappa, the designed grasps in both and sims/s and labels/s per core of each, written to
``engine_agreement.json``, ``engine_agreement.md`` and ``provenance.json`` in --out.
"""
from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path

from sagp_batched.benchmarks import engine_agreement as engines
from sagp_batched.benchmarks.analytic_grasps import analytic_config, analytic_grasps, analytic_markdown
from sagp_batched.benchmarks import fixed_labels
from sagp_batched.benchmarks.dataset_speed import STAGES, DatasetCase, benchmark_dataset, projected_hours, shared_world_step_cost
from sagp_batched.benchmarks.gripper_agreement import gripper_agreement, gripper_agreement_markdown
from sagp_batched.benchmarks.label_fidelity import DEFAULT_OBJECTS, fidelity_markdown, label_fidelity
from sagp_batched.config import Config, ConfigError, load_config
from sagp_batched.config.run import LABEL_PROTOCOLS
from sagp_batched.config.world import GRIPPERS
from sagp_batched.datasets.engines import ENGINES
from sagp_batched.datasets.protocols import label_protocol
from sagp_batched.provenance import collect
from sagp_batched.robot.description import robot_of
from sagp_batched.runtime import configure_torch
from sagp_batched.world.mesh_settings import MeshImportSettings
from sagp_batched.world.objects import ObjectLoadError, ObjectSetError, UnknownObjectError, load_object_set

from .cli import names_and_unknown

PROJECTION_CORES = (2, 64)
FIDELITY_JSON = "label_fidelity.json"
FIDELITY_MARKDOWN = "label_fidelity.md"
ENGINES_JSON = "engine_agreement.json"
ENGINES_MARKDOWN = "engine_agreement.md"
ANALYTIC_JSON = "analytic_grasps.json"
ANALYTIC_MARKDOWN = "analytic_grasps.md"
GRIPPERS_JSON = "gripper_agreement.json"
FIXED_JSON = "fixed_labels.json"
FIXED_MARKDOWN = "fixed_labels.md"
GRIPPERS_MARKDOWN = "gripper_agreement.md"


def _counts(parser: argparse.ArgumentParser, flag: str, text: str, minimum: int) -> list[int]:
    try:
        counts = [int(part) for part in text.split(",") if part.strip()]
    except ValueError:
        counts = []
    if not counts or min(counts) < minimum:
        parser.error(f"{flag} takes whole numbers >= {minimum} separated by commas, got {text!r}")
    return counts


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--json", type=Path, help="where to write the results (required but with --fidelity)")
    parser.add_argument("--profile", default="dataset")
    parser.add_argument("--objects-dir", default=None, help="object set (default: the embedded compact YCB set)")
    parser.add_argument("--object", default="025_mug", help="the object, or comma list of objects, every case labels")
    parser.add_argument("--hand-grasps", type=int, default=400, help="grasps per object per hand-mode case (0 skips hand mode)")
    parser.add_argument("--label-engines", default="pybullet,mujoco", help="engines the hand-mode cases label in")
    parser.add_argument("--protocols", default="tabletop,floating", help="protocols the hand-mode cases label in")
    parser.add_argument("--arm-grasps", type=int, default=60, help="grasps per arm-mode case (0 skips arm mode)")
    parser.add_argument("--workers", default="1,2", help="comma-separated worker counts")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--pairs", type=int, default=None, help="sampled point pairs per capture (default: the profile's)")
    parser.add_argument("--shared-world-pairs", default="1,4,16", help="hand-object pairs per world for the step-cost measure ('' skips)")
    parser.add_argument("--project-objects", type=int, default=1000)
    parser.add_argument("--project-grasps", type=int, default=2000)
    parser.add_argument("--gripper", default=None, help="the gripper the speed cases and the analytic cases are made for (default: the profile's)")
    fidelity = parser.add_argument_group("label fidelity (--fidelity)")
    fidelity.add_argument("--fidelity", action="store_true", help="measure label fidelity instead of speed")
    fidelity.add_argument("--out", type=Path, help="folder the fidelity results are written to")
    fidelity.add_argument("--objects", default=None, help="comma-separated object ids (default: see above)")
    fidelity.add_argument("--grasps", type=int, default=60, help="grasps planned per object")
    fidelity.add_argument("--perturbed-simulations", type=int, default=None, help="simulations per label (default: the profile's)")
    agreement = parser.add_argument_group("engine agreement (--engines; --out, --objects, --grasps and --perturbed-simulations as above)")
    agreement.add_argument("--engines", action="store_true", help="compare MuJoCo's labels with PyBullet's instead of speed")
    agreement.add_argument("--mujoco-variants", default="[{}]", help="JSON list of [labelling.mujoco] override tables, one a variant")
    analytic = parser.add_argument_group("analytic grasps (--analytic; --out, --label-engines and --protocols as above)")
    analytic.add_argument("--analytic", action="store_true", help="label grasps whose outcome is known on paper instead of speed")
    fixed = parser.add_argument_group("labels changed on a fixed grasp set (--fixed-set; --out, --objects, --grasps, --label-engines as above)")
    fixed.add_argument("--fixed-set", type=Path, default=None, help="the grasp set (.npz) to label instead of speed; planned first where missing")
    fixed.add_argument("--fixed-protocol", default="floating", help="the protocol the fixed set is labelled in")
    fixed.add_argument("--labelling-overrides", default="{}", help="JSON table of [labelling] overrides the fixed set is labelled with")
    fixed.add_argument("--reference", type=Path, default=None, help="an earlier --fixed-set run's --out: count the labels changed against it")
    grippers = parser.add_argument_group("gripper agreement (--grippers; --out, --objects, --grasps and --perturbed-simulations as above)")
    grippers.add_argument("--grippers", default=None, help="comma list of grippers: label the same planned grasps with each (floating) instead of speed")
    grippers.add_argument("--gripper-engine", default="mujoco", choices=ENGINES, help="the engine the grippers' labels are made in")
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if args.gripper is not None and args.gripper not in GRIPPERS:
        print(f"error: --gripper takes one of {', '.join(GRIPPERS)}, got {args.gripper!r}", file=sys.stderr)
        return 2
    if args.fidelity:
        return _fidelity_main(parser, args)
    if args.engines:
        return _engines_main(parser, args)
    if args.analytic:
        return _analytic_main(parser, args)
    if args.grippers is not None:
        return _grippers_main(parser, args)
    if args.fixed_set is not None:
        return _fixed_set_main(parser, args)
    if args.json is None:
        parser.error("--json is required (or --fidelity with --out)")
    return _speed_main(parser, args)


def _speed_main(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    worker_counts = _counts(parser, "--workers", args.workers, 1)
    pair_counts = _counts(parser, "--shared-world-pairs", args.shared_world_pairs, 1) if args.shared_world_pairs.strip() else []
    if args.repeats < 1 or args.hand_grasps < 0 or args.arm_grasps < 0:
        parser.error("--repeats must be >= 1 and --hand-grasps / --arm-grasps >= 0")
    engines, protocols = args.label_engines.split(","), args.protocols.split(",")
    cases = [DatasetCase("hand", args.hand_grasps, engine.strip(), protocol.strip()) for engine in engines for protocol in protocols
             if args.hand_grasps > 0]
    cases += [DatasetCase("arm", args.arm_grasps)] if args.arm_grasps > 0 else []
    object_ids = [part.strip() for part in args.object.split(",") if part.strip()]
    planner = {key: value for key, value in (("n_pairs", args.pairs), ("gripper", args.gripper)) if value is not None}
    try:
        config = load_config(args.profile, overrides={"planner": planner} if planner else None)
        if pair_counts and robot_of(config).gripper.finger_motion != "slide":
            raise ConfigError(f"--shared-world-pairs closes a slide gripper's fingers, not {config.planner.gripper}'s linkage: pass ''")
        for case in cases:  # an unknown engine or protocol is refused before any work
            dataclasses.replace(config.dataset, engines=(case.engine,), protocol=case.protocol)
        objects = load_object_set(args.objects_dir)
        for object_id in object_ids:
            objects.get(object_id)
    except (ConfigError, ObjectSetError, ObjectLoadError, UnknownObjectError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    configure_torch()

    rows = benchmark_dataset(config, objects, object_ids, cases, worker_counts, args.repeats)
    for row in rows:
        stages = " ".join(f"{stage}={row['stage_s'][stage]:.2f}s" for stage in STAGES)
        print(f"{row['case']:>22} workers={row['workers']} {row['labelled']} labelled ({row['simulated']} simulated, {row['untested']} untested) "
              f"in {row['wall_s']:.1f} s: {row['labels_per_s_per_core']:.1f} labels/s per core ({row['busy_labels_per_s_per_core']:.1f} busy), "
              f"simulation alone {row['simulated_labels_per_s_per_core']:.1f}/s | {stages} (summed over workers, medians of {row['repeats']})", flush=True)
    projection = _projection(rows, args.project_objects, args.project_grasps)
    shared = shared_world_step_cost(config, objects, object_ids[0], pair_counts) if pair_counts else []
    for row in shared:
        print(f"shared world: {row['pairs']:>3} hand-object pairs, {row['contacts']} contacts: {row['step_ms']:.3f} ms a step, "
              f"{row['step_ms_per_pair']:.3f} ms per pair")
    report = {"cases": rows, "projection": projection, "shared_world": shared,
              "provenance": collect(config.to_dict(), object=args.object, objects_source=objects.source, repeats=args.repeats)}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(report, indent=2, default=str))
    return 0


def _projection(rows: list[dict], objects_count: int, grasps_per_object: int) -> list[dict]:
    """Per hand-mode engine and protocol, the hours ``objects_count`` x ``grasps_per_object`` labels take at
    the busy rate of the most workers measured, printed as they are made."""
    projections = []
    for case in dict.fromkeys(row["case"] for row in rows if row["mode"] == "hand"):
        widest = max((row for row in rows if row["case"] == case), key=lambda row: row["workers"])
        rate = widest["busy_labels_per_s_per_core"]
        hours = {cores: projected_hours(rate, objects_count, grasps_per_object, cores) for cores in PROJECTION_CORES}
        projections.append({"case": case, "objects": objects_count, "grasps_per_object": grasps_per_object,
                            "busy_labels_per_s_per_core": rate, "measured_workers": widest["workers"], "hours_by_cores": hours})
        print(f"projection, {case}, every core busy at {rate:.1f} labels/s: {objects_count} objects x {grasps_per_object} grasps = "
              + ", ".join(f"{h:.0f} h on {cores} cores" for cores, h in hours.items()))
    return projections


def _fidelity_inputs(parser: argparse.ArgumentParser, args: argparse.Namespace, flag: str = "--fidelity",
                     default_objects: tuple[str, ...] = DEFAULT_OBJECTS):
    """The config, object set and object ids of a fidelity or engine run, each checked before any work; None once an error is printed."""
    if args.out is None:
        parser.error(f"{flag} needs --out DIR")
    if args.out.exists() and not args.out.is_dir():
        parser.error(f"--out {args.out} is a file, not a folder")
    if args.grasps < 1:
        parser.error(f"--grasps must be >= 1, got {args.grasps}")
    overrides = {"planner": {"n_pairs": args.pairs}, "labelling": {"perturbed_simulations": args.perturbed_simulations}}
    overrides = {section: {k: v for k, v in values.items() if v is not None} for section, values in overrides.items()}
    try:
        config = load_config(args.profile, overrides={section: values for section, values in overrides.items() if values})
        objects = load_object_set(args.objects_dir, MeshImportSettings())
        if args.objects is not None:
            object_ids = [part.strip() for part in args.objects.split(",") if part.strip()]
        elif args.objects_dir is None:
            object_ids = list(default_objects)
        else:
            object_ids = [spec.id for spec in objects.targets()]
        if not object_ids:
            parser.error(f"--objects names no object, got {args.objects!r}")
        for object_id in object_ids:
            objects.get(object_id)
    except (ConfigError, ObjectSetError, ObjectLoadError, UnknownObjectError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return None
    return config, objects, object_ids


def _write_results(out: Path, names: tuple[str, str], report: dict, markdown: str, provenance: dict) -> int:
    """The report's JSON and markdown (``names``) and the provenance written into ``out``, the markdown printed; the exit code."""
    from sagp_batched.run_directory import PROVENANCE_FILE, RunDirectoryError, write_file_atomically, write_json

    try:
        out.mkdir(parents=True, exist_ok=True)
        write_json(out / names[0], report)
        write_file_atomically(out / names[1], markdown.encode("utf-8"))
        write_json(out / PROVENANCE_FILE, provenance)
    except (OSError, RunDirectoryError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(markdown)
    return 0


def _fidelity_main(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    inputs = _fidelity_inputs(parser, args)
    if inputs is None:
        return 2
    config, objects, object_ids = inputs
    configure_torch()
    settings = MeshImportSettings()
    report = label_fidelity(config, objects, object_ids, args.grasps, settings, note=lambda line: print(line, file=sys.stderr))
    return _write_results(args.out, (FIDELITY_JSON, FIDELITY_MARKDOWN), report, fidelity_markdown(report), collect(
        config.to_dict(), objects_source=objects.source, objects=object_ids, grasps_per_object=args.grasps,
        planning="dataset.protocol=floating, captures_per_object=1"))


def _mujoco_variants(parser: argparse.ArgumentParser, text: str, config: Config) -> list[dict]:
    """The --mujoco-variants list, each variant checked as a profile's [labelling.mujoco] would be."""
    try:
        variants = json.loads(text)
    except ValueError as exc:
        parser.error(f"--mujoco-variants is not JSON: {exc}")
    if not isinstance(variants, list) or not variants or not all(isinstance(v, dict) for v in variants):
        parser.error(f"--mujoco-variants takes a JSON list of tables, got {text!r}")
    for variant in variants:
        try:
            engines.mujoco_variant(config, variant)
        except ConfigError as exc:
            parser.error(f"--mujoco-variants: {exc}")
    return variants


def _engines_main(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    inputs = _fidelity_inputs(parser, args, "--engines", engines.DEFAULT_OBJECTS)
    if inputs is None:
        return 2
    config, objects, object_ids = inputs
    variants = _mujoco_variants(parser, args.mujoco_variants, config)
    configure_torch()
    report = engines.engine_agreement(config, objects, object_ids, args.grasps, variants, note=lambda line: print(line, file=sys.stderr))
    return _write_results(args.out, (ENGINES_JSON, ENGINES_MARKDOWN), report, engines.agreement_markdown(report), collect(
        config.to_dict(), objects_source=objects.source, objects=object_ids, grasps_per_object=args.grasps, mujoco_variants=variants))


def _analytic_main(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    if args.out is None:
        parser.error("--analytic needs --out DIR")
    if args.out.exists() and not args.out.is_dir():
        parser.error(f"--out {args.out} is a file, not a folder")
    engines_asked, unknown_engines = names_and_unknown(args.label_engines, ENGINES)
    protocols, unknown_protocols = names_and_unknown(args.protocols, LABEL_PROTOCOLS)
    if unknown_engines or not engines_asked:
        parser.error(f"--label-engines takes a comma list of {', '.join(ENGINES)}, got {args.label_engines!r}")
    if unknown_protocols or not protocols:
        parser.error(f"--protocols takes a comma list of {', '.join(LABEL_PROTOCOLS)}, got {args.protocols!r}")
    try:
        config = load_config(args.profile, overrides={"planner": {"gripper": args.gripper}} if args.gripper else None)
    except ConfigError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    configure_torch()
    report = analytic_grasps(config, tuple(engines_asked), tuple(protocols), note=lambda line: print(line, file=sys.stderr))
    if args.json is not None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2, default=str))
    return _write_results(args.out, (ANALYTIC_JSON, ANALYTIC_MARKDOWN), report, analytic_markdown(report), collect(
        analytic_config(config).to_dict(), engines=engines_asked, protocols=protocols))
def _fixed_set_main(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    engine_names, unknown = names_and_unknown(args.label_engines, ENGINES)
    if unknown or not engine_names:
        parser.error(f"--label-engines takes one or more of {', '.join(ENGINES)}, got {args.label_engines!r}")
    try:
        overrides = json.loads(args.labelling_overrides)
    except ValueError as exc:
        parser.error(f"--labelling-overrides is not JSON: {exc}")
    if not isinstance(overrides, dict):
        parser.error(f"--labelling-overrides takes a JSON table, got {args.labelling_overrides!r}")
    reference_file = None if args.reference is None else args.reference / FIXED_JSON
    if reference_file is not None and not reference_file.is_file():
        parser.error(f"--reference {args.reference} holds no {FIXED_JSON}")
    inputs = _fidelity_inputs(parser, args, "--fixed-set", fixed_labels.FIXED_SET_OBJECTS)
    if inputs is None:
        return 2
    config, objects, object_ids = inputs
    try:
        config = config.override("labelling", **overrides)
        label_protocol(args.fixed_protocol)
        configure_torch()
        if not args.fixed_set.exists():
            planned = fixed_labels.build_fixed_set(config, objects, object_ids, args.grasps, args.fixed_set)
            print(f"planned {sum(planned.values())} grasps into {args.fixed_set}: " + ", ".join(f"{k} {v}" for k, v in planned.items()))
        grasp_set = fixed_labels.load_fixed_set(args.fixed_set)
        for object_id in grasp_set:
            objects.get(object_id)
    except (ConfigError, ValueError, ObjectLoadError, UnknownObjectError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    reference = json.loads(reference_file.read_text())["engines"] if reference_file is not None else {}
    report: dict = {"fixed_set": str(args.fixed_set), "protocol": args.fixed_protocol, "labelling_overrides": overrides, "engines": {}}
    lines = []
    for engine in engine_names:
        records, seconds = fixed_labels.label_fixed_set(config, objects, grasp_set, engine, args.fixed_protocol)
        row = {"records": records, "cpu_s": seconds, "labels_per_cpu_s": len(records) / seconds}
        line = f"{engine}: {len(records)} labels ({sum(r['held'] for r in records)} held) in {seconds:.1f} CPU s, {row['labels_per_cpu_s']:.2f} labels/s"
        if engine in reference:
            row["changed"] = fixed_labels.changed_labels(reference[engine]["records"], records)
            row["cpu_ratio_to_reference"] = seconds / reference[engine]["cpu_s"]
            line += (f"; against the reference: {row['changed']['held_changed']} held/dropped changed ({row['changed']['now_held']} now held, "
                     f"{row['changed']['now_dropped']} now dropped), {row['changed']['failure_changed']} failures changed, "
                     f"{row['cpu_ratio_to_reference']:.2f} of its CPU time")
        report["engines"][engine] = row
        lines.append(line)
    return _write_results(args.out, (FIXED_JSON, FIXED_MARKDOWN), report, "\n".join(lines) + "\n", collect(
        config.to_dict(), objects_source=objects.source, fixed_set=str(args.fixed_set), labelling_overrides=overrides))


def _grippers_main(parser: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    names, unknown = names_and_unknown(args.grippers, GRIPPERS)
    if unknown or len(names) < 2:
        parser.error(f"--grippers takes two or more of {', '.join(GRIPPERS)}, got {args.grippers!r}")
    inputs = _fidelity_inputs(parser, args, "--grippers", engines.DEFAULT_OBJECTS)
    if inputs is None:
        return 2
    config, objects, object_ids = inputs
    configure_torch()
    report = gripper_agreement(config, objects, object_ids, args.grasps, names, args.gripper_engine, note=lambda line: print(line, file=sys.stderr))
    return _write_results(args.out, (GRIPPERS_JSON, GRIPPERS_MARKDOWN), report, gripper_agreement_markdown(report), collect(
        config.to_dict(), objects_source=objects.source, objects=object_ids, grasps_per_object=args.grasps, grippers=names,
        engine=args.gripper_engine))


if __name__ == "__main__":
    raise SystemExit(main())
