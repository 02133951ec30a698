"""Where a robot comes from: a shipped robot, a URDF path (and its loop sidecar), a
``robot.toml`` (or the folder holding one: its ``urdf`` or its ``[dh]`` table), or
example-robot-data.

A URDF path inside a folder whose ``robot.toml`` names that file (``urdf = "..."``) is that
robot: it brings the same settings (coordinate order, loop file, defaults) as when it is loaded
by name, so one robot has one coordinate order.

Loop sidecars beside ``<folder>/<name>.urdf``, first found wins: ``<name>.loops.yaml``,
``<name>.yaml``, ``robot.yaml`` (Gepetto's example-parallel-robots), also for a ``robot.toml``
naming the URDF without a ``loops`` key. A ``<name>.yaml`` or
``robot.yaml`` without the key ``closed_loop`` is not a loop declaration: it is skipped with a
warning.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

import pinocchio as pin

from stiffness.errors import (
    FileFormatError,
    MissingFileError,
    StiffnessError,
    UnknownRobotError,
    did_you_mean,
)
from stiffness.files import looks_like_path, read_toml
from stiffness.robot.dh import TOOL, build_dh_model, read_dh_table
from stiffness.robot.loops import LoopDeclaration, read_loop_declaration
from stiffness.robot.meshes import MissingMesh
from stiffness.robot.urdf import Mimic, mimic_tags, read_urdf, warn
from stiffness.units import finite_number

if TYPE_CHECKING:
    from example_robot_data.utils import RobotLoader


@dataclass
class RobotSource:
    """A robot's model as read, before loops, rewrites and base fixing.

    ``settings`` holds the ``robot.toml`` keys (empty for other sources) and ``_folder``, the
    folder relative loop paths are taken from; ``loop_file`` is the sidecar found (or None).
    ``visual_loader``, when given (``visual`` is then None), builds the visual geometry of
    ``model`` on demand: reading meshes is most of the loading time of example-robot-data
    robots (0.36 s of 0.37 s for the UR5), and only the viewer draws them.
    """

    name: str
    model: pin.Model
    visual: pin.GeometryModel | None
    settings: dict
    mimics: tuple[Mimic, ...] = ()
    missing_meshes: tuple[MissingMesh, ...] = ()
    loop_file: Path | None = None
    urdf: Path | None = None
    notes: list[str] = field(default_factory=list)
    all_mimics: tuple[Mimic, ...] = ()
    visual_loader: Callable[[], pin.GeometryModel | None] | None = None


def robots_directory() -> Path:
    """Folder of the shipped robots: the repository's ``robots/``, installed as package data.

    In order: ``$STIFFNESS_ROBOTS`` if set; the ``robots/`` folder of the source checkout this
    package runs from (``PYTHONPATH`` or an editable install: the checkout's own data, even if
    another copy of the package is installed); else the installed package data
    ``stiffness.robots`` (``robots/`` mapped into the wheel), read with :mod:`importlib.resources`.
    """
    env = os.environ.get("STIFFNESS_ROBOTS")
    if env:
        return Path(env)
    checkout = Path(__file__).resolve().parents[2]
    if (checkout / "pyproject.toml").is_file() and (checkout / "robots" / "__init__.py").is_file():
        return checkout / "robots"
    try:
        data = resources.files("stiffness.robots")
    except ModuleNotFoundError:
        data = None
    if not isinstance(data, Path) or not data.is_dir():
        raise StiffnessError(
            "the shipped robots are missing: this copy of stiffness has no robots/ package data "
            "(reinstall it with `pip install .`, or set STIFFNESS_ROBOTS to a robots/ folder)"
        )
    return data


def shipped_robots() -> list[str]:
    """Names of the robots shipped in ``robots/`` (folders holding a ``robot.toml``)."""
    root = robots_directory()
    return sorted(p.parent.name for p in root.glob("*/robot.toml"))


def example_robot_names() -> list[str]:
    """Names example-robot-data can load."""
    from example_robot_data import robots_loader

    return sorted(robots_loader.ROBOTS)


def find_loop_sidecar(urdf: Path) -> Path | None:
    """The loop declaration beside a URDF (see the module docstring), or None."""
    import yaml

    for candidate in (urdf.with_suffix(".loops.yaml"), urdf.with_suffix(".yaml"),
                      urdf.parent / "robot.yaml"):
        if not candidate.is_file():
            continue
        if candidate.name.endswith(".loops.yaml"):
            return candidate
        try:
            # not UTF-8 (a ROS config in Latin-1): read what can be; a loop declaration's
            # reader then names the bytes
            content = yaml.safe_load(candidate.read_bytes().decode("utf-8", "replace"))
        except yaml.YAMLError:
            return candidate  # let the loop reader report where the YAML is broken
        if isinstance(content, dict) and "closed_loop" in content:
            return candidate
        warn(f"{candidate}: not a loop declaration (no closed_loop key); ignored")
    return None


def _from_toml(folder: Path, name: str, toml: Path | None = None) -> RobotSource:
    """The robot of a ``robot.toml`` (``folder/robot.toml`` unless ``toml`` is given): its
    ``urdf`` or its ``[dh]`` table (:mod:`stiffness.robot.dh`)."""
    toml = folder / "robot.toml" if toml is None else toml
    settings = read_toml(toml, "robot file")
    check_settings(settings, toml)
    settings["_folder"], settings["_file"] = folder, toml
    if "dh" in settings:
        return _from_dh(toml, name, settings)
    if "urdf" not in settings:
        raise FileFormatError("names no robot: give urdf = \"<file>.urdf\" or a [dh] table "
                              "(docs/robot-files.md)", path=toml)
    urdf = folder / settings["urdf"]
    read = read_urdf(urdf)
    # without a loops key, the sidecar beside its URDF, as for the URDF's own path
    loop_file = folder / settings["loops"] if "loops" in settings else find_loop_sidecar(urdf)
    return RobotSource(name, read.model, read.visual, settings, read.mimics, read.missing_meshes,
                       loop_file, urdf, all_mimics=read.all_mimics)


#: Top-level keys of a ``robot.toml`` that hold text (docs/robot-files.md).
TEXT_KEYS = ("name", "urdf", "loops", "frame", "twist_order")
#: Keys that list names.
NAME_LIST_KEYS = ("compliant_joints", "coordinate_order")
#: Keys that list numbers (SI or their named unit), with the counts they take (None: any).
NUMBER_LIST_KEYS = {"target_offset_m": (3,), "k_theta_SI": None, "q_deg": None, "q_SI": None,
                    "rest_q_SI": None, "wrench_SI": (3, 6)}
#: Keys that hold tables.
TABLE_KEYS = ("dh", "controller", "workspace")
#: Keys of a robot's ``[workspace]`` table (read by :mod:`stiffness.calibration.poses`).
WORKSPACE_KEYS = ("angle_unit", "uniform", "choice", "linear", "avoid", "target_above_base")


def check_settings(settings: dict, toml: Path) -> None:
    """Refuse a ``robot.toml`` whose known top-level keys hold values of the wrong type (a
    number where names are listed, text where numbers are; a stiffness not positive) or an
    unknown key (top-level or of ``[workspace]``), in one line naming the key.

    Raises
    ------
    FileFormatError
        The first key of the wrong type.
    """
    def refuse(key: str, what: str) -> None:
        raise FileFormatError(f"{key} must be {what}, got {settings[key]!r:.60}", path=toml,
                              field=key)

    for key in TEXT_KEYS:
        if key in settings and not isinstance(settings[key], str):
            refuse(key, "text (a quoted string)")
    for key in NAME_LIST_KEYS:
        value = settings.get(key)
        if key in settings and not (isinstance(value, list)
                                    and all(isinstance(v, str) for v in value)):
            refuse(key, "a list of names")
    for key, counts in NUMBER_LIST_KEYS.items():
        value = settings.get(key)
        if key in settings and not (isinstance(value, list) and all(map(finite_number, value))
                                    and (counts is None or len(value) in counts)):
            size = "" if counts is None else " or ".join(map(str, counts)) + " "
            refuse(key, f"a list of {size}finite numbers")
    if not all(v > 0 for v in settings.get("k_theta_SI", ())):
        refuse("k_theta_SI", "positive stiffnesses, one per compliant joint, N.m/rad (N/m "
               "prismatic)")
    for key in TABLE_KEYS:
        if key in settings and not isinstance(settings[key], dict):
            refuse(key, f"a table ([{key}])")
    known = sorted({*TEXT_KEYS, *NAME_LIST_KEYS, *NUMBER_LIST_KEYS, *TABLE_KEYS})
    for key in settings:
        if key not in known:
            raise FileFormatError(f"unknown key {key!r}; {did_you_mean(key, known)} "
                                  "(docs/robot-files.md)", path=toml, field=key)
    for key in settings.get("workspace", {}):
        if key not in WORKSPACE_KEYS:
            raise FileFormatError(f"unknown key {key!r}; {did_you_mean(key, WORKSPACE_KEYS)} "
                                  "(docs/design.md)", path=toml, field=f"[workspace].{key}")


def check_counts(settings: dict, coordinates: Sequence[str], springs: Sequence[str]) -> dict:
    """Refuse a robot file's defaults of the wrong length, naming the file and the key:
    ``q_deg``/``q_SI`` (one per coordinate), ``k_theta_SI``/``rest_q_SI`` (one per compliant
    joint of the file, ``springs``); return the settings, their ``compliant_joints`` the
    ``springs`` the per-spring keys were counted against when the file gives those keys alone
    (a robot.toml beside a URDF with fingers: its target's chain, not every coordinate).

    Raises
    ------
    FileFormatError
        The first key whose count differs.
    """
    for key, names, what in (("q_deg", coordinates, "coordinate"),
                             ("q_SI", coordinates, "coordinate"),
                             ("k_theta_SI", springs, "compliant joint"),
                             ("rest_q_SI", springs, "compliant joint")):
        if key in settings and len(settings[key]) != len(names):
            listed = ", ".join(names[:8]) + (", ..." if len(names) > 8 else "")
            raise FileFormatError(f"{key} has {len(settings[key])} values for "
                                  f"{len(names)} {what}s ({listed}); give one per {what}",
                                  path=settings.get("_file", "robot.toml"), field=key)
    if {"k_theta_SI", "rest_q_SI"} & {*settings}:
        return {"compliant_joints": list(springs), **settings}
    return settings


def _from_dh(toml: Path, name: str, settings: dict) -> RobotSource:
    """A robot described by the ``[dh]`` table of ``toml``; its target defaults to the tool."""
    if "urdf" in settings:
        raise FileFormatError("gives both urdf and a [dh] table: describe the robot by one of "
                              "them", path=toml, field="urdf")
    if "loops" in settings:
        raise FileFormatError("a [dh] robot is a tree: it has no loop file (write a "
                              "parallelogram as a [controller] coupling)", path=toml,
                              field="loops")
    model = build_dh_model(read_dh_table(settings["dh"], toml),
                           str(settings.get("name", name)), toml)
    settings.setdefault("frame", TOOL)
    return RobotSource(name, model, None, settings, notes=[f"DH table of {toml}"])


def _toml_naming(path: Path) -> bool:
    """Whether a ``robot.toml`` beside ``path`` declares it as its URDF."""
    toml = path.parent / "robot.toml"
    if not toml.is_file():
        return False
    try:
        declared = read_toml(toml, "robot file").get("urdf")
    except FileFormatError:
        return False
    return declared is not None and (path.parent / declared).resolve() == path.resolve()


def _loader(name: str) -> type[RobotLoader]:
    """example-robot-data's loader class of ``name``; its table gives "ur3" the UR5's loader
    (4.x: a UR5 read for a UR3, 0.425 m upper arm for 0.244 m), so "ur3" takes ``UR3Loader``."""
    from example_robot_data import robots_loader

    cls: type[RobotLoader] = robots_loader.ROBOTS[name]
    if name == "ur3" and cls is getattr(robots_loader, "UR5Loader", None):
        return robots_loader.UR3Loader  # type: ignore[no-any-return]
    return cls


def _from_example_robot_data(name: str) -> RobotSource:
    loader_class = _loader(name)
    plain = _plain_urdf_loader(loader_class)
    if plain is not None:  # the model now, the meshes when the viewer asks
        model, path, visual_loader = plain
        visual = None
    else:  # a loader of its own (it builds and edits the model itself): run it
        try:
            loader = loader_class()
        except (ImportError, ValueError, RuntimeError, OSError) as exc:
            why = str(exc).strip().splitlines()[0] if str(exc).strip() else repr(exc)
            fix = ("it is an SDF model, which stiffness cannot read: choose a robot described "
                   "by a URDF" if getattr(loader_class, "sdf_filename", None)
                   else "load its URDF file instead, or choose another robot")
            raise StiffnessError(f"example-robot-data cannot build {name!r} here "
                                 f"({type(exc).__name__}: {why}); {fix}") from exc
        model, visual, visual_loader = loader.robot.model, loader.robot.visual_model, None
        path = Path(getattr(loader, "df_path", ""))
    mimics: tuple[Mimic, ...] = ()
    tags: tuple[Mimic, ...] = ()
    if path.suffix.lower() == ".urdf" and path.is_file():
        tags = _mimic_tags(path)
        mimics = tuple(m for m in tags if model.existJointName(m.follower)
                       and model.existJointName(m.leader)
                       and model.joints[model.getJointId(m.follower)].nv == 1)
    posture = getattr(loader_class, "ref_posture", None)
    settings = {"reference_posture": posture} if posture and any(
        entry.key() == posture for entry in model.referenceConfigurations) else {}
    return RobotSource(name, model, visual, settings, mimics, (), None,
                       path if path.is_file() else None, all_mimics=tags,
                       visual_loader=visual_loader)


def _plain_urdf_loader(cls: type[RobotLoader]) -> tuple[pin.Model, Path, UrdfVisual] | None:
    """Model, URDF path and visual-geometry builder of an example-robot-data loader class
    that only reads a URDF (the library's own ``RobotLoader.__init__``, no SDF), without
    building its meshes; None for the loaders that build their model otherwise.

    The same steps as that ``__init__``, with the library's functions: its paths
    (``getModelPath`` on ``path/urdf_subpath/urdf_filename``, package folder
    ``model_path/../..``), Pinocchio's ``buildModelsFromUrdf`` for the model alone,
    ``readParamsFromSrdf`` (reference posture, rotor parameters) and the free-flyer limits of
    ``RobotLoader.addFreeFlyerJointLimits``; tests/test_robot_loading.py checks that the model
    equals the loader's.
    """
    from types import SimpleNamespace

    from example_robot_data.utils import RobotLoader, getModelPath, readParamsFromSrdf

    if cls.__init__ is not RobotLoader.__init__ or not cls.urdf_filename or cls.sdf_filename:
        return None
    relative = os.path.join(cls.path, cls.urdf_subpath, cls.urdf_filename)
    model_path = cls.model_path if cls.model_path is not None else getModelPath(relative)
    urdf = os.path.join(model_path, relative)
    package_dirs = [os.path.join(model_path, "../..")]
    root = pin.JointModelFreeFlyer() if cls.free_flyer else None
    model = pin.buildModelsFromUrdf(urdf, package_dirs=package_dirs, root_joint=root,
                                    geometry_types=[])[0]
    if cls.srdf_filename:
        readParamsFromSrdf(model, os.path.join(model_path, cls.path, cls.srdf_subpath,
                                               cls.srdf_filename),
                           False, cls.has_rotor_parameters, cls.ref_posture)
    if cls.free_flyer:
        RobotLoader.addFreeFlyerJointLimits(SimpleNamespace(robot=SimpleNamespace(model=model)))
    return model, Path(urdf), UrdfVisual(pin.Model(model), urdf, tuple(package_dirs))


@dataclass(frozen=True)
class UrdfVisual:
    """The visual geometry of a URDF for its model, read when called (picklable, so that a
    robot whose meshes were not read yet pickles small)."""

    model: pin.Model
    urdf: str
    package_dirs: tuple[str, ...]

    def __call__(self) -> object:
        """A copy of the geometry (its meshes shared: nothing here edits a mesh), read once
        per process for a URDF file as it is and a model with these frames (a UR5's 0.6 s, a
        Panda's 0.8 s of CPU each time, measured 2026-12-06)."""
        stat = os.stat(self.urdf)
        key = (self.urdf, stat.st_mtime_ns, stat.st_size, self.package_dirs,
               tuple(self.model.names), tuple(f.name for f in self.model.frames))
        if key not in _VISUALS:
            if len(_VISUALS) >= _VISUALS_KEPT:
                del _VISUALS[next(iter(_VISUALS))]  # the oldest
            _VISUALS[key] = pin.buildGeomFromUrdf(self.model, self.urdf,
                                                  pin.GeometryType.VISUAL,
                                                  package_dirs=list(self.package_dirs))
        return _VISUALS[key].copy()


#: The visual geometries :class:`UrdfVisual` read in this process, the newest last.
_VISUALS: dict[tuple, pin.GeometryModel] = {}
#: How many of them are kept (a robot's meshes hold 60-75 MB: UR5, UR10, Panda).
_VISUALS_KEPT = 4


def _mimic_tags(path: Path) -> tuple[Mimic, ...]:
    from lxml import etree

    return mimic_tags(etree.parse(str(path), etree.XMLParser(recover=True, huge_tree=True))
                      .getroot(), include_fixed=True)


def resolve_source(source: str | os.PathLike) -> RobotSource:
    """Read a shipped robot name, a URDF path (or a folder holding a ``robot.toml`` or one
    URDF) or an example-robot-data name; names are matched regardless of case.

    Raises
    ------
    StiffnessError
        Unknown name, missing or malformed file, a folder that holds no robot.
    """
    text = str(source)
    shipped = shipped_robots()
    if not text.strip():  # Path("") is the working folder: an unset $ROBOT took its URDF
        raise UnknownRobotError(f"the robot is an empty name {text!r}; give a shipped robot "
                                f"({', '.join(shipped)}), an example-robot-data name, a URDF "
                                "path or a robot.toml", name=text, choices=shipped)
    if text in shipped:
        return _from_toml(robots_directory() / text, text)
    path = Path(text)
    try:
        path.exists()
    except OSError as exc:  # a name the file system cannot even look up (too long)
        raise UnknownRobotError(f"robot {text[:60]!r}... cannot be a file ({exc.strerror}) and "
                                "is not a robot name; give a shipped robot, a URDF path or an "
                                "example-robot-data name", name=text,
                                choices=shipped) from None
    if path.suffix.lower() == ".toml" or (path.is_dir() and (path / "robot.toml").is_file()):
        toml = path if path.suffix.lower() == ".toml" else path / "robot.toml"
        if not toml.is_file():
            raise MissingFileError(f"robot file {toml} does not exist; give the path of a "
                                   "robot.toml", path=toml)
        return _from_toml(toml.parent, text, toml)
    # a folder or file named like an example-robot-data robot (a campaign folder "ur5") is
    # that robot unless it holds a robot or is written as a path
    named = not looks_like_path(text) and text.lower() in {
        n.lower() for n in example_robot_names()}
    if path.is_dir() and not (named and not any(path.glob("*.urdf"))):
        return _from_folder(path)
    if (path.suffix.lower() in (".urdf", ".xml") or path.exists()) and not named:
        if path.is_file() and _toml_naming(path):
            found = _from_toml(path.parent, text)
            found.notes.append(f"settings from {path.parent / 'robot.toml'}")
            return found
        read = read_urdf(path)
        return RobotSource(text, read.model, read.visual, {"_folder": path.parent}, read.mimics,
                           read.missing_meshes, find_loop_sidecar(path), path,
                           all_mimics=read.all_mimics)
    erd_names = example_robot_names()
    if text in erd_names:
        return _from_example_robot_data(text)
    same = [n for n in shipped + erd_names if n.lower() == text.lower()]
    if len(same) == 1:
        return resolve_source(same[0])
    raise UnknownRobotError(
        f"unknown robot {text!r}: not a shipped robot ({', '.join(shipped)}), not an existing "
        f"URDF file or folder, and not an example-robot-data name; "
        f"{_closest_names(text, shipped + erd_names)}", name=text, choices=shipped + erd_names)


def _closest_names(text: str, names: list[str]) -> str:
    """``did you mean ...?`` with the few names closest to ``text`` (case ignored), or where
    the full list is."""
    import difflib

    lower = {n.lower(): n for n in names}
    close = [lower[n] for n in difflib.get_close_matches(text.lower(), list(lower), n=4,
                                                         cutoff=0.5)]
    close += [n for n in names if text.lower() in n.lower() and n not in close][:4 - len(close)]
    where = (f"{len(names)} names in all, example-robot-data's in "
             "example_robot_data.robots_loader.ROBOTS")
    return f"did you mean {', '.join(close)}? ({where})" if close else where


def _from_folder(folder: Path) -> RobotSource:
    """The robot of a folder without a ``robot.toml``: its one URDF file."""
    urdfs = sorted(p for p in folder.iterdir() if p.suffix.lower() == ".urdf" and p.is_file())
    if len(urdfs) == 1:
        return resolve_source(urdfs[0])
    held = (f"{len(urdfs)} URDF files ({', '.join(p.name for p in urdfs[:5])})" if urdfs
            else "no robot.toml and no URDF file")
    raise StiffnessError(f"{folder} is a folder holding {held}: give the path of one URDF file, "
                         "or a folder with a robot.toml or a single URDF")


#: Marks of loop-closure frame names in the tools that write closed-loop URDFs: Gepetto's
#: example-parallel-robots (``closedloop<N>_A`` / ``_B``, formerly ``fermeture<N>``) and
#: onshape-to-robot (``closing_``).
LOOP_FRAME_MARKS = ("closedloop", "fermeture", "closing_")


def loop_declaration(source: RobotSource, loops: str | os.PathLike | None
                     ) -> LoopDeclaration | None:
    """The loop declaration to read: ``loops``, the shipped one, or the sidecar found; with
    none, a warning if the URDF's frames are named as loop-closure frames
    (:data:`LOOP_FRAME_MARKS`): its loops would otherwise be dropped in silence."""
    marked = [f.name for f in source.model.frames if f.type in (pin.BODY, pin.OP_FRAME)
              and any(mark in f.name.lower() for mark in LOOP_FRAME_MARKS)]
    path = Path(loops) if loops is not None else source.loop_file
    if path is not None:
        declaration = read_loop_declaration(path)
        paired = {name for p in declaration.pairs for name in (p.frame_a, p.frame_b)}
        left = [name for name in marked if name not in paired]
        if left and source.urdf is not None:
            warn(f"{path}: {len(left)} frames of {source.urdf.name} named as loop-closure "
                 f"frames are in no closed_loop pair ({', '.join(left[:4])}"
                 f"{' ...' if len(left) > 4 else ''}): their loops are left open; add each "
                 "pair to closed_loop with its type (docs/robot-files.md)")
        return declaration
    if marked and source.urdf is not None:
        warn(f"{source.urdf}: {len(marked)} frames are named as loop-closure frames (e.g. "
             f"{marked[0]!r}) but no loop declaration is beside it: loaded as an open tree; "
             f"declare the loops in {source.urdf.parent / 'robot.yaml'} or give --loops FILE "
             "(docs/robot-files.md)")
    return None
