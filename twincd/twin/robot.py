"""Robot models: find a URDF by name in example-robot-data, load it with Pinocchio, and reduce it
to the joints a log actually has.

Only the model's 1-DoF joints (revolute, prismatic, and unbounded revolute stored as cos/sin) are
matched to log joints; joints the log lacks are locked at their neutral value with Pinocchio's
``buildReducedModel``.
"""

from __future__ import annotations

import contextlib
import hashlib
import importlib.metadata
import logging
import os
import re
import tempfile
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from functools import cached_property, lru_cache
from pathlib import Path
from typing import TYPE_CHECKING, Any
from xml.etree import ElementTree

import numpy as np

if TYPE_CHECKING:
    import pinocchio as pin

from twincd.defaults import DEFAULT_ROBOT
from twincd.errors import JointMismatchError, RobotModelError
from twincd.twin.openmp import load_pinocchio
from twincd.types import FloatArray

log = logging.getLogger("twincd")


@lru_cache(maxsize=1)
def robots_dir() -> Path:
    """The ``robots`` folder that the installed example-robot-data wheel ships."""
    try:
        dist = importlib.metadata.distribution("example-robot-data")
    except importlib.metadata.PackageNotFoundError as exc:
        raise RobotModelError(
            "example-robot-data is not installed",
            "robot",
            "pip install example-robot-data",
            option="robot",
        ) from exc
    path = Path(str(dist.locate_file("cmeel.prefix/share/example-robot-data/robots")))
    if not path.is_dir():
        raise RobotModelError(
            "example-robot-data ships no robots folder", str(path), "reinstall example-robot-data"
        )
    return path


@lru_cache(maxsize=1)
def list_robots() -> dict[str, Path]:
    """Robot names to URDF paths, sorted by name.

    A name is the URDF's stem (``<package>/<stem>`` where several packages ship that stem);
    ``ur5_robot`` is also known as ``ur5`` when no URDF is called that already.
    """
    root = robots_dir()
    by_stem: dict[str, list[Path]] = {}
    for urdf in sorted(root.glob("*/*/*.urdf")):
        by_stem.setdefault(urdf.stem, []).append(urdf)
    names: dict[str, Path] = {}
    for stem, paths in by_stem.items():
        for urdf in paths:
            package = urdf.relative_to(root).parts[0].removesuffix("_description")
            names[stem if len(paths) == 1 else f"{package}/{stem}"] = urdf
    for name, urdf in list(names.items()):
        short = name.removesuffix("_robot")
        names.setdefault(short, urdf)
    return dict(sorted(names.items()))


PACKAGE = "package://"


def package_roots(package: str) -> list[Path]:
    """Where the ROS package ``package`` may be installed: among example-robot-data's robots
    (each ``<name>_description`` folder is one), in each ``share`` folder of
    ``AMENT_PREFIX_PATH`` (ROS 2), and in each folder of ``ROS_PACKAGE_PATH`` (ROS 1)."""
    roots = [robots_dir() / package]
    roots += [prefix / "share" / package for prefix in _search_path("AMENT_PREFIX_PATH")]
    for folder in _search_path("ROS_PACKAGE_PATH"):
        roots += [folder / package] + ([folder] if folder.name == package else [])
    return roots


def _search_path(variable: str) -> list[Path]:
    """The folders an environment variable lists (``os.pathsep``-separated)."""
    return [Path(p) for p in os.environ.get(variable, "").split(os.pathsep) if p]


def package_file(uri: str) -> Path | None:
    """The file a ``package://PACKAGE/REST`` URI names on this machine (None: not found)."""
    package, _, rest = uri.removeprefix(PACKAGE).partition("/")
    if not package or not rest:
        return None
    return next((r / rest for r in package_roots(package) if (r / rest).is_file()), None)


