"""Another simulator's grasps relabelled by ours (``runners.relabel`` is its command line).

A grasp file (``formats.grasp_file.read_grasp_file``) is checked with its mesh (``check_inputs``), the mesh imported as our
object at the file's scale, mass and friction (``import_object``), the file's grasps moved into that object's link
frame (``link_from_imported_mesh``) and labelled in chunks kept as each finishes (``label_pending``), so that a second
``relabel`` into the same directory resumes; the agreement of the file's labels and ours is written with them.
"""
from __future__ import annotations

import functools
import hashlib
import json
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from .. import provenance
from ..config import Config, ConfigError, load_config
from ..formats.acronym import relabel_file_bytes
from ..formats.frames import grasp_poses_from_acronym
from ..formats.grasp_file import GraspFile, read_grasp_file
from ..robot.description import robot_of
from ..robot.gripper_description import gripper_by_file_name
from ..run_directory import CONFIG_FILE, PROVENANCE_FILE, RunLock, check_same_run, write_file_atomically, write_json
from ..workers import Recipe, WorkerPool
from ..world.mesh_sources import MESH_SUFFIXES
from ..world.objects import ObjectSpec, load_object_set
from .agreement import agreement_markdown, grasp_regions, label_agreement
from .cross_engine import combined_labels, diverged_by_engine
from .disagreement_causes import cause_counts, causes_table_lines, label_cause
from .engines import ENGINES
from .grasp_geometry import object_mesh_link
from .labelling import label_object_grasps

RELABEL_FILE = "relabel.h5"
AGREEMENT_FILE = "agreement.json"
REPORT_FILE = "report.md"
# What was relabelled (the file's bytes, the protocol, the grasps chosen): a resume must be of the same.
INPUT_FILE = "relabel.json"
CHUNKS_DIR = "chunks"
# How far the object's import scale may stray from the file's.
SCALE_TOLERANCE = 1e-6


class InputError(ValueError):
    """A named input that cannot serve; the message is one line."""


@dataclass(frozen=True)
class Inputs:
    """The checked inputs of a relabel: the grasp file, its mesh, the grasps chosen, the object's id, the gripper
    the file names (the package's name for it), which the grasps are simulated with."""
    grasp_file: GraspFile
    mesh_path: Path
    selection: np.ndarray  # (M,) rows of the file relabelled, ascending
    object_id: str
    protocol: str
    engines: tuple[str, ...]
    gripper: str

    def configured(self, config: Config) -> Config:
        """``config`` planning and labelling with the file's gripper."""
        return config.override("planner", gripper=self.gripper)

    @property
    def engine(self) -> str:
        """The engines as one name ("pybullet", "pybullet,mujoco"): what the records and the files say."""
        return ",".join(self.engines)


# -- inputs --------------------------------------------------------------------------------------------------------
def check_inputs(grasp_file: str | Path, mesh_root: str | Path, config: Config, engine: str | tuple[str, ...] = "pybullet",
                 max_grasps: int | None = None) -> Inputs:
    """Every named input checked before any work: ``InputError`` / ``GraspFileError`` name the first that cannot serve.

    The output directory, protocol and seed (that draws ``max_grasps`` of the file's grasps) come from ``config``;
    the messages name the command's flags, so a library caller and the command see the same one-line errors.
    """
    engines = tuple(name.strip() for name in (engine.split(",") if isinstance(engine, str) else engine) if name.strip())
    if not engines or any(name not in ENGINES for name in engines) or len(set(engines)) < len(engines):
        raise InputError(f"--engine must be one of {', '.join(ENGINES)} or a comma list of them without repeats, got {engine!r}")
    grasps = read_grasp_file(grasp_file)
    if len(grasps) == 0:
        raise InputError(f"{grasps.path}: holds no grasps")
    try:
        gripper = gripper_by_file_name(grasps.gripper).name
    except ConfigError as exc:
        raise InputError(f"{grasps.path}: {exc}") from None
    mesh_root = Path(mesh_root).expanduser()
    if not mesh_root.is_dir():
        raise InputError(f"--mesh-root {mesh_root} is not a directory")
    mesh_path = mesh_file_path(mesh_root, grasps.mesh_file)
    if mesh_path.suffix.lower() not in MESH_SUFFIXES:
        raise InputError(f"mesh {mesh_path} is a {mesh_path.suffix or 'suffix-less'} file; meshes are imported from "
                         f"{', '.join(sorted(s.lstrip('.').upper() for s in MESH_SUFFIXES))}")
    if max_grasps is not None and max_grasps < 1:
        raise InputError(f"--max-grasps must be at least 1, got {max_grasps}")
    _check_writable(Path(config.run.out).expanduser())
    n = len(grasps)
    count = n if max_grasps is None else min(max_grasps, n)
    selection = np.arange(n) if count == n else np.sort(np.random.default_rng(config.dataset.seed).choice(n, count, replace=False))
    return Inputs(grasps, mesh_path, selection, _object_id(grasps.path), config.dataset.protocol, engines, gripper)


