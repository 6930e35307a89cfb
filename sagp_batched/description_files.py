"""The one reader of description files (URDF, MJCF): robots', grippers' and objects'.

Every fact the package takes from a robot's or a gripper's URDF (its links' collision geometry, its joints, their mimic
rules, the kinematic chain) is read here, with pytorch-kinematics' URDF parser and chains; an MJCF is read with MuJoCo's
own parser. A URDF that PyBullet loads as a body (an object, the floating hand) is read as PyBullet reads it
(``read_urdf_document``): with its ``<contact>`` friction, which pytorch-kinematics' parser drops, and the file's own
errors, which callers report; PyBullet's own reading of a URDF goes through ``load_urdf``. Modules that need such a fact
ask this module, so a file's quirks (PyBullet-only tags, mesh units, mesh-name prefixes, mimic joints) are handled once.
"""
from __future__ import annotations

import copy
import functools
import logging
import xml.etree.ElementTree as ElementTree
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

import numpy as np

log = logging.getLogger(__name__)


def _quietly(parse: Callable[[str], Any], urdf_path: Path) -> Any:
    """``parse(text)`` of a URDF with pytorch-kinematics' parser, its reports sent to the debug log: panda.urdf's
    PyBullet-only tags (``<contact>``, collision ``<material>``), reported once per link, change nothing it reads."""
    from pytorch_kinematics.urdf_parser_py.xml_reflection import core

    previous, core.on_error = core.on_error, lambda message: log.debug("%s: %s", urdf_path.name, message)
    try:
        return parse(urdf_path.read_text())
    finally:
        core.on_error = previous


@functools.lru_cache(maxsize=16)
def read_urdf(urdf_path: Path):
    """The parsed URDF (pytorch-kinematics' ``urdf_parser_py`` model: ``links``, ``joints``)."""
    from pytorch_kinematics.urdf_parser_py.urdf import URDF

    return _quietly(URDF.from_xml_string, Path(urdf_path))


def chain(urdf_path: Path):
    """The whole kinematic tree of ``urdf_path`` as a pytorch-kinematics chain (float32)."""
    import pytorch_kinematics as pk

    return _quietly(pk.build_chain_from_urdf, Path(urdf_path))


def serial_chain(urdf_path: Path, end_link: str):
    """The serial chain of ``urdf_path`` from its root to ``end_link`` (pytorch-kinematics)."""
    import pytorch_kinematics as pk

    return _quietly(lambda text: pk.build_serial_chain_from_urdf(text, end_link), Path(urdf_path))


@dataclass(frozen=True)
class Mimic:
    """A joint that follows another: value = multiplier * leader + offset."""

    leader: str
    multiplier: float
    offset: float


def mimics(urdf_path: Path) -> dict[str, Mimic]:
    """Per mimic joint of the URDF, the joint it follows and how."""
    return {joint.name: Mimic(joint.mimic.joint, float(joint.mimic.multiplier if joint.mimic.multiplier is not None else 1.0),
                              float(joint.mimic.offset or 0.0))
            for joint in read_urdf(Path(urdf_path)).joints if joint.mimic is not None}


def joint_limits(urdf_path: Path, joint_name: str) -> tuple[float, float]:
    """(lower, upper) of a joint of the URDF."""
    joint = next((joint for joint in read_urdf(Path(urdf_path)).joints if joint.name == joint_name), None)
    if joint is None or joint.limit is None:
        raise ValueError(f"{Path(urdf_path).name}: no joint '{joint_name}' with limits")
    return float(joint.limit.lower), float(joint.limit.upper)


def link_poses(urdf_path: Path, joint_values: dict[str, float]) -> dict[str, np.ndarray]:
    """(4, 4) float64 pose of every link in the URDF's root frame, with the joints at ``joint_values``
    (others at 0) and every mimic joint where its leader puts it: pytorch-kinematics' forward kinematics,
    which leaves mimic rules to its caller."""
    import torch

    urdf_path = Path(urdf_path)
    tree = chain(urdf_path).to(dtype=torch.float64)
    values = dict(joint_values)
    for name, rule in mimics(urdf_path).items():
        values[name] = rule.multiplier * values.get(rule.leader, 0.0) + rule.offset
    names = tree.get_joint_parameter_names()
    joints = torch.tensor([[values.get(name, 0.0) for name in names]], dtype=torch.float64)
    return {name: pose.get_matrix()[0].numpy() for name, pose in tree.forward_kinematics(joints).items()}