def package_uri(path: Path) -> str | None:
    """``package://PACKAGE/REST`` for a file inside a package that ``package_roots`` finds
    (example-robot-data's robots, an ``AMENT_PREFIX_PATH`` share, a ``ROS_PACKAGE_PATH``
    folder): how another machine with that package finds it; None elsewhere."""
    resolved = path.resolve()
    roots = [robots_dir()]
    roots += [prefix / "share" for prefix in _search_path("AMENT_PREFIX_PATH")]
    roots += _search_path("ROS_PACKAGE_PATH")
    for root in roots:
        try:
            parts = resolved.relative_to(root.resolve()).parts
        except (ValueError, OSError):
            continue
        if len(parts) >= 2:
            return PACKAGE + "/".join(parts)
    return None


def resolve_urdf(name_or_path: str) -> Path:
    """A URDF path for an example-robot-data name, a ``package://`` URI or a path to a URDF
    file."""
    robots = list_robots()
    if name_or_path in robots:
        return robots[name_or_path]
    if name_or_path.startswith(PACKAGE):
        found = package_file(name_or_path)
        if found is None:
            raise RobotModelError(
                "URDF not found in any installed package",
                name_or_path,
                "install the package (or set AMENT_PREFIX_PATH or ROS_PACKAGE_PATH), or give "
                "the URDF's path",
                option="robot",
            )
        return found
    path = Path(name_or_path)
    if path.suffix.lower() == ".urdf" or path.exists():
        if not path.is_file():
            raise RobotModelError(
                "URDF file not found", str(path), "check the robot's URDF path", option="robot"
            )
        return path
    close = [n for n in robots if name_or_path.lower() in n.lower()][:5]
    hint = (
        f"did you mean {', '.join(close)}?"
        if close
        else "give a known example-robot-data name or a URDF path"
    )
    raise RobotModelError(f"unknown robot {name_or_path!r}", "robot", hint, option="robot")


def locate_urdf(recorded: str, package: str | None, beside: Path | None) -> str | None:
    """Where a robot model recorded as ``recorded`` (an example-robot-data name, a
    ``package://`` URI or a URDF path) is on this machine: the name or URI when it resolves
    here, the path where it exists; else a file of the recorded path, or of its name, beside
    ``beside`` (a calibration's folder); else the file its ``package`` URI names. None:
    nowhere."""
    if recorded in list_robots():
        return recorded
    if recorded.startswith(PACKAGE):
        return recorded if package_file(recorded) is not None else None
    path = Path(recorded)
    if path.is_file():
        return recorded
    if beside is not None:
        for candidate in (beside / path, beside / path.name):
            if candidate.is_file():
                return str(candidate)
    if package and package_file(package) is not None:
        return package
    return None


def file_sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@dataclass(frozen=True)
class JointSpec:
    """Where one model joint lives in Pinocchio's q and v vectors."""

    name: str
    idx_q: int
    idx_v: int
    unbounded: bool  # stored as (cos, sin) in q


