"""Picture of an object's coarse zones: ``python -m runners.zones --object 025_mug --out mug_zones.png``.

Places the object as trial ``--trial`` of the study would, captures its cloud with the three
cameras, decomposes it into zones and saves the cloud coloured by zone with a legend, beside the
object's annotated functional and avoid regions where it has them (else its side zones). The zone
descriptions the rating prompt would carry are printed.
"""
from __future__ import annotations

import argparse
import sys

from sagp_batched.config import ConfigError, load_config
from sagp_batched.functional_regions import region_membership
from sagp_batched.objects import ObjectLoadError, ObjectSetError, UnknownObjectError, load_object_set
from sagp_batched.perception import capture
from sagp_batched.scene import Scene
from sagp_batched.types import PerceptionFailure
from sagp_batched.zones import decompose, describe_zones, plot_zones


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