def mesh_file_path(mesh_root: Path, mesh_file: str) -> Path:
    """The mesh a file names, below ``mesh_root``; GraspGen's Objaverse files name a uuid that the root's
    ``map_uuid_to_path[_simplified].json`` maps to a path, so that map is read where the name is no file."""
    direct = mesh_root / mesh_file
    if direct.is_file():
        return direct
    for name in ("map_uuid_to_path_simplified.json", "map_uuid_to_path.json"):
        try:
            mapped = json.loads((mesh_root / name).read_text(encoding="utf-8")).get(mesh_file)
        except (OSError, ValueError, AttributeError):
            continue
        if isinstance(mapped, str) and (mesh_root / mapped).is_file():
            return mesh_root / mapped
    raise InputError(f"mesh {mesh_file} not found under --mesh-root {mesh_root}")


def _check_writable(out_dir: Path) -> None:
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"--out {out_dir} cannot be made: {exc.strerror or exc}") from None
    if not os.access(out_dir, os.W_OK | os.X_OK):
        raise InputError(f"--out {out_dir} is not writable")


def _object_id(path: Path) -> str:
    # ACRONYM names a file <category>_<mesh>_<scale>.h5: one object per mesh and scale, as an id our files can carry.
    cleaned = "".join(c if c.isalnum() or c in "-_" else "_" for c in path.stem)
    return cleaned or "object"


def input_record(inputs: Inputs) -> dict[str, Any]:
    """What a resume must find unchanged: the file's bytes, its mesh's, the protocol, the engine, the grasps chosen."""
    def sha256(path: Path) -> str:
        return hashlib.sha256(path.read_bytes()).hexdigest()

    return {
        "file": str(inputs.grasp_file.path.resolve()), "file_sha256": sha256(inputs.grasp_file.path),
        "format": inputs.grasp_file.format, "mesh": str(inputs.mesh_path.resolve()), "mesh_sha256": sha256(inputs.mesh_path),
        "object_id": inputs.object_id, "protocol": inputs.protocol, "engine": inputs.engine,
        "selection_sha256": hashlib.sha256(inputs.selection.astype(np.int64).tobytes()).hexdigest(), "grasps": len(inputs.selection),
    }


def _check_same_input(out_dir: Path, record: dict[str, Any]) -> None:
    try:
        previous = json.loads((out_dir / INPUT_FILE).read_text(encoding="utf-8"))
    except FileNotFoundError:
        return
    except (OSError, ValueError):
        previous = {}
    keys = ("file_sha256", "mesh_sha256", "protocol", "engine", "selection_sha256")
    differing = [key.removesuffix("_sha256") for key in keys if not isinstance(previous, dict) or previous.get(key) != record[key]]
    if differing:
        raise InputError(f"{out_dir} holds a relabel of other inputs ({', '.join(differing)} differ); choose another --out or delete that directory")