@dataclass(frozen=True)
class RobotModel:
    """A Pinocchio model reduced to the joints a log has, in model order."""

    name: str
    urdf_path: Path
    urdf_sha256: str
    model: pin.Model
    joints: tuple[JointSpec, ...]
    locked: tuple[str, ...]

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def dof(self) -> int:
        return len(self.joints)

    @cached_property
    def plain_layout(self) -> bool:
        """True when q and v are just the joint values in model order (no locked joint left in
        the vectors, no cos/sin joint): arrays then pass to Pinocchio without conversion."""
        n = len(self.joints)
        return self.model.nq == self.model.nv == n and all(
            j.idx_q == j.idx_v == i and not j.unbounded for i, j in enumerate(self.joints)
        )

    @cached_property
    def neutral(self) -> FloatArray:
        pin = load_pinocchio()

        neutral: FloatArray = pin.neutral(self.model)
        return neutral

    def __reduce__(self) -> tuple[Any, ...]:
        # a ModelPool does not pickle, and a Pinocchio model need not travel between processes
        # (evaluate's prepared logs do): the receiving process loads the same URDF again
        return (_reloaded, (self.name, self.joint_names))

    def pool(self, threads: int) -> Any:
        """A Pinocchio ModelPool of at least ``threads`` model/data pairs (built once)."""
        pin = load_pinocchio()

        pools: dict[int, Any] = self.__dict__.setdefault("_pools", {})
        if threads not in pools:
            pools[threads] = pin.ModelPool(self.model, threads)
        return pools[threads]

    def configuration(self, position: FloatArray) -> FloatArray:
        """Pinocchio configurations (N, nq) from joint positions (N, dof) in model order."""
        position = np.atleast_2d(position)
        q = np.tile(self.neutral, (position.shape[0], 1))
        for col, joint in enumerate(self.joints):
            if joint.unbounded:
                q[:, joint.idx_q] = np.cos(position[:, col])
                q[:, joint.idx_q + 1] = np.sin(position[:, col])
            else:
                q[:, joint.idx_q] = position[:, col]
        return q

    def velocity_vector(self, values: FloatArray) -> FloatArray:
        """Tangent vectors (N, nv) from per-joint values (N, dof) in model order."""
        values = np.atleast_2d(values)
        v = np.zeros((values.shape[0], self.model.nv))
        v[:, [j.idx_v for j in self.joints]] = values
        return v

    def joint_values(self, tangent: FloatArray) -> FloatArray:
        """Per-joint values (N, dof) from tangent-space arrays (N, nv), e.g. torques."""
        return np.atleast_2d(tangent)[:, [j.idx_v for j in self.joints]]

    @cached_property
    def velocity_limits(self) -> dict[str, float]:
        """Velocity limits by joint name (the URDF's ``velocity``); joints without one (not
        finite or not positive) are left out."""
        return self._per_joint(self.model.velocityLimit)

    @cached_property
    def effort_limits(self) -> dict[str, float]:
        """Effort limits by joint name (the URDF's ``effort``), as ``velocity_limits``."""
        return self._per_joint(self.model.effortLimit)

    def _per_joint(self, values: Any) -> dict[str, float]:
        out = {j.name: float(values[j.idx_v]) for j in self.joints}
        return {n: v for n, v in out.items() if np.isfinite(v) and v > 0}

    @cached_property
    def dynamics_sha256(self) -> str:
        """What the twin computes with, hashed (``dynamics_hash``): a calibration identifies
        its robot by it, not by the URDF file's bytes or path."""
        return dynamics_hash(self.model)

    @cached_property
    def position_limits(self) -> dict[str, tuple[float, float]]:
        """(lower, upper) position limits by joint name; joints without any are left out (a
        continuous joint, stored as cos/sin, or limits absent: not finite, or lower ≥ upper)."""
        lo, hi = self.model.lowerPositionLimit, self.model.upperPositionLimit
        limits = {}
        for joint in self.joints:
            a, b = float(lo[joint.idx_q]), float(hi[joint.idx_q])
            if not joint.unbounded and np.isfinite(a) and np.isfinite(b) and a < b:
                limits[joint.name] = (a, b)
        return limits


# decimals the dynamics hash keeps (SI units): far below any value that changes a torque, far
# above what parsing the same URDF with another build of Pinocchio might change
_HASH_DECIMALS = 10