def box_corners(size: tuple[float, ...]) -> np.ndarray:
    """(8, 3) the corners of a URDF ``<box>`` of ``size`` about its centre."""
    return np.array(np.meshgrid([-0.5, 0.5], [-0.5, 0.5], [-0.5, 0.5], indexing="ij")).reshape(3, -1).T * np.asarray(size, dtype=np.float64)


def _obj_vertices(path: Path) -> np.ndarray:
    """(V, 3) vertex positions of a Wavefront OBJ file, read directly: trimesh would merge and reorder them."""
    rows = [line.split()[1:4] for line in path.read_text().splitlines() if line.startswith("v ")]
    if not rows:
        raise ValueError(f"{path} holds no vertices")
    return np.asarray(rows, dtype=np.float64)


def _mesh_vertices(path: Path) -> np.ndarray:
    if path.suffix.lower() == ".obj":
        return _obj_vertices(path)
    import trimesh

    return np.asarray(trimesh.load(path, force="mesh").vertices, dtype=np.float64)


@functools.lru_cache(maxsize=8)
def link_hulls(urdf_path: Path, links: tuple[str, ...]) -> dict[str, np.ndarray]:
    """Per link, the vertices (V, 3) of the convex hull of its collision geometry (meshes and boxes), in
    the link's own frame: what PyBullet collides the link as."""
    from scipy.spatial import ConvexHull

    urdf_path = Path(urdf_path)
    by_name = {link.name: link for link in read_urdf_document(urdf_path).links}
    hulls = {}
    for name in links:
        if name not in by_name or not by_name[name].collisions:
            raise ValueError(f"{urdf_path.name}: link '{name}' has no collision geometry")
        link_vertices = []
        for collision in by_name[name].collisions:
            if collision.shape == "mesh":
                vertices = _mesh_vertices(urdf_file_path(urdf_path, collision.filename)) * np.asarray(collision.scale)
            elif collision.shape == "box":
                vertices = box_corners(collision.size)
            else:
                raise ValueError(f"{urdf_path.name}: link '{name}' collides as a {collision.shape or 'nothing'}; only meshes and boxes are read")
            link_vertices.append(vertices @ collision.origin[:3, :3].T + collision.origin[:3, 3])
        vertices = np.concatenate(link_vertices)
        hulls[name] = vertices[ConvexHull(vertices).vertices]
    return hulls


def read_mjcf(mjcf_path: Path):
    """The MJCF as a MuJoCo model specification (``mujoco.MjSpec``), its mesh folder made absolute."""
    import mujoco

    spec = mujoco.MjSpec.from_file(str(mjcf_path))
    spec.meshdir = str((Path(mjcf_path).parent / (spec.meshdir or "")).resolve())
    return spec


@functools.lru_cache(maxsize=8)
def mjcf_body_pose(mjcf_path: Path, body: str) -> np.ndarray:
    """(4, 4) pose of the MJCF's ``body`` in the model's root (world) frame, every joint at its reference value."""
    import mujoco

    model = read_mjcf(mjcf_path).compile()
    data = mujoco.MjData(model)
    mujoco.mj_kinematics(model, data)
    index = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, body)
    if index < 0:
        raise ValueError(f"{Path(mjcf_path).name}: no body '{body}'")
    pose = np.eye(4)
    pose[:3, :3], pose[:3, 3] = data.xmat[index].reshape(3, 3), data.xpos[index]
    return pose


