"""Picture of an object's coarse zones: ``python -m runners.zones --object 025_mug --out mug_zones.png``.

Places the object as trial ``--trial`` of the study would, captures its cloud with the three
cameras, decomposes it into zones and saves the cloud coloured by zone with a legend, beside the
object's annotated functional and avoid regions where it has them (else its side zones). The zone
descriptions the rating prompt would carry are printed.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from sagp_batched.config import ConfigError, load_config
from sagp_batched.semantics.zone_descriptions import describe_zones
from sagp_batched.semantics.zone_marks import PRIMARY_ZONE_RGB, PROTRUSION_RGB
from sagp_batched.semantics.zones import GEOMETRIC_ZONES, ZONE_INDEX, ZoneDecomposition, decompose
from sagp_batched.types import PerceptionFailure
from sagp_batched.world.functional_regions import region_membership
from sagp_batched.world.objects import ObjectLoadError, ObjectSetError, UnknownObjectError, load_object_set
from sagp_batched.world.perception import capture
from sagp_batched.world.scene import Scene


# Zone colours are the ones ``zone_marks`` draws on the rating image, so the plot and the image agree.
_PRIMARY_COLOURS = {name: tuple(c / 255.0 for c in rgb) for name, rgb in PRIMARY_ZONE_RGB.items()}
_PROTRUSION_COLOURS = tuple(tuple(c / 255.0 for c in rgb) for rgb in PROTRUSION_RGB)
_SIDE_COLOURS = {("left", "front"): "tab:purple", ("left", "back"): "tab:pink", ("right", "front"): "tab:cyan", ("right", "back"): "tab:olive"}


def plot_zones(
    decomposition: ZoneDecomposition, path: str | Path, title: str = "", regions: dict[str, np.ndarray] | None = None
) -> Path:
    """Save a PNG of the cloud coloured by zone: primary zones (left panel, each protrusion in its
    own colour) and, beside them, the object's annotated regions when ``regions`` ("functional",
    "avoid": (N,) bool per cloud point) is given, else the side zones."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    points = decomposition.points_world.numpy()
    figure = plt.figure(figsize=(11, 5.5))
    primary_axes = figure.add_subplot(1, 2, 1, projection="3d")
    right_axes = figure.add_subplot(1, 2, 2, projection="3d")
    protrusions = decomposition.zone_names[len(GEOMETRIC_ZONES):]
    colours = {**_PRIMARY_COLOURS, **{name: _PROTRUSION_COLOURS[k % len(_PROTRUSION_COLOURS)] for k, name in enumerate(protrusions)}}
    for name, colour in colours.items():
        member = (decomposition.point_zone == decomposition.zone_names.index(name)).numpy()
        if member.any():
            primary_axes.scatter(*points[member].T, s=2, color=colour, label=f"{name} ({int(member.sum())})")
    if regions is not None:
        functional, avoid = np.asarray(regions["functional"], dtype=bool), np.asarray(regions["avoid"], dtype=bool)
        panels = {"functional region": (functional, "tab:green"), "avoid region": (avoid, "tab:red"),
                  "elsewhere": (~functional & ~avoid, "lightgray")}
        right_heading = "annotated regions"
    else:
        panels = {
            f"{lateral}/{depth}": ((decomposition.memberships[:, ZONE_INDEX[lateral]] & decomposition.memberships[:, ZONE_INDEX[depth]]).numpy(), colour)
            for (lateral, depth), colour in _SIDE_COLOURS.items()
        }
        right_heading = "side zones"
    for label, (member, colour) in panels.items():
        if member.any():
            right_axes.scatter(*points[member].T, s=2, color=colour, label=f"{label} ({int(member.sum())})")
    subtitle = f" [degenerate: {decomposition.degenerate}]" if decomposition.degenerate else ""
    primary_heading = f"primary zones, {decomposition.split} thirds, {decomposition.protrusion_rule} protrusion rule"
    for axes, heading in ((primary_axes, primary_heading), (right_axes, right_heading)):
        axes.set_title(f"{title} {heading}{subtitle}".strip())
        axes.set_xlabel("x (m)")
        axes.set_ylabel("y (m)")
        axes.set_zlabel("z (m)")
        if points.shape[0]:
            centre = points.mean(axis=0)
            half = max(float(np.ptp(points, axis=0).max()) / 2.0, 1e-3)
            axes.set_xlim(centre[0] - half, centre[0] + half)
            axes.set_ylim(centre[1] - half, centre[1] + half)
            axes.set_zlim(centre[2] - half, centre[2] + half)
        axes.legend(loc="upper left", markerscale=4, fontsize=8)
    figure.tight_layout()
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    figure.savefig(path, dpi=120)
    plt.close(figure)
    return path


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m runners.zones", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--object", required=True, dest="object_id", help="object id, e.g. 025_mug")
    parser.add_argument("--objects-dir", help="YCB directory (objects.json + URDFs), or 'pybullet_data' for the built-in set; default $SAGP_YCB_DIR, else the embedded compact YCB set")
    parser.add_argument("--out", help="PNG path (default: <object>_zones.png)")
    parser.add_argument("--trial", type=int, default=0, help="trial whose random placement to use (default 0)")
    parser.add_argument("--profile", default="paper", help="profile name in profiles/ or a TOML path (default: paper)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        config = load_config(args.profile)
        spec = load_object_set(args.objects_dir).get(args.object_id)
    except (ConfigError, ObjectSetError, ObjectLoadError, UnknownObjectError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    with Scene(config) as scene:
        scene.reset(spec, args.trial)
        try:
            cloud = capture(scene, config)
        except PerceptionFailure as failure:
            print(f"error: {spec.id} trial {args.trial}: {failure}", file=sys.stderr)
            return 1
    zones = decompose(cloud.points_world, config.zones)
    points_object = cloud.in_object_frame(cloud.points_world.numpy())
    membership = region_membership(spec.id, points_object)
    regions = None if membership["in_functional_region"] is None else {
        "functional": membership["in_functional_region"], "avoid": membership["in_avoid_region"]}
    out = plot_zones(zones, args.out or f"{spec.id}_zones.png", f"{spec.id} (trial {args.trial})", regions)
    if zones.degenerate:
        print(f"degenerate cloud: {zones.degenerate} ({zones.degenerate_reason})", file=sys.stderr)
    for description in describe_zones(zones).values():
        print(description)
    print(f"wrote {out}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
