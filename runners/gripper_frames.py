"""Draw each gripper's file frame on the mug (the documentation's pictures).

    python -m runners.gripper_frames --out docs/images/grippers

One PNG per gripper the package describes: its open hand's collision hulls at a grasp on the embedded YCB mug's
rim, with the frame ACRONYM's and GraspGen's files write for it.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import trimesh

from sagp_batched.config.world import GRIPPERS
from sagp_batched.formats.frame_pictures import draw_gripper_frame
from sagp_batched.world.objects import embedded_ycb_dir, load_object_set

from .cli import names_and_unknown

OBJECT_ID = "025_mug"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True, help="folder the pictures are written to (<gripper>.png)")
    parser.add_argument("--grippers", default=",".join(GRIPPERS), help="comma list of grippers (default: all)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    names, unknown = names_and_unknown(args.grippers, GRIPPERS)
    if unknown or not names:
        print(f"error: --grippers: unknown {', '.join(unknown) or '(none given)'}; known: {', '.join(GRIPPERS)}", file=sys.stderr)
        return 2
    spec = load_object_set(embedded_ycb_dir()).get(OBJECT_ID)
    mesh = trimesh.load(spec.urdf_path.parent / "textured.obj", force="mesh")
    for name in names:
        print(draw_gripper_frame(name, spec, mesh, args.out / f"{name}.png"))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