# -- the object ----------------------------------------------------------------------------------------------------
def import_object(inputs: Inputs, out_dir: Path, finger_lateral_friction: float) -> tuple[Any, ObjectSpec]:
    """The file's mesh imported as our object (``mesh_import``) from ``out_dir/objects/<id>/``: a link to the mesh
    and an ``objects.json`` giving the file's scale and, where the file has them, its mass and friction.

    A file's friction is its contacts' coefficient (its simulator takes one for a contact), where PyBullet
    multiplies the finger's by the object's: the object gets the file's over ``finger_lateral_friction``, so
    its contacts with our fingers have the file's coefficient."""
    folder = out_dir / "objects" / inputs.object_id
    folder.mkdir(parents=True, exist_ok=True)
    link = folder / f"{inputs.object_id}{inputs.mesh_path.suffix.lower()}"
    for stale in folder.iterdir():
        if stale != link and stale.name != "objects.json" and (stale.is_symlink() or stale.is_file()):
            stale.unlink()  # an earlier mesh of another suffix: the folder must hold one mesh only
    if link.is_symlink() or link.exists():
        link.unlink()
    link.symlink_to(inputs.mesh_path.resolve())
    grasp_file = inputs.grasp_file
    entry: dict[str, Any] = {"scale": grasp_file.scale}
    if grasp_file.mass_kg is not None:
        entry["mass_kg"] = grasp_file.mass_kg
    elif grasp_file.density_kg_m3 is not None:
        entry["density_kg_m3"] = grasp_file.density_kg_m3
    if grasp_file.friction is not None:
        entry["friction"] = grasp_file.friction / finger_lateral_friction
    write_json(folder / "objects.json", {inputs.object_id: entry})
    objects = load_object_set(folder)
    return objects, objects.get(inputs.object_id)


def link_from_imported_mesh(spec: ObjectSpec, scale: float) -> np.ndarray:
    """(4, 4) rigid map from the file's frame (its mesh scaled by ``scale``) into the object's link frame: the
    import's own map from the mesh at its import scale, which must be the file's.

    The import recorded this map when it built the object (``world.mesh_import``); taking it from there, rather than
    rebuilding it from a mesh-to-link and the scale (``formats.frames.link_from_scaled_mesh``), keeps the exact
    values the object was built with: the rebuilt map differs in the last bits."""
    record = spec.import_record
    if record is None:
        raise InputError(f"object '{spec.id}' was not imported from a mesh, so its mesh frame is unknown")
    if not np.isclose(record.scale, scale, rtol=SCALE_TOLERANCE):
        raise InputError(f"object '{spec.id}' was imported at scale {record.scale:g}, the file's is {scale:g}")
    return record.link_from_source


def object_bounds(spec: ObjectSpec) -> np.ndarray:
    """(2, 3) the object's axis-aligned box in its link frame, from its visual mesh."""
    return np.asarray(object_mesh_link(spec).bounds, dtype=np.float64)


# -- labelling in chunks -------------------------------------------------------------------------------------------
def chunk_bounds(n: int, size: int) -> list[tuple[int, int]]:
    return [(start, min(start + size, n)) for start in range(0, n, size)]


def label_chunk(spec: ObjectSpec, transforms_link: np.ndarray, widths: np.ndarray | None, protocol: str, engines: tuple[str, ...],
                config: Config | dict) -> list[dict[str, Any]]:
    """Our labels of (C, 4, 4) ACRONYM grasp poses in the object's link frame, by each of ``engines``, as plain
    values: held where every engine held (``cross_engine.combined_labels``), each engine's own under "by_engine"."""
    if isinstance(config, dict):  # in a worker process: the config travels as its dict
        config = load_config(overrides=config)
    poses = grasp_poses_from_acronym(transforms_link, robot_of(config).gripper)
    labels = combined_labels({engine: label_object_grasps(spec, poses, widths, protocol, config, engine=engine) for engine in engines})
    if len(labels) != len(transforms_link):
        raise RuntimeError(f"{len(labels)} labels for {len(transforms_link)} grasps")
    knock_tolerance_m = config.execution.knock_tolerance_m
    plain = [_plain(label, knock_tolerance_m) for label in labels]
    if len(engines) > 1:
        for values, label in zip(plain, labels):
            values["by_engine"] = {own.engine: _plain(own, knock_tolerance_m) for own in label.by_engine}
    return plain


def _plain(label, knock_tolerance_m: float) -> dict[str, Any]:
    return {
        "cause": label_cause(label, knock_tolerance_m),  # how a dropped simulation lost the object (``disagreement_causes``)
        "held": bool(label.held),
        "failure_reason": label.failure_reason or "",
        "failed_at": label.failed_at or ("" if label.held else "unknown"),
        # One simulation's share held is its outcome.
        "held_fraction": float(label.held if label.held_fraction is None else label.held_fraction),
        "simulated": bool(getattr(label, "simulated", True)),
        # Why no simulation tested the grasp (it diverged), "" where one did: such a grasp is no label.
        "untested": f"{label.engine} {label.untested}" if label.untested else "",
    }