def write_collision_urdf(source: Path, destination: Path, meshes: dict[str, tuple[str, tuple[float, float, float]]],
                         header: str) -> None:
    """``source`` without its visuals, written to ``destination`` behind the comment ``header``; each collision
    mesh whose file name is a key of ``meshes`` renamed to its (file name, scale)."""
    root = ElementTree.parse(source).getroot()
    root[:] = [_collision_only(element, lambda mesh: meshes.get(mesh.get("filename"))) if element.tag == "link" else element for element in root]
    ElementTree.indent(root)
    destination.write_text(f"<?xml version=\"1.0\"?>\n<!-- {header} -->\n{ElementTree.tostring(root, encoding='unicode')}\n")


def _collision_only(link: ElementTree.Element, renamed: Callable[[ElementTree.Element], tuple[str, tuple[float, ...]] | None]) -> ElementTree.Element:
    """A copy of a URDF link without visuals, each mesh whose ``renamed(mesh)`` is a (file name, scale) renamed to it."""
    link = copy.deepcopy(link)
    for visual in link.findall("visual"):
        link.remove(visual)
    for mesh in link.iter("mesh"):
        if (new := renamed(mesh)) is not None:
            mesh.set("filename", new[0])
            if new[1] is not None:
                mesh.set("scale", " ".join(f"{v:g}" for v in new[1]))
    return link


def _absolute(base: Path) -> Callable[[ElementTree.Element], tuple[str, None]]:
    """Mesh file names made absolute from ``base``, so a URDF written elsewhere loads from anywhere."""
    return lambda mesh: (str(base / mesh.get("filename").removeprefix("package://")), None)


def collision_only_urdf_text(urdf_path: Path) -> str:
    """``urdf_path`` without its visual geometry, its mesh file names made absolute so it loads from anywhere."""
    root = ElementTree.parse(urdf_path).getroot()
    root[:] = [_collision_only(element, _absolute(Path(urdf_path).parent)) if element.tag == "link" else element for element in root]
    return ElementTree.tostring(root, encoding="unicode")


def subtree_urdf_text(urdf_path: Path, root_link: str, robot_name: str, collision_meshes: dict[tuple[str, int], str] | None = None) -> str:
    """A URDF named ``robot_name`` of ``root_link``, the links below it and the joints between them, collision
    geometry only, its mesh file names made absolute so it loads from anywhere; each collision that
    ``collision_meshes`` names by (link, its index among the link's collisions) made that mesh file, unscaled."""
    source, keep, grown = ElementTree.parse(urdf_path).getroot(), {root_link}, True
    joints = source.findall("joint")
    while grown:
        below = {joint.find("child").get("link") for joint in joints if joint.find("parent").get("link") in keep}
        grown, keep = not below <= keep, keep | below
    subtree = ElementTree.Element("robot", name=robot_name)
    for element in source:
        if element.tag == "link" and element.get("name") in keep:
            subtree.append(link := _collision_only(element, _absolute(Path(urdf_path).parent)))
            for index, collision in enumerate(link.findall("collision")):
                if (filename := (collision_meshes or {}).get((link.get("name"), index))) is not None:
                    collision.find("geometry")[:] = [ElementTree.Element("mesh", filename=filename)]
        elif element.tag == "joint" and element.find("parent").get("link") in keep:
            subtree.append(element)
    return ElementTree.tostring(subtree, encoding="unicode")


# -- URDFs that PyBullet loads as bodies -------------------------------------------------------------------
# ElementTree's error for a file that is not XML, under a name its callers catch without the parser.
UrdfSyntaxError = ElementTree.ParseError
# PyBullet's surface of a link whose URDF gives no ``<contact>``: lateral friction 0.5, no spinning or rolling friction.
DEFAULT_FRICTION = (0.5, 0.0, 0.0)
# Per primitive, the attributes that size it, in the order ``UrdfGeometry.size`` holds them.
_PRIMITIVE_SIZES = {"box": ("size",), "cylinder": ("radius", "length"), "sphere": ("radius",)}


def _floats(text: str | None, default: tuple[float, ...]) -> tuple[float, ...]:
    return tuple(float(v) for v in text.split()) if text else default


