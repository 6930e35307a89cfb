"""Metric views of an object's mesh for placing functional-region boxes:
``python -m runners.annotation_views --objects-dir /work/shared/ycb --object 025_mug --out DIR``.

Draws the visual mesh's vertices (``textured.obj``, in the object's link frame, metres) in three
orthographic views, top (x-y), front (x-z) and side (y-z), on a 1 cm grid, and overlays the
object's annotated functional (green) and avoid (red) boxes from ``functional_regions.json`` when it
has any. Writes ``DIR/<object>_views.png``.
"""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from sagp_batched.world.functional_regions import RegionBox, load_regions, mesh_vertices

GRID_M = 0.01
# (title, index of the horizontal axis, index of the vertical axis)
VIEWS = (("top (x-y)", 0, 1), ("front (x-z)", 0, 2), ("side (y-z)", 1, 2))
AXIS_NAMES = "xyz"
REGION_COLOURS = {"functional": "tab:green", "avoid": "tab:red"}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m runners.annotation_views", description=__doc__,
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--objects-dir", required=True, help="YCB directory (objects.json + <id>/textured.obj)")
    parser.add_argument("--object", required=True, dest="object_id", help="object id, e.g. 025_mug")
    parser.add_argument("--out", required=True, help="directory for <object>_views.png")
    parser.add_argument("--regions", help="functional_regions.json to overlay (default: the package's)")
    return parser


def draw_views(vertices_object: np.ndarray, boxes: dict[str, tuple[RegionBox, ...]], title: str, path: Path) -> Path:
    """Save three orthographic scatter views of ``vertices_object`` (N, 3) in metres, object frame,
    with each region's boxes drawn as rectangles (their projection onto the view's plane)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.patches import Rectangle
    from matplotlib.ticker import MultipleLocator

    low = vertices_object.min(axis=0) - 2 * GRID_M
    high = vertices_object.max(axis=0) + 2 * GRID_M
    # One scale for all three views, so 1 cm is the same length on the page in each.
    inches_per_m = 40.0
    widths = [high[h] - low[h] for _, h, _ in VIEWS]
    height = max(high[v] - low[v] for _, _, v in VIEWS)
    fig, axes = plt.subplots(1, 3, figsize=(inches_per_m * sum(widths) + 3, inches_per_m * height + 1.5),
                             gridspec_kw={"width_ratios": widths})
    for ax, (view_title, h, v) in zip(axes, VIEWS):
        ax.scatter(vertices_object[:, h], vertices_object[:, v], s=0.3, c="0.3", alpha=0.5, linewidths=0)
        for region, region_boxes in boxes.items():
            for box in region_boxes:
                ax.add_patch(Rectangle((box.min[h], box.min[v]), box.max[h] - box.min[h], box.max[v] - box.min[v],
                                       fill=False, edgecolor=REGION_COLOURS[region], linewidth=1.5))
        ax.set_xlim(low[h], high[h])
        ax.set_ylim(low[v], high[v])
        ax.set_aspect("equal")
        ax.xaxis.set_minor_locator(MultipleLocator(GRID_M))
        ax.yaxis.set_minor_locator(MultipleLocator(GRID_M))
        ax.xaxis.set_major_locator(MultipleLocator(5 * GRID_M))
        ax.yaxis.set_major_locator(MultipleLocator(5 * GRID_M))
        ax.grid(which="minor", linewidth=0.3, color="0.85")
        ax.grid(which="major", linewidth=0.6, color="0.6")
        ax.tick_params(labelsize=7)
        ax.set_xlabel(f"{AXIS_NAMES[h]} (m)")
        ax.set_ylabel(f"{AXIS_NAMES[v]} (m)")
        ax.set_title(view_title, fontsize=9)
    fig.suptitle(f"{title}   green: functional, red: avoid   grid 1 cm", fontsize=9)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    mesh_path = Path(args.objects_dir) / args.object_id / "textured.obj"
    try:
        vertices_object = mesh_vertices(mesh_path)
        regions = load_regions(args.regions)
    except (OSError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    annotation = regions.get(args.object_id)
    boxes = {"functional": annotation.functional, "avoid": annotation.avoid} if annotation else {}
    out_dir = Path(args.out)
    out_dir.mkdir(parents=True, exist_ok=True)
    path = draw_views(vertices_object, boxes, args.object_id, out_dir / f"{args.object_id}_views.png")
    if annotation is None:
        print(f"{args.object_id} has no annotated regions; drew the mesh only", file=sys.stderr)
    print(f"wrote {path}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