def _read_chunk(path: Path, start: int, stop: int) -> list[dict[str, Any]] | None:
    try:
        chunk = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None  # a chunk a killed run never finished writing: it is labelled again
    ok = isinstance(chunk, dict) and chunk.get("start") == start and chunk.get("stop") == stop and len(chunk.get("labels", ())) == stop - start
    return chunk["labels"] if ok else None


class _ChunkLabeller:
    """A worker of ``label_pending``: a unit is the (start, stop) rows of the grasps it labels (``label_chunk``)."""
    objects_dir = None

    def __init__(self, spec: ObjectSpec, transforms_link: np.ndarray, widths: np.ndarray | None, protocol: str,
                 engines: tuple[str, ...], config: Config | dict):
        self.spec, self.transforms_link, self.widths = spec, transforms_link, widths
        self.protocol, self.engines, self.config = protocol, engines, config

    def run(self, rows: tuple[int, int]) -> list[dict[str, Any]]:
        start, stop = rows
        widths = None if self.widths is None else self.widths[start:stop]
        return label_chunk(self.spec, self.transforms_link[start:stop], widths, self.protocol, self.engines, self.config)

    def close(self) -> None:
        """Nothing to free: each chunk's engines are closed when it is labelled."""


def label_pending(spec: ObjectSpec, transforms_link: np.ndarray, widths: np.ndarray | None, inputs: Inputs,
                  config: Config, out_dir: Path, on_chunk: Any = None) -> list[dict[str, Any]]:
    """Every grasp's label: chunks already in ``out_dir/chunks`` read back, the rest labelled and each written as it ends."""
    (out_dir / CHUNKS_DIR).mkdir(exist_ok=True)
    bounds = chunk_bounds(len(transforms_link), config.dataset.grasps_per_chunk)
    done = {start: labels for start, stop in bounds if (labels := _read_chunk(out_dir / CHUNKS_DIR / f"{start:08d}.json", start, stop)) is not None}
    pending = [(start, stop) for start, stop in bounds if start not in done]

    def keep(start: int, stop: int, labels: list[dict[str, Any]]) -> None:
        write_json(out_dir / CHUNKS_DIR / f"{start:08d}.json", {"start": start, "stop": stop, "labels": labels})
        done[start] = labels
        if on_chunk is not None:
            on_chunk(len(done), len(bounds))

    labeller = functools.partial(_ChunkLabeller, spec, transforms_link, widths, inputs.protocol, inputs.engines)
    # Relabelling runs here or in spawned processes (``--workers``), whatever the run's backend.
    pool = WorkerPool("local", config.run.workers, here=lambda: labeller(config), in_process=Recipe(labeller, (config.to_dict(),)))
    with pool:
        for (start, stop), labels, _ in pool.as_finished(pending):
            keep(start, stop, labels)
    return [label for start, _ in bounds for label in done[start]]


