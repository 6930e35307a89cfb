"""Copy the Robotiq grippers' description files into the package (``sagp_batched/data/grippers``).

    python -m runners.import_grippers --source GRIPPER_MODELS --out sagp_batched/data/grippers

GRIPPER_MODELS holds robotiq_2f85/ and robotiq_2f140/, each with Menagerie's MJCF (mjcf/) and ros-industrial's
URDF expanded from its xacro (urdf/).

For each gripper: the MuJoCo Menagerie MJCF with its meshes and licence, its largest meshes made compact
(``_compact_mjcf``: what MuJoCo collides and weighs kept exactly, the meshes only drawn decimated); the URDF without its
visuals (the package simulates and checks collisions; it never renders the gripper's own meshes), its
COLLADA collision meshes turned into OBJ convex hulls of the vertices PyBullet reads from them (PyBullet
collides a link as the convex hull of its mesh, and ignores COLLADA's ``up_axis``, which other readers
honour), in metres. The package reads only the result.
"""
from __future__ import annotations

import argparse
import shutil
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import mujoco
import numpy as np
import pybullet
import trimesh

from sagp_batched.description_files import read_urdf_document, write_collision_urdf

# An MJCF mesh file larger than this is made compact: the Menagerie's body meshes (1-1.7 MB of STL each)
# were most of the package's gripper data.
COMPACT_MESH_BYTES = 300_000
# Faces a compacted mesh is drawn with: the gripper's pictures show its outline, not its fillets.
DRAWN_MESH_FACES = 4000
# Package name -> (source folder, URDF file, MJCF file).
GRIPPERS = {
    "robotiq_2f85": ("robotiq_2f85", "robotiq_2f85.urdf", "2f85.xml"),
    "robotiq_2f140": ("robotiq_2f140", "robotiq_2f140.urdf", "2f140.xml"),
}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--source", type=Path, required=True, help="folder holding robotiq_2f85/ and robotiq_2f140/ (mjcf/, urdf/)")
    parser.add_argument("--out", type=Path, required=True, help="the package's data/grippers folder")
    return parser


def _pybullet_collision_meshes(urdf_path: Path) -> dict[str, np.ndarray]:
    """Per COLLADA collision file the URDF names, the (V, 3) vertices PyBullet reads from it, scaled, in metres, link frame."""
    client = pybullet.connect(pybullet.DIRECT)
    try:
        body = pybullet.loadURDF(str(urdf_path), physicsClientId=client)
        meshes = {}
        for link in range(-1, pybullet.getNumJoints(body, physicsClientId=client)):
            for shape in pybullet.getCollisionShapeData(body, link, physicsClientId=client):
                filename = shape[4].decode()
                if filename.lower().endswith(".dae"):
                    _, vertices = pybullet.getMeshData(body, link, physicsClientId=client)
                    # PyBullet keeps a link's shapes in its inertial frame; the URDF writes them in the link frame.
                    position, quat = pybullet.getDynamicsInfo(body, link, physicsClientId=client)[3:5]
                    rotation = np.asarray(pybullet.getMatrixFromQuaternion(quat)).reshape(3, 3)
                    meshes[filename] = np.asarray(vertices, dtype=np.float64) @ rotation.T + position
        return meshes
    finally:
        pybullet.disconnect(client)


