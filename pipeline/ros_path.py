"""A plan or a run handed back to ROS 2: a ``nav_msgs/msg/Path`` message as YAML or JSON.

The YAML is what ``ros2 topic pub --once /plan nav_msgs/msg/Path "$(cat FILE)"`` reads (no ROS
installation is needed to write it); the JSON holds the same fields, for rosbridge or a bag
converter. The message follows its definition field by field::

    nav_msgs/Path:            std_msgs/Header header, geometry_msgs/PoseStamped[] poses
    std_msgs/Header:          builtin_interfaces/Time stamp (int32 sec, uint32 nanosec), string frame_id
    geometry_msgs/PoseStamped: std_msgs/Header header, geometry_msgs/Pose pose
    geometry_msgs/Pose:       Point position (float64 x, y, z), Quaternion orientation (float64 x, y, z, w)

Every pose is the robot's reference point (x, y, 0) with the quaternion of its heading theta,
(0, 0, sin(theta / 2), cos(theta / 2)), stamped with ``stamp`` plus its time along the nominal (or
the run); the path's header carries ``stamp`` itself. The coordinates are nhstab's map coordinates,
unchanged: for a map read from a ROS ``map_server`` YAML file they are the ROS ``map`` frame, since
nhstab places the grid at the file's ``origin`` as map_server does (:mod:`nhstab.maps.ros`).

``nav_msgs/Path`` has no direction of travel: a car's reversing poses keep the heading of the car
(the orientation is where the car points, not where it moves). The directions are given next to
the message: in YAML comments (``# cusps: ...`` and one ``# segment`` line per run of constant
direction), and for JSON in a companion file ``NAME.segments.json``.
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np

from .errors import InputError
from .execution.outputs import PLAN_FILES, RUN_FILES, read_run_csv
from .records import write_text
from .robot import robot_from_spec
from .safe_io import read_text
from .trajectory_io import read_trajectory

__all__ = ["FORMATS", "export_path", "path_message", "quaternion_yaw", "read_folder", "ros_stamp",
           "travel_directions", "yaw_quaternion"]

FORMATS = ("yaml", "json")
#: the longest single argument Linux passes to a program (MAX_ARG_STRLEN, 32 pages of 4 KiB): ``"$(cat FILE)"``
#: fails with "Argument list too long" above it
SHELL_ARG_MAX = 131072
_FRAME = re.compile(r"[A-Za-z0-9_./-]{1,256}")
_MAX_SEC = 2**31 - 1


def yaw_quaternion(yaw) -> tuple[float, float, float, float]:
    """The quaternion (x, y, z, w) of a rotation by ``yaw`` about z: (0, 0, sin(yaw/2), cos(yaw/2))."""
    return 0.0, 0.0, math.sin(0.5 * yaw), math.cos(0.5 * yaw)


def quaternion_yaw(q) -> float:
    """The yaw of a quaternion (x, y, z, w): atan2(2 (w z + x y), 1 - 2 (y^2 + z^2)) (tf2's getYaw)."""
    x, y, z, w = (float(a) for a in q)
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def ros_stamp(t: float) -> dict:
    """builtin_interfaces/Time of ``t`` seconds (>= 0): {sec, nanosec}, rounded to the nanosecond."""
    ns = round(float(t) * 1e9)
    sec, nanosec = divmod(ns, 10**9)
    return {"sec": int(sec), "nanosec": int(nanosec)}


def path_message(t, poses, frame_id: str = "map", stamp: float = 0.0) -> dict:
    """A ``nav_msgs/Path`` as nested dicts: ``t`` (N,) seconds from the start, ``poses`` (N, 3) x, y, theta."""
    _check_frame(frame_id)
    t = np.asarray(t, dtype=float)
    poses = np.asarray(poses, dtype=float)
    if poses.ndim != 2 or poses.shape[1] != 3 or t.shape != (len(poses),) or len(t) == 0:
        raise InputError("poses", "N >= 1 poses (x, y, theta) with one time each", f"shape {poses.shape}")
    if not (np.all(np.isfinite(poses)) and np.all(np.isfinite(t))):
        raise InputError("poses", "finite numbers", "NaN or inf")
    if np.any(np.diff(t) < 0):
        raise InputError("t", "non-decreasing times", "decreasing times")
    _check_stamp("stamp", stamp)
    _check_stamp("stamp + t", stamp + float(t[-1]))
    out = []
    for ti, (x, y, th) in zip(t, poses):
        qx, qy, qz, qw = yaw_quaternion(float(th))
        out.append({"header": {"stamp": ros_stamp(stamp + ti), "frame_id": frame_id},
                    "pose": {"position": {"x": float(x), "y": float(y), "z": 0.0},
                             "orientation": {"x": qx, "y": qy, "z": qz, "w": qw}}})
    return {"header": {"stamp": ros_stamp(stamp), "frame_id": frame_id}, "poses": out}


def travel_directions(model, x, u) -> np.ndarray:
    """+1 (forward) or -1 (reverse) per sample: the sign of the velocity along the heading,
    x' cos(theta) + y' sin(theta). A sample at rest takes the direction of the motion it is part of: the
    next move's, or at the end the last move's (all +1 if the robot never moves)."""
    names = list(model.state_names)
    ix, iy, ith = names.index("x"), names.index("y"), names.index("theta")
    xd = model.rhs(np.asarray(x, dtype=float), np.asarray(u, dtype=float))
    along = xd[:, ix] * np.cos(x[:, ith]) + xd[:, iy] * np.sin(x[:, ith])
    scale = float(np.abs(along).max()) if len(along) else 0.0
    sign = np.where(np.abs(along) > 1e-9 * scale, np.sign(along), 0.0) if scale > 0 else np.zeros(len(along))
    out = np.ones(len(sign))
    nxt = 0.0
    for i in range(len(sign) - 1, -1, -1):            # a stop takes the next move's direction
        if sign[i] != 0:
            nxt = sign[i]
        out[i] = nxt
    moving = np.flatnonzero(sign)
    if moving.size:
        out[moving[-1] + 1:] = sign[moving[-1]]        # after the last move, its direction
    else:
        out[:] = 1.0
    return out


def segments(directions) -> list[tuple[int, int, int]]:
    """Runs of constant direction as (first index, last index, +1 or -1)."""
    d = np.asarray(directions)
    if len(d) == 0:
        return []
    cuts = np.flatnonzero(np.diff(d) != 0) + 1
    starts = [0, *cuts.tolist()]
    ends = [*(cuts - 1).tolist(), len(d) - 1]
    return [(int(a), int(b), int(d[a])) for a, b in zip(starts, ends)]


def read_folder(folder) -> dict:
    """The trajectory of a ``nhstab plan`` folder (plan.json, trajectory.npz: the nominal) or a
    ``nhstab run`` folder (run.json, trajectory.csv: the robot's state as simulated, with the direction
    of travel of the nominal it follows) as {kind, map, model, t, poses (N, 3), directions (N,)}."""
    folder = Path(folder)
    if not folder.is_dir():
        raise InputError("FOLDER", "the output folder of nhstab plan or nhstab run", str(folder))
    plan, run = folder / "plan.json", folder / "run.json"
    if plan.is_file():
        kind, record_file = "plan", plan
    elif run.is_file():
        kind, record_file = "run", run
    else:
        raise InputError("FOLDER", "a folder holding plan.json (nhstab plan) or run.json (nhstab run)", str(folder))
    try:
        record = json.loads(read_text(record_file, "FOLDER", f"{kind}.json"))
        inputs = record["inputs"]
        spec = {k: v for k, v in inputs["robot"].items() if k not in _DESCRIBE_ONLY}
    except (ValueError, KeyError, TypeError, AttributeError):
        raise InputError(str(record_file), f"nhstab {kind}'s {kind}.json with inputs.robot", "another file") from None
    robot = robot_from_spec(spec, where=f"{record_file.name}: inputs.robot", source=str(record_file))
    cols = robot.pose_columns
    if kind == "plan":
        nom = read_trajectory(folder / "trajectory.npz", robot.model)
        t, x, u = nom.t, nom.x, nom.u
        x_dir = x
    else:
        csv_file = folder / "trajectory.csv"
        if not csv_file.is_file():
            raise InputError("FOLDER", "a run folder with its trajectory.csv", str(folder))
        try:
            data = read_run_csv(csv_file)
            t = data["t"]
            x = np.column_stack([data[n] for n in robot.model.state_names])
            # the direction of travel is the plan's being followed: the simulated robot's own speed changes
            # sign under noise wherever its nominal stops
            x_dir = np.column_stack([data[f"{n}_nominal"] for n in robot.model.state_names])
            u = np.column_stack([data[f"{n}_nominal"] for n in robot.model.input_names])
        except (KeyError, ValueError, IndexError):
            raise InputError(str(csv_file), f"nhstab run's trajectory.csv for a {robot.model.name}",
                             "other columns") from None
        if len(t) == 0:
            raise InputError(str(csv_file), "a run with at least one sample", "no samples")
    return {"kind": kind, "map": str(inputs.get("map", "")), "model": robot.model.name, "t": np.asarray(t, float),
            "poses": np.asarray(x, float)[:, cols], "directions": travel_directions(robot.model, x_dir, u)}


#: the files of a plan or run folder (an export never replaces them)
_OWNED = tuple(dict.fromkeys((*PLAN_FILES, *RUN_FILES, "nhstab-manifest.json")))
#: keys of ``Robot.describe()`` that are not part of the robot's YAML form
_DESCRIBE_ONLY = ("state_names", "input_names", "footprint_label", "trailer_footprint_labels", "min_turning_radius_m",
                  "source", "notes")


def export_path(folder, out, fmt: str = "yaml", frame_id: str = "map", stamp: float = 0.0, stride: int = 1) -> dict:
    """Write the trajectory of a plan or run folder as a ``nav_msgs/Path`` (``fmt`` yaml or json) to
    ``out``; every ``stride``-th sample is kept, and always the first, the last and the first and last of
    every run of constant direction. Returns {message, segments, cusps, files, bytes, kind}."""
    if fmt not in FORMATS:
        raise InputError("--format", "one of " + ", ".join(FORMATS), fmt)
    if isinstance(stride, bool) or not isinstance(stride, int) or stride < 1:
        raise InputError("--stride", "an integer >= 1", stride)
    out = Path(out)
    if out.resolve().parent == Path(folder).resolve() and out.name in _OWNED:
        raise InputError("--out", f"a file other than the folder's own {', '.join(_OWNED)}", str(out))
    data = read_folder(folder)
    n = len(data["t"])
    segs_all = segments(data["directions"])
    keep = set(range(0, n, stride)) | {n - 1} | {a for a, _, _ in segs_all} | {b for _, b, _ in segs_all}
    idx = np.array(sorted(keep))
    msg = path_message(data["t"][idx], data["poses"][idx], frame_id, stamp)
    segs = segments(data["directions"][idx])
    cusps = [a for a, _, _ in segs[1:]]
    head = [f"nav_msgs/msg/Path: the {data['kind']} of {data['map'] or 'an nhstab map'} ({data['model']}), "
            f"{len(idx)} poses in frame {frame_id!r}, nhstab's map coordinates",
            f"times: stamp {stamp:g} s + the {data['kind']}'s time; orientation: the robot's heading",
            "nav_msgs/Path has no direction of travel: the segments below give it (+1 forward, -1 reverse)",
            f"cusps (pose indices where the direction changes): {cusps}"]
    head += [f"segment poses {a}..{b}: {'forward' if d > 0 else 'reverse'}" for a, b, d in segs]
    if fmt == "yaml":
        text = "".join(f"# {h}\n" for h in head) + to_yaml(msg)
        files = [write_text(out, text)]
    else:
        text = json.dumps(msg, separators=(",", ":")) + "\n"
        companion = out.with_name(out.stem + ".segments.json")
        files = [write_text(out, text), write_text(companion, json.dumps(
            {"message": out.name, "frame_id": frame_id, "cusps": cusps, "notes": head,
             "segments": [{"first": a, "last": b, "direction": d} for a, b, d in segs]}, indent=1) + "\n")]
    return {"message": msg, "segments": segs, "cusps": cusps, "files": files, "bytes": len(text.encode()),
            "kind": data["kind"], "poses": len(idx)}


def to_yaml(msg: dict) -> str:
    """The message as YAML: one flow mapping per pose, floats written so that a YAML 1.1 reader (PyYAML,
    as ``ros2 topic pub`` uses) reads them back as the same floats."""
    def stamp(s):
        return f"{{sec: {s['sec']}, nanosec: {s['nanosec']}}}"

    def header(h):
        return f"{{stamp: {stamp(h['stamp'])}, frame_id: {json.dumps(h['frame_id'])}}}"

    lines = [f"header: {header(msg['header'])}", "poses:" if msg["poses"] else "poses: []"]
    for p in msg["poses"]:
        pos, q = p["pose"]["position"], p["pose"]["orientation"]
        lines.append(f"- {{header: {header(p['header'])}, pose: {{position: {{x: {_f(pos['x'])}, y: {_f(pos['y'])}, "
                     f"z: {_f(pos['z'])}}}, orientation: {{x: {_f(q['x'])}, y: {_f(q['y'])}, z: {_f(q['z'])}, "
                     f"w: {_f(q['w'])}}}}}}}")
    return "\n".join(lines) + "\n"


def _f(v: float) -> str:
    """A float's shortest round-trip text in a form YAML 1.1 reads as a float (1e-05 -> 1.0e-05)."""
    s = repr(float(v))
    if "e" in s:
        mant, exp = s.split("e")
        if "." not in mant:
            mant += ".0"
        s = f"{mant}e{exp if exp[0] in '+-' else '+' + exp}"
    return s


def _check_frame(frame_id) -> None:
    if not isinstance(frame_id, str) or not _FRAME.fullmatch(frame_id):
        raise InputError("--frame", "a ROS frame id: 1 to 256 letters, digits, '_', '.', '/' or '-'", frame_id)


def _check_stamp(name: str, value) -> None:
    ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    if not ok or not 0.0 <= value <= _MAX_SEC:
        raise InputError("--stamp", f"a time in [0, {_MAX_SEC}] s for every pose (builtin_interfaces/Time)",
                         value, detail="" if name == "stamp" else "the last pose's stamp + t")