def dynamics_hash(model: pin.Model) -> str:
    """The sha256 of what inverse dynamics computes with on ``model`` (a robot reduced to the
    twin's joints): per joint in model order its name, type, parent and placement, its motion
    subspace, its body's inertia (mass, centre of mass, rotational inertia), its armature and
    its position, velocity and effort limits; and gravity. Numbers are rounded to 10
    decimals. Two URDF files that differ only in what the twin does not use (meshes,
    comments, visual and collision elements, link names, the file's path) hash alike."""
    import json

    pin = load_pinocchio()

    data = model.createData()
    pin.computeJointJacobians(model, data, pin.neutral(model))

    def numbers(values: Any) -> list[float]:
        rounded = np.round(np.asarray(values, dtype=np.float64).ravel(), _HASH_DECIMALS) + 0.0
        out: list[float] = rounded.tolist()
        return out

    joints = []
    for jid in range(1, model.njoints):
        joint = model.joints[jid]
        q = slice(joint.idx_q, joint.idx_q + joint.nq)
        v = slice(joint.idx_v, joint.idx_v + joint.nv)
        local = pin.getJointJacobian(model, data, jid, pin.ReferenceFrame.LOCAL)[:, v]
        joints.append(
            [
                str(model.names[jid]),
                str(joint.shortname()),
                int(model.parents[jid]),
                numbers(model.jointPlacements[jid].homogeneous[:3]),
                numbers(local),
                numbers(model.inertias[jid].toDynamicParameters()),
                numbers(model.armature[v]),
                numbers(model.lowerPositionLimit[q]),
                numbers(model.upperPositionLimit[q]),
                numbers(model.velocityLimit[v]),
                numbers(model.effortLimit[v]),
            ]
        )
    content = {"joints": joints, "gravity": numbers(model.gravity.linear)}
    text = json.dumps(content, separators=(",", ":"), sort_keys=True)
    return hashlib.sha256(text.encode("utf-8")).hexdigest()


@lru_cache(maxsize=16)
def _reloaded(name: str, joints: tuple[str, ...]) -> RobotModel:
    return load_robot(name, keep=joints)


def _joint_specs(model: pin.Model) -> tuple[JointSpec, ...]:
    specs = []
    for jid in range(1, model.njoints):
        joint = model.joints[jid]
        if joint.nv != 1:
            continue  # free-flyers, spherical joints: never a log joint
        specs.append(JointSpec(model.names[jid], joint.idx_q, joint.idx_v, unbounded=joint.nq == 2))
    return tuple(specs)


@contextlib.contextmanager
def _native_stderr_captured() -> Iterator[list[str]]:
    """Capture what C++ code (urdfdom) writes to file descriptor 2 into the yielded list.

    urdfdom prints parse errors straight to stderr; twincd reports one line of its own instead.
    """
    lines: list[str] = []
    try:
        saved = os.dup(2)
    except OSError:  # no usable stderr: nothing to protect
        yield lines
        return
    with tempfile.TemporaryFile() as sink:
        os.dup2(sink.fileno(), 2)
        try:
            yield lines
        finally:
            os.dup2(saved, 2)
            os.close(saved)
            sink.seek(0)
            lines.extend(sink.read().decode("utf-8", "replace").splitlines())


def file_version(path: Path) -> tuple[int, int]:
    """(mtime in ns, size) of a file: part of a cache key, so an edited URDF is loaded again."""
    stat = path.stat()
    return stat.st_mtime_ns, stat.st_size


@lru_cache(maxsize=16)
def _full_model(urdf_path: Path, version: tuple[int, int] = (0, 0)) -> pin.Model:
    """The whole model of ``urdf_path`` (``version``: ``file_version``, the cache key)."""
    pin = load_pinocchio()

    try:
        tree = ElementTree.parse(urdf_path)  # malformed XML: said before Pinocchio sees it
    except ElementTree.ParseError as exc:
        raise RobotModelError(
            f"cannot load URDF: not valid XML ({exc})",
            str(urdf_path),
            "check that the file is a valid URDF",
        ) from exc
    _refuse_xacro(urdf_path, tree.getroot())
    with _native_stderr_captured() as native:
        try:
            model = pin.buildModelFromUrdf(str(urdf_path))
        except (RuntimeError, ValueError) as exc:
            text = str(exc).strip() or (native[-1] if native else type(exc).__name__)
            raise RobotModelError(
                f"cannot load URDF: {text.splitlines()[0]}",
                str(urdf_path),
                "check that the file is a valid URDF",
            ) from exc
    for line in native:
        log.debug("urdfdom: %s", line)
    return model


