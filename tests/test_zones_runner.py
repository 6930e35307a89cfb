"""``python -m runners.zones``: a YCB object placed, seen by the three cameras, and drawn by zone."""
from __future__ import annotations

from picture_checks import TAB_RGB, pixels_of_colour

from sagp_batched_runners.zones import main


def test_zone_picture_of_a_placed_mug(ycb_dir, tmp_path, capsys):
    out = tmp_path / "mug_zones.png"
    assert main(["--object", "025_mug", "--objects-dir", str(ycb_dir), "--out", str(out), "--trial", "1"]) == 0
    # The handle is drawn as protrusion_1 (red) among the zones on the left panel, and as the
    # functional region (green) beside the rim's avoid region (red) on the right.
    left, right = (0.0, 0.5), (0.5, 1.0)
    assert pixels_of_colour(out, TAB_RGB["red"], columns=left) > 200
    assert pixels_of_colour(out, TAB_RGB["green"], columns=right) > 200 and pixels_of_colour(out, TAB_RGB["red"], columns=right) > 200
    printed = capsys.readouterr().out
    assert "top:" in printed and "bottom:" in printed


def test_unknown_object_is_named(ycb_dir, tmp_path, capsys):
    assert main(["--object", "999_teapot", "--objects-dir", str(ycb_dir), "--out", str(tmp_path / "x.png")]) == 2
    assert "999_teapot" in capsys.readouterr().err
