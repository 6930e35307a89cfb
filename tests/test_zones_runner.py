"""``python -m runners.zones``: a YCB object placed, seen by the three cameras, and drawn by zone."""
from __future__ import annotations

from PIL import Image

from sagp_batched_runners.zones import main


def test_zone_picture_of_a_placed_mug(ycb_dir, tmp_path, capsys):
    out = tmp_path / "mug_zones.png"
    assert main(["--object", "025_mug", "--objects-dir", str(ycb_dir), "--out", str(out), "--trial", "1"]) == 0
    with Image.open(out) as image:
        assert image.size[0] > 500
    printed = capsys.readouterr().out
    assert "top:" in printed and "bottom:" in printed


def test_unknown_object_is_named(ycb_dir, tmp_path, capsys):
    assert main(["--object", "999_teapot", "--objects-dir", str(ycb_dir), "--out", str(tmp_path / "x.png")]) == 2
    assert "999_teapot" in capsys.readouterr().err