def urdf_origin(element: ElementTree.Element | None) -> np.ndarray:
    """(4, 4) a URDF ``<origin>``: fixed-axis roll, pitch, yaw, then the translation; identity where absent."""
    from scipy.spatial.transform import Rotation

    matrix = np.eye(4)
    if element is not None:
        matrix[:3, :3] = Rotation.from_euler("xyz", _floats(element.get("rpy"), (0.0, 0.0, 0.0))).as_matrix()  # URDF: fixed-axis roll, pitch, yaw
        matrix[:3, 3] = _floats(element.get("xyz"), (0.0, 0.0, 0.0))
    return matrix


def urdf_file_path(urdf_path: Path, filename: str) -> Path:
    """A file a URDF names, where PyBullet finds it: relative to the URDF's folder, a ``package://`` or ``file://`` prefix dropped."""
    return Path(urdf_path).parent / filename.removeprefix("package://").removeprefix("file://")


@dataclass(frozen=True)
class UrdfGeometry:
    """One ``<visual>`` or ``<collision>`` of a link: its shape and where it sits in the link."""

    shape: str  # the element inside <geometry>: "mesh", "box", "cylinder", "sphere" or another; "" where it holds none
    filename: str  # a mesh's file name as written ("" where it names none)
    scale: tuple[float, ...]  # a mesh's per-axis scale; (1, 1, 1) where absent, one value standing for all three
    size: tuple[float, ...]  # a primitive's: box (x, y, z), cylinder (radius, length), sphere (radius,)
    origin: np.ndarray  # (4, 4) geometry frame -> link frame


@dataclass(frozen=True)
class LinkInertial:
    """A link's ``<inertial>``: mass (kg; 0 where it gives none), its frame in the link frame (4, 4: the centre
    of mass and the axes the tensor is written in) and the (3, 3) tensor about the centre of mass (kg m^2)."""

    mass_kg: float
    frame_in_link: np.ndarray
    tensor_kg_m2: np.ndarray


class UrdfLink:
    """A link of a URDF, each part read when asked for: a malformed part fails only the caller that needs it."""

    def __init__(self, link: ElementTree.Element, root: ElementTree.Element):
        self._link, self._root = link, root
        self.name: str = link.get("name", "")

    @property
    def visuals(self) -> tuple[UrdfGeometry, ...]:
        return tuple(urdf_geometry(visual) for visual in self._link.findall("visual"))

    @property
    def collisions(self) -> tuple[UrdfGeometry, ...]:
        return tuple(urdf_geometry(collision) for collision in self._link.findall("collision"))

    @property
    def inertial(self) -> LinkInertial | None:
        """The link's ``<inertial>``; None where it has none."""
        inertial = self._link.find("inertial")
        if inertial is None:
            return None
        mass, terms = inertial.find("mass"), inertial.find("inertia")
        value = {key: float(terms.get(key, 0.0)) if terms is not None else 0.0 for key in ("ixx", "ixy", "ixz", "iyy", "iyz", "izz")}
        tensor = np.array([[value["ixx"], value["ixy"], value["ixz"]], [value["ixy"], value["iyy"], value["iyz"]], [value["ixz"], value["iyz"], value["izz"]]])
        return LinkInertial(float(mass.get("value")) if mass is not None else 0.0, urdf_origin(inertial.find("origin")), tensor)

    @property
    def body_inertial(self) -> LinkInertial | None:
        """The inertial of a body: None where the link has none or a massless one (a frame, not a body)."""
        inertial = self.inertial
        return inertial if inertial is not None and inertial.mass_kg > 0.0 else None

    @property
    def friction(self) -> tuple[float, float, float]:
        """(lateral, spinning, rolling) friction of the link's ``<contact>``, PyBullet's default for any it leaves out."""
        contact = self._link.find("contact")
        given = [contact.find(name) if contact is not None else None for name in ("lateral_friction", "spinning_friction", "rolling_friction")]
        lateral, spinning, rolling = (float(element.get("value")) if element is not None else default for element, default in zip(given, DEFAULT_FRICTION))
        return lateral, spinning, rolling

    @property
    def rgba(self) -> tuple[float, float, float, float] | None:
        """The colour of the first material its visuals name; None where they name none or it has no four values."""
        material = self._link.find("visual/material")
        if material is None:
            return None
        color = material.find("color")
        if color is None:  # a material defined once at the robot level and named here
            named = [m for m in self._root.findall("material") if m.get("name") == material.get("name")]
            color = named[0].find("color") if named else None
        rgba = _floats(color.get("rgba") if color is not None else None, ())
        return rgba if len(rgba) == 4 else None  # type: ignore[return-value]