# -- results -------------------------------------------------------------------------------------------------------
def relabel(inputs: Inputs, config: Config, out_dir: Path, note: Any = print) -> dict[str, Any]:
    """Relabel the inputs into ``out_dir`` (resuming what is there) and return the agreement.

    ``note`` is handed each progress and import-fidelity line. Raises ``InputError`` for a directory holding a
    relabel of other inputs or an object whose frame cannot take the file's grasps, and the object set's and run
    directory's own errors."""
    config = inputs.configured(config)
    gripper = robot_of(config).gripper  # the file's gripper, its grip force range checked before any work
    record = input_record(inputs)
    with RunLock(out_dir):
        _check_same_input(out_dir, record)
        objects, spec = import_object(inputs, out_dir, config.execution.finger_lateral_friction)
        for issue in spec.import_record.fidelity_issues if spec.import_record is not None else ():
            note(f"note: object '{spec.id}': {issue}")
        checksum = objects.checksum()
        check_same_run(out_dir, config, checksum, objects.source)
        write_json(out_dir / CONFIG_FILE, config.to_dict())
        write_json(out_dir / PROVENANCE_FILE, provenance.collect(
            config.to_dict(), relabel=record, objects={"source": objects.source, "checksum": checksum, "ids": [spec.id]}))
        write_json(out_dir / INPUT_FILE, record)
        link_from_file = link_from_imported_mesh(spec, inputs.grasp_file.scale)
        transforms_link = link_from_file @ inputs.grasp_file.transforms[inputs.selection]
        widths = None if inputs.grasp_file.width_m is None else inputs.grasp_file.width_m[inputs.selection]
        every_label = label_pending(spec, transforms_link, widths, inputs, config, out_dir,
                                    lambda done, total: note(f"chunk {done}/{total} labelled"))
        # A grasp no simulation tested is compared with nothing and kept apart in the file.
        tested = np.array([not label.get("untested") for label in every_label], dtype=bool)
        labels = [label for label, kept in zip(every_label, tested) if kept]
        untested = {"rows": inputs.selection[~tested], "reason": [label["untested"] for label in every_label if label.get("untested")]}
        regions = grasp_regions(grasp_poses_from_acronym(transforms_link[tested], gripper).position.numpy(), object_bounds(spec))
        phases = [label["failed_at"] for label in labels]
        reference = inputs.grasp_file.labels[inputs.selection][tested]
        result = label_agreement(reference, np.array([label["held"] for label in labels], dtype=bool), phases, regions)
        result.update(file=record["file"], protocol=inputs.protocol, engine=inputs.engine, object_id=spec.id,
                      untested=diverged_by_engine(untested["reason"], inputs.engines))
        if len(inputs.engines) > 1:
            result.update(_engine_agreements(reference, labels, regions, inputs.engines))
        write_file_atomically(out_dir / RELABEL_FILE, relabel_file_bytes(
            inputs.grasp_file, inputs.selection[tested], link_from_file, labels, regions, object_id=spec.id, mass_kg=spec.mass_kg,
            protocol=inputs.protocol, engine=inputs.engine, gripper=gripper, untested=untested))
        write_json(out_dir / AGREEMENT_FILE, result)
        name = f"{inputs.grasp_file.path.name} ({inputs.grasp_file.format})"
        markdown = agreement_markdown(result, f"Label agreement: {name} vs ours ({inputs.protocol}, {inputs.engine})")
        for engine, part in result.get("by_engine", {}).items():
            markdown += "\n" + agreement_markdown(part, f"Label agreement: {name} vs {engine} alone")
        if "between_engines" in result:
            between = result["between_engines"]
            markdown += "\n" + agreement_markdown(between, f"Between the engines: {between['ours']} against {between['reference']} as the reference")
            causes = causes_table_lines(result["disagreement_causes"], inputs.engines[:2], config.execution.knock_tolerance_m)
            markdown += "\n" + "\n".join(causes) + "\n"
        write_file_atomically(out_dir / REPORT_FILE, markdown.encode("utf-8"))
    return result


def _engine_agreements(reference: np.ndarray, labels: list[dict[str, Any]], regions: list[str], engines: tuple[str, ...]) -> dict[str, Any]:
    """With several engines: each one's agreement with the file's labels, and the second's with the first's."""
    own = {engine: [label["by_engine"][engine] for label in labels] for engine in engines}
    held = {engine: np.array([label["held"] for label in own[engine]], dtype=bool) for engine in engines}
    phases = {engine: [label["failed_at"] for label in own[engine]] for engine in engines}
    first, second = engines[:2]
    simulated = np.array([label["simulated"] for label in labels], dtype=bool)
    rows = np.flatnonzero(simulated & (held[first] != held[second]))
    dropped_by = [first if not held[first][row] else second for row in rows]
    # A chunk kept by a relabel from before causes were recorded has none: "other", the rule's no-record cause.
    causes = [own[engine][row].get("cause") or "other" for engine, row in zip(dropped_by, rows)]
    return {"by_engine": {engine: label_agreement(reference, held[engine], phases[engine], regions) for engine in engines},
            "between_engines": {"reference": first, "ours": second, **label_agreement(held[first], held[second], phases[second], regions)},
            "disagreement_causes": cause_counts(dropped_by, causes, (first, second))}