def _compact_mjcf(source_mjcf: Path, mjcf: Path) -> None:
    """The copied ``mjcf``'s meshes over ``COMPACT_MESH_BYTES`` made compact without changing its physics:
    its collision geoms take the mesh's convex hull (MuJoCo collides a mesh as its hull), its drawn geoms a
    decimated copy, and a body whose mass MuJoCo derived from such a mesh states that mass and inertia,
    as ``source_mjcf`` compiles them."""
    from sagp_batched._open3d import o3d

    tree = ET.parse(mjcf, parser=ET.XMLParser(target=ET.TreeBuilder(insert_comments=True)))
    root, assets = tree.getroot(), mjcf.parent / "assets"
    compacted = {}
    for asset in root.iter("asset"):
        for mesh in list(asset.findall("mesh")):
            path = assets / mesh.get("file")
            if path.stat().st_size <= COMPACT_MESH_BYTES:
                continue
            name = mesh.get("name", path.stem)
            trimesh.load(path, force="mesh").convex_hull.export(assets / f"{path.stem}_hull.stl")
            hull = ET.Element("mesh", {**mesh.attrib, "name": f"{name}_hull", "file": f"{path.stem}_hull.stl"})
            hull.tail = mesh.tail
            asset.insert(list(asset).index(mesh) + 1, hull)
            drawn = o3d.io.read_triangle_mesh(str(path)).simplify_quadric_decimation(DRAWN_MESH_FACES)
            drawn.compute_triangle_normals()
            o3d.io.write_triangle_mesh(str(path), drawn)
            compacted[name] = f"{name}_hull"
    model = mujoco.MjModel.from_xml_path(str(source_mjcf))
    for body in root.iter("body"):
        geoms = [geom for geom in body.findall("geom") if geom.get("mesh") in compacted]
        for geom in geoms:
            if geom.get("class") != "visual":
                geom.set("mesh", compacted[geom.get("mesh")])
        if geoms and body.find("inertial") is None:
            index = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body.get("name"))
            fields = {"mass": model.body_mass, "pos": model.body_ipos, "quat": model.body_iquat, "diaginertia": model.body_inertia}
            inertial = ET.Element("inertial", {key: " ".join(repr(float(x)) for x in np.atleast_1d(values[index])) for key, values in fields.items()})
            inertial.tail = body.text
            body.insert(0, inertial)
    mjcf.write_text(ET.tostring(root, encoding="unicode").replace(" />", "/>") + "\n")


def import_gripper(source: Path, out: Path, urdf_name: str, mjcf_name: str) -> None:
    shutil.rmtree(out, ignore_errors=True)
    shutil.copytree(source / "mjcf", out / "mjcf", ignore=shutil.ignore_patterns("*.png", "scene.xml"))
    _compact_mjcf(source / "mjcf" / mjcf_name, out / "mjcf" / mjcf_name)
    urdf_dir = out / "urdf"
    (urdf_dir / "meshes").mkdir(parents=True)
    source_urdf = source / "urdf" / urdf_name
    renamed = {}
    converted = _pybullet_collision_meshes(source_urdf)
    meshes = {c.filename: c.scale for link in read_urdf_document(source_urdf).links for c in link.collisions if c.shape == "mesh"}
    for relative, scale in meshes.items():
        path = source / "urdf" / relative
        if path.suffix.lower() == ".dae":
            vertices = next(v for name, v in converted.items() if Path(name).resolve() == path.resolve())
            trimesh.Trimesh(vertices).convex_hull.export(urdf_dir / "meshes" / f"{path.stem}.obj")
            renamed[relative] = (f"meshes/{path.stem}.obj", (1.0, 1.0, 1.0))
        else:
            shutil.copy2(path, urdf_dir / "meshes" / path.name)
            renamed[relative] = (f"meshes/{path.name}", scale)
    for licence in (source / "urdf").glob("LICENSE*"):
        shutil.copy2(licence, urdf_dir / licence.name)
    write_collision_urdf(source_urdf, urdf_dir / urdf_name, renamed,
                         f"{urdf_name} (ros-industrial/robotiq, BSD) without visuals; COLLADA collision meshes as OBJ hulls in metres "
                         "(runners.import_grippers)")


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    for name, (folder, urdf_name, mjcf_name) in GRIPPERS.items():
        if not (args.source / folder / "urdf" / urdf_name).is_file():
            print(f"error: --source {args.source}: no {folder}/urdf/{urdf_name}", file=sys.stderr)
            return 2
        import_gripper(args.source / folder, args.out / name, urdf_name, mjcf_name)
        print(f"{name}: {args.out / name}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