@dataclass(frozen=True)
class UrdfJoint:
    name: str
    kind: str  # the joint's type: "fixed", "prismatic", "revolute", ...
    parent: str
    child: str
    origin: np.ndarray  # (4, 4) child link frame -> parent link frame at joint value 0
    axis: tuple[float, ...]  # (1, 0, 0) where absent
    limits: tuple[float, float] | None  # (lower, upper) of its <limit>, None where it has none


class UrdfDocument:
    """A URDF as PyBullet reads it, its links and joints (in the file's order) read when asked for."""

    def __init__(self, root: ElementTree.Element):
        self._root = root
        self.root_element: str = root.tag  # "robot" for a URDF
        self.name: str | None = root.get("name")
        # Every <mesh>'s (visual and collision) and <texture>'s file name as written, in file order; "" where one names none.
        self.mesh_files = tuple(mesh.get("filename") or "" for mesh in root.iter("mesh"))
        self.texture_files = tuple(texture.get("filename") or "" for texture in root.iter("texture"))

    @property
    def links(self) -> tuple[UrdfLink, ...]:
        return tuple(UrdfLink(link, self._root) for link in self._root.findall("link"))

    @property
    def joints(self) -> tuple[UrdfJoint, ...]:
        return tuple(_joint(joint) for joint in self._root.findall("joint"))


def urdf_geometry(element: ElementTree.Element) -> UrdfGeometry:
    """A ``<visual>`` or ``<collision>`` element read: its shape, sizes and origin."""
    geometry = element.find("geometry")
    shape = geometry[0] if geometry is not None and len(geometry) else None
    if shape is None:
        return UrdfGeometry("", "", (1.0, 1.0, 1.0), (), urdf_origin(element.find("origin")))
    scale = _floats(shape.get("scale"), (1.0, 1.0, 1.0))
    size = tuple(v for name in _PRIMITIVE_SIZES.get(shape.tag, ()) for v in _floats(shape.get(name), ()))
    return UrdfGeometry(shape.tag, shape.get("filename", ""), scale * 3 if len(scale) == 1 else scale, size,
                        urdf_origin(element.find("origin")))


def _joint(joint: ElementTree.Element) -> UrdfJoint:
    limit, axis = joint.find("limit"), joint.find("axis")
    return UrdfJoint(joint.get("name", ""), joint.get("type", ""), joint.find("parent").get("link"), joint.find("child").get("link"),
                     urdf_origin(joint.find("origin")), _floats(axis.get("xyz") if axis is not None else None, (1.0, 0.0, 0.0)),
                     (float(limit.get("lower", 0.0)), float(limit.get("upper", 0.0))) if limit is not None else None)


def read_urdf_document(urdf_path: Path) -> UrdfDocument:
    """The URDF at ``urdf_path``, any root element. Raises ``UrdfSyntaxError`` where the file is not XML and
    ``OSError`` where it cannot be read."""
    return UrdfDocument(ElementTree.parse(urdf_path).getroot())


def load_urdf(client: int, urdf_path: Path, **options: Any) -> int:
    """PyBullet's body of ``urdf_path`` in ``client``; ``options`` are ``pybullet.loadURDF``'s (``basePosition``,
    ``baseOrientation``, ``useFixedBase``, ``flags``). Raises ``pybullet.error`` where PyBullet cannot load it."""
    import pybullet

    return pybullet.loadURDF(str(urdf_path), physicsClientId=client, **options)