XACRO_NS = "{http://www.ros.org/wiki/xacro}"


def _refuse_xacro(path: Path, root: ElementTree.Element) -> None:
    """A xacro file (macros, properties, includes: ``*.urdf.xacro``) is not a URDF yet: say so
    and what to run, rather than Pinocchio's "does not contain a valid URDF model"."""
    macros = any(str(e.tag).startswith(XACRO_NS) for e in root.iter())
    if macros or path.suffix.lower() == ".xacro":
        urdf = path.name.removesuffix(".xacro").removesuffix(".urdf") + ".urdf"
        raise RobotModelError(
            "the robot model is a xacro file, not a URDF",
            str(path),
            f"expand it into a URDF first (xacro {path.name} > {urdf}) and give that file",
            option="robot",
        )


# gripper joints: the arm's twin does not drive them (contract: Inputs: locked, never fitted)
_UNDRIVEN = re.compile(r"finger|gripper", re.IGNORECASE)


def load_robot(name_or_path: str = DEFAULT_ROBOT, keep: Sequence[str] | None = None) -> RobotModel:
    """Load a robot; with ``keep``, lock every model joint not listed (at its neutral value).

    Raises JointMismatchError when ``keep`` shares no joint with the model.
    """
    pin = load_pinocchio()

    urdf = resolve_urdf(name_or_path)
    full = _full_model(urdf, file_version(urdf))
    specs = _joint_specs(full)
    if not specs:
        raise RobotModelError("the URDF has no movable 1-DoF joints", str(urdf), "use an arm URDF")
    locked: tuple[str, ...] = ()
    model = full
    names = [s.name for s in specs]
    undriven = [n for n in names if _UNDRIVEN.search(n)]
    if len(undriven) < len(names) and undriven:  # an arm with a gripper: the arm is the twin
        keep = [n for n in (names if keep is None else keep) if n not in undriven]
    if keep is not None:
        wanted = set(keep)
        if not wanted & set(names):
            raise JointMismatchError(
                "no joint of the log is in the robot model",
                f"log: {', '.join(sorted(wanted)[:8])}; model: {', '.join(names[:8])}",
                "pick the right robot model or rename the log's joints (old=new)",
                option="robot,joint_map",
            )
        locked = tuple(n for n in names if n not in wanted)
        if locked:
            ids = [full.getJointId(n) for n in locked]
            model = pin.buildReducedModel(full, ids, pin.neutral(full))
            lacking = [n for n in locked if n not in undriven]
            if lacking:
                log.warning(
                    "locking %d model joint(s) the log lacks at their neutral value: %s",
                    len(lacking),
                    ", ".join(lacking),
                )
            specs = _joint_specs(model)
    label = name_or_path if name_or_path in list_robots() else str(urdf)
    return RobotModel(
        name=label,
        urdf_path=urdf,
        urdf_sha256=file_sha256(urdf),
        model=model,
        joints=specs,
        locked=locked,
    )


def child_links(robot: RobotModel, names: Sequence[str]) -> tuple[tuple[str, ...], tuple[int, ...]]:
    """For each joint in ``names``: the body (link) it moves, and its depth in the kinematic
    tree (the number of joints from the base to it, itself included).

    A push on a link makes torque only on the joints between the base and that link, so the
    deepest joint whose residual is significant bounds the link that was touched.
    """
    pin = load_pinocchio()

    model = robot.model
    links: list[str] = []
    depths: list[int] = []
    for name in names:
        jid = int(model.getJointId(name))
        body = next(
            (f.name for f in model.frames if f.parentJoint == jid and f.type == pin.FrameType.BODY),
            name,
        )
        depth = 0
        while jid > 0:
            depth += 1
            jid = int(model.parents[jid])
        links.append(body)
        depths.append(depth)
    return tuple(links), tuple(depths)
