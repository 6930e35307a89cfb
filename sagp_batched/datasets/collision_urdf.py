"""URDFs for worlds that simulate and never render: a robot's hand alone, and an object without its
visual meshes, each with absolute mesh paths and written once per content into a cache folder."""
from __future__ import annotations

import copy
import hashlib
import os
import tempfile
import xml.etree.ElementTree as ElementTree
from pathlib import Path

from ..robot.description import RobotDescription


def floating_hand_urdf(robot: RobotDescription, cache_dir: str | Path) -> Path:
    """A URDF of ``robot``'s hand alone: the hand link and every link below it (fingers on their
    prismatic joints, the grasp target), collision geometry only, mesh paths made absolute so it
    loads from anywhere. Written once per content into ``cache_dir`` (named by its hash)."""
    tree = ElementTree.parse(robot.urdf_path)
    source = tree.getroot()
    joints = [element for element in source if element.tag == "joint"]
    keep = {robot.hand_link}
    grown = True
    while grown:
        below = {joint.find("child").get("link") for joint in joints if joint.find("parent").get("link") in keep}
        grown = not below <= keep
        keep |= below
    hand = ElementTree.Element("robot", name=f"{robot.name}_floating_hand")
    for element in source:
        if element.tag == "link" and element.get("name") in keep:
            hand.append(_collision_only(element, robot.urdf_path.parent))
        elif element.tag == "joint" and element.find("parent").get("link") in keep:
            hand.append(element)
    return _cached_urdf(ElementTree.tostring(hand, encoding="unicode"), cache_dir, f"{robot.name}_hand")


def collision_only_urdf(urdf_path: str | Path, cache_dir: str | Path) -> Path:
    """``urdf_path`` without its visual geometry, mesh paths made absolute, cached in ``cache_dir``.

    A world built for every grasp would otherwise parse the object's visual mesh each time (often
    far larger than its convex hulls) for a simulation that never renders."""
    urdf_path = Path(urdf_path)
    root = ElementTree.parse(urdf_path).getroot()
    for position, element in enumerate(list(root)):
        if element.tag == "link":
            root[position] = _collision_only(element, urdf_path.parent)
    return _cached_urdf(ElementTree.tostring(root, encoding="unicode"), cache_dir, root.get("name", urdf_path.stem))


def _collision_only(link: ElementTree.Element, base: Path) -> ElementTree.Element:
    """A copy of a URDF link without visuals, its mesh file names made absolute (from ``base``)."""
    link = copy.deepcopy(link)
    for visual in link.findall("visual"):
        link.remove(visual)
    for mesh in link.iter("mesh"):
        mesh.set("filename", str(base / mesh.get("filename").removeprefix("package://")))
    return link


def _cached_urdf(text: str, cache_dir: str | Path, stem: str) -> Path:
    folder = Path(cache_dir).expanduser()
    path = folder / f"{stem}_{hashlib.sha256(text.encode()).hexdigest()[:16]}.urdf"
    if not path.is_file():
        folder.mkdir(parents=True, exist_ok=True)
        # Written beside its final name and moved there whole: concurrent labellers never read half a file.
        handle, partial = tempfile.mkstemp(dir=folder, suffix=".urdf.partial")
        with os.fdopen(handle, "w") as stream:
            stream.write(text)
        os.replace(partial, path)
    return path
