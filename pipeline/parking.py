"""The parking suite (``nhstab parking suite``): parallel slots, perpendicular and angled bays, made
from the geometry of the car that parks, and the closed forms the slots are sized against.

A car here is a rectangle referenced to its rear axle (:class:`CarGeometry`): wheelbase L, width w,
front overhang f (ahead of the front axle) and rear overhang b (behind the rear axle), and R, the
rear axle's minimum turning radius L / tan(max_steer).

**Parallel slots.** The single-maneuver minimum slot length (the gap between the parked cars'
bumpers) is

    L1 = b + sqrt((R + w/2)^2 + (L + f)^2 - (R - w/2)^2) = b + sqrt(2 R w + (L + f)^2)

Why: run the last reverse arc backwards in time. From the parked pose (rear axle at the origin,
heading +x, curb on the right) the car drives forward on a left arc about C = (0, R). Its
outer front corner (L + f, -w/2) is the body point farthest from C, at r = sqrt((R + w/2)^2 +
(L + f)^2), and it rises along that circle. The car ahead is parked in line, so its rear corner
nearest to the lane is at (X_f, w/2); the circle crosses the height w/2 at x = sqrt(r^2 - (R -
w/2)^2), which is the smallest X_f that the corner misses. The rear of the car needs b behind the
rear axle. For the default rwd_car (L 2.5 m, max_steer 0.6 rad so R = 3.654 m, body 4.2 x 1.8 m,
b 0.9 m, f 0.8 m) L1 = 5.804 m. With a planning margin m the same construction, with the corner
circle kept m away from the neighbour's corner and m behind the car, gives
:func:`parallel_min_length` ``(car, margin=m)``; at a turning radius other than R (the planner's),
pass ``radius``.

**Perpendicular bays** (reverse-in). Backwards in time the car drives straight out of its bay
(heading +y), then turns right at R to run along the aisle. Its right side sweeps no closer than
R - w/2 to the turn centre, so the turn may begin with the rear axle h = sqrt((R - w/2)^2 - (R -
c)^2) below the corner of the neighbour on that side (c: that corner's lateral offset from the bay's
centre line, w/2 < c <= R), and the outer front corner then reaches r = sqrt((R + w/2)^2 + (L +
f)^2) above the turn centre. With the neighbours' ends flush with the aisle line the swept path
needs an aisle of

    A90 = sqrt((R + w/2)^2 + (L + f)^2) - sqrt((R - w/2)^2 - (R - c)^2)

(:func:`perpendicular_min_aisle`; 3.79 m for the default rwd_car in a 2.5 m bay). Angled bays have
no such short form: :func:`swept_aisle_width` computes the same estimate numerically for any bay
angle (exact rectangle overlap tests along the maneuver, the turn start found by bisection); for
90 degree bays it agrees with A90 (tested).

The suite (:func:`suite`) sizes parallel slots at :data:`PARALLEL_FACTORS` x L1, perpendicular
aisles at :data:`PERPENDICULAR_AISLE_FACTORS` x A90 and angled aisles at
:data:`ANGLED_AISLE_FACTORS` x their swept estimate, for each car of :data:`CARS`. Every case is an
nhstab YAML map (obstacles are boxes: parked cars, curbs, walls) with its start in the lane and its
goal parked in the slot, and the car as the map's ``robot:`` block. :func:`write_suite` writes the
maps, ``suite.csv`` (one row per case) and ``SOURCE.md``.
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from .errors import InputError
from .examples import data_root
from .execution import RunOptions, execute
from .maps import load_map
from .records import write_generated
from .robot import default_robot, robot_from_spec, robot_preset

#: parallel slot lengths, as multiples of the single-maneuver minimum L1
PARALLEL_FACTORS = (0.9, 1.0, 1.05, 1.1, 1.2, 1.4)
#: perpendicular aisle widths, as multiples of the swept-path estimate A90
PERPENDICULAR_AISLE_FACTORS = (1.1, 1.3, 1.6, 1.9)
#: angled bays: angle between the bay axis and the aisle [deg], and aisle widths as multiples of the
#: swept-path estimate of a forward (nose-in) entry
ANGLES_DEG = (45, 60)
ANGLED_AISLE_FACTORS = (1.5, 2.0)
#: the planning margin of the suite's cars [m]: what a careful driver keeps to a parked car; the
#: built-in rwd_car's 0.3 m would leave no single-maneuver slot below 1.16 L1 (see SOURCE.md)
SUITE_MARGIN = 0.1

# street and car-park layout [m]
CURB_GAP = 0.3              # parked body to curb (about 12 in, the usual legal limit)
PARKING_LANE_EXTRA = 0.6    # parking lane = car width + this
TRAVEL_LANE = 3.25          # two travel lanes beside the parking lane
SIDEWALK = 1.0              # depth of the curb/sidewalk boxes
NEIGHBOUR_GAP = 1.0         # between parked cars in the parallel row beside the slot
BAY_EXTRA_WIDTH = 0.7       # bay width = car width + this (2.5 m for the default rwd_car)
BAY_EXTRA_DEPTH = 0.8       # bay depth = car length + this (5.0 m)
GOAL_SETBACK = 0.3          # the parked goal sits this far inside its bay's aisle end
BAYS_EACH_SIDE = 3          # occupied bays on either side of the free one
WALL = 0.5                  # thickness of walls at the map's edge


def _default_car_spec() -> dict:
    """The built-in rwd_car, every parameter explicit, with the suite's margin."""
    robot = default_robot("rwd_car")
    spec = robot.spec()
    geo = CarGeometry.from_robot(robot)
    return {"model": "rwd_car", "name": "rwd_car", **{k: spec[k] for k in ("wheelbase", "max_speed", "max_steer",
                                                                          "max_steer_rate")},
            "footprint": {"rectangle": {"length": geo.length, "width": geo.width, "rear_overhang": geo.rear_overhang}},
            "margin": SUITE_MARGIN}


def cars() -> dict[str, dict]:
    """The suite's cars: name -> robot description (the ``robot:`` block of each map): the built-in
    rwd_car and the rwd_car's ``van`` preset (:attr:`nhstab.models.RwdCar.robot_presets`), each with
    the suite's margin."""
    return {"rwd_car": _default_car_spec(), "van": {**robot_preset("rwd_car", "van"), "margin": SUITE_MARGIN}}


@dataclass(frozen=True)
class CarGeometry:
    """A car's rectangle, referenced to the rear axle, and its rear axle's minimum turning radius."""

    wheelbase: float          # L [m]
    width: float              # w [m]
    length: float             # body length [m]
    rear_overhang: float      # b [m], body behind the rear axle
    min_turning_radius: float  # R [m], L / tan(max_steer)

    @property
    def front_overhang(self) -> float:
        """f [m]: body ahead of the front axle."""
        return self.length - self.rear_overhang - self.wheelbase

    @property
    def front_reach(self) -> float:
        """L + f [m]: body ahead of the rear axle."""
        return self.length - self.rear_overhang

    @classmethod
    def from_footprint(cls, fp, wheelbase: float, min_turning_radius: float) -> "CarGeometry":
        v = None if fp.vertices is None else np.asarray(fp.vertices, dtype=float)
        if v is None or len(v) != 4:
            raise InputError("footprint", "a rectangle (4 vertices) for a parking car", fp.label or "a disc")
        xs, ys = np.unique(np.round(v[:, 0], 12)), np.unique(np.round(v[:, 1], 12))
        if len(xs) != 2 or len(ys) != 2 or abs(ys[0] + ys[1]) > 1e-9 or not (xs[0] <= 0 <= xs[1]):
            raise InputError("footprint", "an axis-aligned rectangle, symmetric about the car's axis, around the rear "
                             "axle", v.tolist())
        geo = cls(wheelbase=float(wheelbase), width=float(ys[1] - ys[0]), length=float(xs[1] - xs[0]),
                  rear_overhang=float(-xs[0]), min_turning_radius=float(min_turning_radius))
        if geo.front_overhang < 0:
            raise InputError("footprint", f"a body reaching at least the front axle ({wheelbase:g} m ahead of the "
                             "rear axle)", geo.front_reach)
        return geo

    @classmethod
    def from_robot(cls, robot) -> "CarGeometry":
        model = robot.model
        if not (hasattr(model, "wheelbase") and hasattr(model, "max_steer")):
            raise InputError("robot", "a car (a model with wheelbase and max_steer)", model.name)
        return cls.from_footprint(robot.footprint, model.wheelbase, model.min_turning_radius)

    def corners(self, poses, grow: float = 0.0) -> np.ndarray:
        """World corners (N, 4, 2) of the body (grown by ``grow`` on every side) at poses (N, 3)."""
        p = np.asarray(poses, dtype=float).reshape(-1, 3)
        b, fr, hw = self.rear_overhang + grow, self.front_reach + grow, self.width / 2 + grow
        local = np.array([[-b, -hw], [fr, -hw], [fr, hw], [-b, hw]])
        c, s = np.cos(p[:, 2]), np.sin(p[:, 2])
        x = p[:, None, 0] + c[:, None] * local[:, 0] - s[:, None] * local[:, 1]
        y = p[:, None, 1] + s[:, None] * local[:, 0] + c[:, None] * local[:, 1]
        return np.stack([x, y], axis=-1)


# ---- closed forms ---------------------------------------------------------------------------------

def parallel_min_length(car: CarGeometry, margin: float = 0.0, radius: float | None = None) -> float:
    """The single-maneuver minimum parallel slot length (see the module docstring). ``margin`` m
    kept from both parked cars; ``radius`` the rear axle's turning radius (default: the minimum)."""
    R = car.min_turning_radius if radius is None else float(radius)
    w, reach, b = car.width, car.front_reach, car.rear_overhang
    r = math.hypot(R + w / 2, reach) + margin
    return b + margin + math.sqrt(r * r - (R - w / 2) ** 2)


def _tail_dip(car: CarGeometry, radius: float) -> float:
    """How much closer to the curb the curb-side rear corner comes on the arc that straightens a car
    at turning radius ``radius`` than it is when parked."""
    r = radius + car.width / 2
    return math.hypot(car.rear_overhang, r) - r


def perpendicular_min_aisle(car: CarGeometry, bay_width: float, radius: float | None = None) -> float:
    """A90: the swept-path aisle width of a single reverse-in maneuver into a bay of ``bay_width``
    between neighbours of the car's width, centred in their bays, ends flush with the aisle line."""
    R = car.min_turning_radius if radius is None else float(radius)
    w = car.width
    c = bay_width - w / 2             # the neighbour's near side, from the bay's centre line
    if not (w / 2 < c <= R):
        raise InputError("bay_width", f"a bay whose neighbour lies within the turning radius (w/2 < c <= R = {R:.3g})",
                         bay_width)
    return math.hypot(R + w / 2, car.front_reach) - math.sqrt((R - w / 2) ** 2 - (R - c) ** 2)


# ---- geometry of the cases ------------------------------------------------------------------------

@dataclass
class Box:
    """An oriented box: centre, length along yaw, width across."""

    cx: float
    cy: float
    length: float
    width: float
    yaw: float = 0.0
    label: str = ""

    def corners(self) -> np.ndarray:
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        half = np.array([[-self.length, -self.width], [self.length, -self.width], [self.length, self.width],
                         [-self.length, self.width]]) / 2
        return half @ np.array([[c, s], [-s, c]]) + [self.cx, self.cy]


@dataclass
class Case:
    """One parking problem of the suite."""

    name: str
    car: str                  # key of cars()
    kind: str                 # parallel | perpendicular | angled45 | angled60
    factor: float             # slot length / L1, or aisle width / its estimate
    size_m: float             # slot length (parallel) or aisle width [m]
    reference_m: float        # L1 (parallel) or the aisle's swept-path estimate [m]
    bounds: tuple
    obstacles: list           # of Box
    start: tuple
    goal: tuple
    slot: np.ndarray          # (4, 2) the slot or bay the goal must lie in
    robot: dict
    description: str

    @property
    def file_name(self) -> str:
        return f"{self.name}.yaml"


def _box_along(center: np.ndarray, axis: np.ndarray, length: float, width: float, label: str) -> Box:
    return Box(float(center[0]), float(center[1]), float(length), float(width),
               float(math.atan2(axis[1], axis[0])), label)


def parallel_case(car_name: str, spec: dict, factor: float) -> Case:
    """A parallel slot of ``factor`` x L1 between two parked cars ahead and two behind, at a curb."""
    car = _geometry(spec)
    L1 = parallel_min_length(car)
    slot = factor * L1
    ln, w = car.length, car.width
    lane = w + PARKING_LANE_EXTRA
    y_top = lane + 2 * TRAVEL_LANE
    x0 = 2.0
    rear_end = x0 + 2 * ln + NEIGHBOUR_GAP            # front bumper of the car behind the slot
    front_start = rear_end + slot                      # rear bumper of the car ahead
    x_max = front_start + 3 * ln + NEIGHBOUR_GAP + 4.0
    yc = CURB_GAP + w / 2
    obstacles = [Box(x_max / 2, -SIDEWALK / 2, x_max, SIDEWALK, 0.0, "curb and sidewalk"),
                 Box(x_max / 2, y_top + SIDEWALK / 2, x_max, SIDEWALK, 0.0, "opposite curb")]
    for k, xs in enumerate((x0, x0 + ln + NEIGHBOUR_GAP, front_start, front_start + ln + NEIGHBOUR_GAP)):
        obstacles.append(Box(xs + ln / 2, yc, ln, w, 0.0, ("behind", "behind", "ahead", "ahead")[k]))
    start = (x0 + car.rear_overhang, lane + TRAVEL_LANE / 2, 0.0)
    goal = (rear_end + (slot - ln) / 2 + car.rear_overhang, yc, 0.0)
    slot_poly = np.array([[rear_end, 0.0], [front_start, 0.0], [front_start, lane], [rear_end, lane]])
    label = "the default rwd_car" if car_name == "rwd_car" else f"the {car_name}"
    desc = (f"Parallel parking, {label} ({ln:g} x {w:g} m): a slot of {slot:.2f} m = {factor:g} x L1 "
            f"(L1 = {L1:.2f} m, the single-maneuver minimum) between parked cars at a curb; start in the lane.")
    return Case(f"parallel_{car_name}_{round(100 * factor):03d}", car_name, "parallel", factor, slot, L1,
                (0.0, -SIDEWALK, x_max, y_top + SIDEWALK), obstacles, start, goal, slot_poly, spec, desc)


def _bay_case(car_name: str, spec: dict, kind: str, theta: float, aisle: float, factor: float, estimate: float,
              reverse_in: bool) -> Case:
    car = _geometry(spec)
    ln, w = car.length, car.width
    W = w + BAY_EXTRA_WIDTH
    n_bays = 2 * BAYS_EACH_SIDE + 1
    lead = ln + 2.0                                    # aisle beyond the row's ends
    row = _row(car, theta, W, lead, n_bays)
    x_max = row["x_right"] + lead
    y_back = row["y_back"]
    obstacles = [Box(x_max / 2, y_back - WALL / 2, x_max, WALL, 0.0, "back wall")]
    obstacles += _row_ends(row, 0.0, x_max, y_back, 0.0)
    goal_k = BAYS_EACH_SIDE
    for k, e in enumerate(row["ends"]):
        if k != goal_k:
            obstacles.append(_box_along(e + (ln / 2) * row["d"], row["d"], ln, w, f"parked in bay {k}"))
    if kind == "perpendicular":
        far = _row(car, theta, W, lead, n_bays, mirror=True, y_line=aisle)
        y_top = far["y_back"]
        obstacles.append(Box(x_max / 2, y_top + WALL / 2, x_max, WALL, 0.0, "far back wall"))
        obstacles += _row_ends(far, 0.0, x_max, aisle, y_top)
        for k, e in enumerate(far["ends"]):
            obstacles.append(_box_along(e + (ln / 2) * far["d"], far["d"], ln, w, f"parked opposite, bay {k}"))
    else:
        y_top = aisle + WALL
        obstacles.append(Box(x_max / 2, aisle + WALL / 2, x_max, WALL, 0.0, "far curb"))
    e = row["ends"][goal_k]
    centre = e + (GOAL_SETBACK + ln / 2) * row["d"]
    if reverse_in:       # nose to the aisle: heading -d, rear axle deeper than the centre
        heading = -row["d"]
    else:                # nose in: heading d
        heading = row["d"]
    axle = centre - (ln / 2 - car.rear_overhang) * heading
    goal = (float(axle[0]), float(axle[1]), float(math.atan2(heading[1], heading[0])))
    start = (1.0 + car.rear_overhang, aisle / 2, 0.0)
    bay = e[None, :] + np.array([[-W / 2, 0.0], [W / 2, 0.0], [W / 2, row["depth"]], [-W / 2, row["depth"]]]) @ \
        np.stack([row["n"], row["d"]])
    label = "the default rwd_car" if car_name == "rwd_car" else f"the {car_name}"
    what = {"perpendicular": "reverse into a perpendicular bay", "angled45": "drive forward into a 45-degree bay",
            "angled60": "drive forward into a 60-degree bay"}[kind]
    aisle_kind = "two-way aisle between two rows of parked cars" if kind == "perpendicular" else "one-way aisle"
    desc = (f"{label[0].upper() + label[1:]} ({ln:g} x {w:g} m) must {what} ({W:g} m wide) off a {aisle_kind} "
            f"{aisle:.2f} m wide = {factor:g} x its swept-path estimate {estimate:.2f} m; start in the aisle.")
    return Case(f"{kind}_{car_name}_aisle{round(100 * factor):03d}", car_name, kind, factor, aisle, estimate,
                (0.0, y_back - WALL, x_max, y_top + (WALL if kind == "perpendicular" else 0.0)), obstacles, start,
                goal, bay, spec, desc)


def _row(car: CarGeometry, theta: float, W: float, x_left: float, n_bays: int, mirror: bool = False,
         y_line: float = 0.0) -> dict:
    """A row of ``n_bays`` bays at angle ``theta`` below the aisle line y = ``y_line`` (above it with
    ``mirror``), the first bay's leftmost point at ``x_left``. Each bay is a W x depth rectangle along
    the axis d (pointing into the bay) whose corner nearest the aisle lies on the aisle line."""
    sgn = -1.0 if mirror else 1.0
    d = np.array([math.cos(theta), -sgn * math.sin(theta)])
    n = np.array([math.sin(theta), sgn * math.cos(theta)])      # across the bay, towards the aisle side
    depth = car.length + BAY_EXTRA_DEPTH
    pitch = W / math.sin(theta)
    y_end = y_line - sgn * (W / 2) * math.cos(theta)            # aisle end's centre: corner e + (W/2) n on the line
    corners = np.array([[-W / 2, 0.0], [W / 2, 0.0], [W / 2, depth], [-W / 2, depth]])
    rect0 = corners @ np.stack([n, d])                          # relative to the aisle end's centre
    x_first = x_left - rect0[:, 0].min()
    ends = [np.array([x_first + k * pitch, y_end]) for k in range(n_bays)]
    rects = [e + rect0 for e in ends]
    return {"d": d, "n": n, "ends": ends, "rects": rects, "pitch": pitch, "depth": depth, "rect0": rect0,
            "x_left": x_left, "x_right": float(rects[-1][:, 0].max()),
            "y_back": float(min(r[:, 1].min() for r in rects)) if not mirror else
            float(max(r[:, 1].max() for r in rects)), "mirror": mirror, "y_line": y_line}


def _row_ends(row: dict, x_min: float, x_max: float, y_a: float, y_b: float) -> list:
    """Blocks closing the bay row's band (between y_a and y_b) beyond its first and last bays."""
    lo, hi = min(y_a, y_b), max(y_a, y_b)
    out = []
    if row["x_left"] - x_min > 1e-9:
        out.append(Box((x_min + row["x_left"]) / 2, (lo + hi) / 2, row["x_left"] - x_min, hi - lo, 0.0, "row end"))
    if x_max - row["x_right"] > 1e-9:
        out.append(Box((row["x_right"] + x_max) / 2, (lo + hi) / 2, x_max - row["x_right"], hi - lo, 0.0, "row end"))
    return out


def _geometry(spec: dict) -> CarGeometry:
    return CarGeometry.from_robot(robot_from_spec(spec))


# ---- the numeric swept-path estimate --------------------------------------------------------------

def _overlap(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Whether convex quadrilaterals overlap (separating axis test): a (N, 4, 2), b (K, 4, 2) -> (N, K)."""
    def axes(q):
        e = np.roll(q, -1, axis=-2) - q
        return np.stack([-e[..., 1], e[..., 0]], axis=-1)            # (.., 4, 2) edge normals

    A, B = a[:, None], b[None, :]                                     # (N, 1, 4, 2), (1, K, 4, 2)
    sep = np.zeros(np.broadcast_shapes(A.shape[:2], B.shape[:2]), dtype=bool)
    for normals in (axes(A), axes(B)):
        for j in range(4):
            ax = normals[..., j, :][..., None, :]                     # (N|1, K|1, 1, 2)
            pa = np.sum(A * ax, axis=-1)
            pb = np.sum(B * ax, axis=-1)
            sep |= (pa.max(-1) < pb.min(-1)) | (pb.max(-1) < pa.min(-1))
    return ~sep


def _exit_sweep(car: CarGeometry, goal, s: float, direction: float, R: float, step: float, grow: float,
                approach: float) -> np.ndarray:
    """The body's sweep, backwards in time, out of the parked ``goal``: straight ``s`` m along the
    heading (``direction`` +1 forward, -1 backward), an arc of radius R turning to heading 0, then
    straight along the aisle towards -x for ``approach`` m (the way the car came). Quads (N, 4, 2),
    grown by ``grow``: each straight as the one rectangle it sweeps, the arc as body outlines at most
    ``step`` m apart at the farthest body point."""
    x, y, th = goal
    b, fr, hw = car.rear_overhang + grow, car.front_reach + grow, car.width / 2 + grow
    c, si = math.cos(th), math.sin(th)
    x1, y1 = x + direction * s * c, y + direction * s * si
    lo, hi = (-b, fr + s) if direction > 0 else (-b - s, fr)
    straight = np.array([[lo, -hw], [hi, -hw], [hi, hw], [lo, hw]]) @ np.array([[c, si], [-si, c]]) + [x, y]
    # the heading goes to 0: dtheta = kappa dsigma with dsigma of the sign of direction
    kappa = -math.copysign(1.0, th) * direction / R
    reach = math.hypot(R + hw, max(b, fr))
    n_a = max(2, int(math.ceil(abs(th) * reach / step)) + 1)
    psi = np.linspace(th, 0.0, n_a)
    arc = np.stack([x1 + (np.sin(psi) - si) / kappa, y1 - (np.cos(psi) - c) / kappa, psi], 1)
    x2, y2 = arc[-1, :2]
    way = np.array([[x2 - b - approach, y2 - hw], [x2 + fr, y2 - hw], [x2 + fr, y2 + hw], [x2 - b - approach, y2 + hw]])
    return np.concatenate([straight[None], car.corners(arc, grow), way[None]])


def swept_aisle_width(row, car: CarGeometry, goal, reverse_in: bool, margin: float = 0.0,
                      radius: float | None = None, step: float = 0.005, approach: float = 60.0) -> dict:
    """The aisle width a single maneuver at the turning radius needs to reach ``goal`` in a bay row
    below the aisle line y = 0. Backwards in time the car leaves the bay straight, turns at R to
    heading 0 and goes back along the aisle the way it came (towards -x). The turn starts as early
    as the row's obstacles (``row``: boxes) allow: bisection on the straight's length, the straights
    checked as the rectangles they sweep and the arc at poses ``step`` m apart, with exact rectangle
    overlap tests, the body grown by ``margin``. The aisle must hold the highest point of the sweep
    (plus ``margin``). Returns the width, the straight's length and the radius."""
    R = car.min_turning_radius if radius is None else float(radius)
    boxes = np.array([b.corners() for b in row])
    direction = 1.0 if reverse_in else -1.0

    def sweep(s: float, st: float):
        quads = _exit_sweep(car, goal, s, direction, R, st, margin, approach)
        return bool(_overlap(quads, boxes).any()), float(quads[..., 1].max())

    # the first feasible straight length on a 0.25 m scan, then bisection (feasibility only improves
    # as the turn moves out of the bay; the scan guards against a lucky early gap)
    s_hi = next((float(s) for s in np.arange(0.0, 30.0, 0.25) if not sweep(float(s), 4 * step)[0]), None)
    if s_hi is None:
        raise InputError("goal", "a bay the car can leave by a straight and one arc", goal)
    if s_hi > 0 or sweep(0.0, step)[0]:
        s_lo = max(0.0, s_hi - 0.25)
        while sweep(s_hi, step)[0]:
            s_lo, s_hi = s_hi, s_hi + 0.25
        while s_hi - s_lo > 1e-6:
            mid = (s_lo + s_hi) / 2
            if sweep(mid, step)[0]:
                s_lo = mid
            else:
                s_hi = mid
    _, top = sweep(s_hi, step)
    return {"aisle_m": top + margin, "straight_m": s_hi, "radius_m": R}


def _estimate_aisle(spec: dict, theta: float, reverse_in: bool, margin: float = 0.0,
                    radius: float | None = None) -> float:
    """The swept-path estimate for a bay at ``theta`` in the suite's row layout (no far side)."""
    import json

    return _estimate_cached(json.dumps(spec, sort_keys=True), theta, reverse_in, margin, radius)


@lru_cache(maxsize=64)
def _estimate_cached(spec_json: str, theta: float, reverse_in: bool, margin: float, radius: float | None) -> float:
    import json

    spec = json.loads(spec_json)
    car = _geometry(spec)
    deg = round(math.degrees(theta))
    case = _bay_case("x", spec, "perpendicular" if deg == 90 else f"angled{deg}", theta, 50.0, 1.0, 1.0, reverse_in)
    row = [b for b in case.obstacles if not b.label.startswith(("parked opposite", "far"))]
    return swept_aisle_width(row, car, case.goal, reverse_in, margin, radius)["aisle_m"]


# ---- the suite ------------------------------------------------------------------------------------

def suite(specs: dict | None = None) -> list[Case]:
    """Every case of the parking suite, in a fixed order: for the suite's cars (:func:`cars`), or for
    ``specs`` (name -> robot description, e.g. :func:`own_car`'s)."""
    out = []
    for car_name, spec in (cars() if specs is None else specs).items():
        car = _geometry(spec)
        for f in PARALLEL_FACTORS:
            out.append(parallel_case(car_name, spec, f))
        W = car.width + BAY_EXTRA_WIDTH
        a90 = perpendicular_min_aisle(car, W)
        for f in PERPENDICULAR_AISLE_FACTORS:
            out.append(_bay_case(car_name, spec, "perpendicular", math.pi / 2, f * a90, f, a90, True))
        for deg in ANGLES_DEG:
            est = _estimate_aisle(spec, math.radians(deg), False)
            for f in ANGLED_AISLE_FACTORS:
                out.append(_bay_case(car_name, spec, f"angled{deg}", math.radians(deg), f * est, f, est, False))
    return out


def _num(v: float) -> str:
    """A number written to 1e-10 (so that slot lengths read back equal factor x L1 to 1e-9)."""
    text = f"{float(v):.10f}".rstrip("0").rstrip(".")
    return "0.0" if text in ("-0", "0", "") else (text if "." in text else text + ".0")


def _flow(value) -> str:
    if isinstance(value, dict):
        return "{" + ", ".join(f"{k}: {_flow(v)}" for k, v in value.items()) + "}"
    if isinstance(value, (list, tuple)):
        return "[" + ", ".join(_flow(v) for v in value) + "]"
    if value is None or isinstance(value, bool):
        return json.dumps(value)          # null, true, false
    if isinstance(value, (int, float, np.floating)):
        return _num(value)
    if isinstance(value, str) and not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_.-]*", value):
        return json.dumps(value)          # a string YAML would read otherwise (spaces, :, {, a number, ...)
    return str(value)


def case_yaml(case: Case, command: str | None = None) -> str:
    """The case as an nhstab YAML map (``command``: what generated it, for a suite of one's own car)."""
    lines = ([f"# {case.file_name} -- generated by `nhstab parking suite --out maps/parking` (nhstab.parking);",
              "# do not edit by hand: change pipeline/parking.py and regenerate. See SOURCE.md in this folder."]
             if command is None else
             [f"# {case.file_name} -- generated by `{command}` (nhstab.parking);",
              "# do not edit by hand: regenerate with that command. See SOURCE.md in this folder."]) + [
             f"# {case.kind}, car {case.car}, " + (f"slot {case.size_m:.6f} m = {case.factor:g} x L1 = "
                                                   f"{case.factor:g} x {case.reference_m:.6f} m"
                                                   if case.kind == "parallel" else
                                                   f"aisle {case.size_m:.6f} m = {case.factor:g} x "
                                                   f"{case.reference_m:.6f} m (swept-path estimate)")]
    return generated_map_yaml(lines, case)


def generated_map_yaml(header: list[str], case) -> str:
    """A generated case (the parking suite's, the trailer suite's) as an nhstab YAML map: the comment lines
    ``header``, then its name, description, bounds, box obstacles (each with its label), start, goal and
    robot."""
    lines = list(header) + [f"name: {case.name}", f"description: \"{case.description}\"",
                            f"bounds: {_flow(list(case.bounds))}", "obstacles:"]
    for b in case.obstacles:
        lines.append(f"  - box: {{center: [{_num(b.cx)}, {_num(b.cy)}], size: [{_num(b.length)}, {_num(b.width)}], "
                     f"yaw: {_num(b.yaw)}}}   # {b.label}")
    lines += [f"start: {_flow(list(case.start))}", f"goal: {_flow(list(case.goal))}", f"robot: {_flow(case.robot)}", ""]
    return "\n".join(lines)


CSV_COLUMNS = ("name", "car", "kind", "factor", "size_m", "reference_m", "start_x", "start_y", "start_theta",
               "goal_x", "goal_y", "goal_theta", "description")


def suite_csv(cases: list[Case]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    for c in cases:
        w.writerow([c.name, c.car, c.kind, f"{c.factor:g}", _num(c.size_m), _num(c.reference_m),
                    *(_num(v) for v in c.start), *(_num(v) for v in c.goal), c.description])
    return buf.getvalue()


def read_suite_csv(path) -> list[dict]:
    """The rows of a suite.csv (numbers as floats)."""
    with open(path, encoding="utf-8", newline="") as fh:
        rows = list(csv.DictReader(fh))
    for r in rows:
        for k in ("factor", "size_m", "reference_m", "start_x", "start_y", "start_theta", "goal_x", "goal_y",
                  "goal_theta"):
            r[k] = float(r[k])
    return rows


def source_md(cases: list[Case]) -> str:
    """SOURCE.md of the suite folder: where the maps come from, the formulas, the table."""
    specs = cars()
    lines = ["# parking — the parking suite", "",
             "Generated, with `suite.csv` and this file, by `nhstab parking suite --out maps/parking` from the",
             "geometry in `pipeline/parking.py` (`nhstab.parking`); do not edit by hand. Original to nhstab,",
             "same licence as nhstab (BSD-3-Clause). nhstab YAML maps: metres, radians, x right, y up.", "",
             "## The cars", "", *_car_table(specs)]
    lines += ["", "`rwd_car` is nhstab's built-in rwd_car; `van` is a long panel van (about a Mercedes Sprinter with",
              "the standard wheelbase: turning circle about 13.5 m kerb to kerb). Each map carries its car as its",
              "`robot:` block (footprint, wheelbase, limits) with a planning margin of "
              f"{SUITE_MARGIN:g} m, what a careful driver", "keeps to a parked car.", "",
              "## Parallel slots: L1", "",
              "The single-maneuver minimum slot (bumper to bumper) is",
              "", "    L1 = b + sqrt((R + w/2)^2 + (L + f)^2 - (R - w/2)^2) = b + sqrt(2 R w + (L + f)^2)", "",
              "(R the rear axle's minimum turning radius, w the width). Backwards in time, the parked car drives",
              "forward on a left arc about C = (0, R) from its parked pose (rear axle at the origin); its outer",
              "front corner, the body point farthest from C at r = sqrt((R + w/2)^2 + (L + f)^2), crosses the",
              "height w/2 of the car ahead's lane-side rear corner at x = sqrt(r^2 - (R - w/2)^2); b more is needed",
              "behind the rear axle. For the default rwd_car L1 = 5.804 m for its 4.2 m body. `tests/parking/test_parking.py`",
              "checks it against a brute-force sweep of the maneuver with shapely.", "",
              "Single-maneuver minima under the conditions the planner works in (the corner circle kept m from the",
              "neighbour's corner, m behind the car; at the planner's turning radius 1.25 R):", "",
              "| car | L1 | L1 with margin 0.1 m | at 1.25 R | at 1.25 R, margin 0.1 m | with the built-in margin 0.3 m |",
              "|---|---|---|---|---|---|"]
    for name, spec in specs.items():
        g = _geometry(spec)
        L1 = parallel_min_length(g)
        vals = [parallel_min_length(g, 0.1), parallel_min_length(g, 0.0, 1.25 * g.min_turning_radius),
                parallel_min_length(g, 0.1, 1.25 * g.min_turning_radius), parallel_min_length(g, 0.3)]
        lines.append(f"| `{name}` | {L1:.3f} m | " + " | ".join(f"{v:.3f} m ({v / L1:.3f} L1)" for v in vals) + " |")
    lines += ["", "So slots below about 1.04 L1 (margin 0.1 m) need more than one maneuver, and a planner that turns",
              "only at 1.25 R cannot park in one maneuver below about 1.09 L1.", "",
              "Layout: a curb (a wall) at y = 0, the parking lane (car width + "
              f"{PARKING_LANE_EXTRA:g} m), two travel lanes of {TRAVEL_LANE:g} m and",
              f"the opposite curb. Two parked cars (boxes of the car's own size, {CURB_GAP:g} m from the curb, "
              f"{NEIGHBOUR_GAP:g} m apart) behind",
              "the slot and two ahead; the goal is centred in the slot at the same curb distance, heading along the",
              "street; the start is in the near travel lane, beside the first parked car, heading the same way.", "",
              "**The tail dips towards the curb.** Any path that ends parallel to the curb ends with an arc that",
              "straightens the car, and on that arc the rear corner on the curb side comes closer to the curb than",
              "it is when parked, by sqrt(b^2 + (R' + w/2)^2) - (R' + w/2) ~ b^2 / (2 (R' + w/2)) at turning",
              "radius R': "
              + ", ".join(f"{n} {_tail_dip(_geometry(sp), _geometry(sp).min_turning_radius):.3f} m at R and "
                          f"{_tail_dip(_geometry(sp), 1.25 * _geometry(sp).min_turning_radius):.3f} m at 1.25 R"
                          for n, sp in specs.items()) + ".",
              f"With the goal {CURB_GAP:g} m from the curb, a planner whose search keeps more than {CURB_GAP:g} m minus",
              "that dip from the curb cannot reach the goal at all, however long the slot.", "",
              "## Bays: aisle widths", "",
              f"Bays are car width + {BAY_EXTRA_WIDTH:g} m wide (2.5 m for the rwd_car, the usual European bay) "
              f"and car length + {BAY_EXTRA_DEPTH:g} m",
              f"deep, {BAYS_EACH_SIDE} occupied bays each side of the free one, parked cars (boxes of the car's size) "
              "centred in their bays",
              "with their aisle ends flush with the bay's, a wall behind the row and blocks beyond its ends. The goal",
              f"sits {GOAL_SETBACK:g} m inside its bay. Perpendicular bays are entered in reverse (nose to the aisle, "
              "as in the bundled",
              "parking lot) off a two-way aisle with a second row of parked cars across it; angled bays forward (as",
              "they are designed) off a one-way aisle with a curb across it. The start is in the aisle, at its",
              "centre line, before the row, heading along it.", "",
              "The aisle widths are multiples of a swept-path estimate: the narrowest aisle in which one maneuver",
              "at the minimum turning radius reaches the goal (no margin). For perpendicular bays, backwards in",
              "time the car leaves the bay straight and turns at R; its inner side sweeps no closer than R - w/2 to",
              "the turn centre, so the turn may start with the rear axle h = sqrt((R - w/2)^2 - (R - c)^2) below",
              "the neighbour's corner (c = bay width - w/2, its offset from the bay's centre line), and the outer",
              "front corner reaches r above the centre:", "",
              "    A90 = sqrt((R + w/2)^2 + (L + f)^2) - sqrt((R - w/2)^2 - (R - c)^2)", "",
              "Angled bays have no short form: `nhstab.parking.swept_aisle_width` computes the estimate",
              "numerically (backwards in time: out of the bay straight, one arc at R to the aisle's heading, back",
              "along the aisle; exact rectangle overlap tests along the way, the turn's start by bisection). For",
              "90 degree bays it equals A90 (tested to 1e-4 m).", "",
              "| car | perpendicular A90 | 45 degree estimate | 60 degree estimate |", "|---|---|---|---|"]
    for name, sp in specs.items():
        g = _geometry(sp)
        lines.append(f"| `{name}` | {perpendicular_min_aisle(g, g.width + BAY_EXTRA_WIDTH):.3f} m | "
                     + " | ".join(f"{_estimate_aisle(sp, math.radians(d), False):.3f} m" for d in ANGLES_DEG) + " |")
    rwd = _geometry(specs["rwd_car"])
    a90 = perpendicular_min_aisle(rwd, rwd.width + BAY_EXTRA_WIDTH)
    perp = ", ".join(f"{f * a90:.2f}" for f in PERPENDICULAR_AISLE_FACTORS)
    lines += ["", f"Perpendicular aisles are {', '.join(f'{f:g}' for f in PERPENDICULAR_AISLE_FACTORS)} x A90; for "
              f"the rwd_car {perp} m: from tight (10 % over",
              "the swept path) through a one-way aisle and the common two-way aisle of 6.0 m (UK and European design",
              "guides) to a generous 7.2 m (US practice, 24 ft). Angled aisles are "
              f"{' and '.join(f'{f:g}' for f in ANGLED_AISLE_FACTORS)} x their estimate:",
              "a tight and a comfortable one-way aisle. The sizes of every case are in the table below.", "",
              "## The cases", "",
              "| map (example:NAME) | car | kind | size | = factor x reference | start | goal |",
              "|---|---|---|---|---|---|---|"]
    lines += _case_rows(cases)
    lines += ["", "`suite.csv` lists the same with full precision. `tests/parking/test_parking.py` checks that the committed",
              "files equal the generator's output, that every slot is its factor x L1 to 1e-9 m, that start and",
              "goal are clear by the margin (FCL and shapely) and that every goal lies inside its slot or bay.", ""]
    return "\n".join(lines)


def _car_table(specs: dict) -> list[str]:
    """SOURCE.md's table of the cars (body, wheelbase, overhangs, steering, R, L1, A90, margin): its lines."""
    rows = ["| car | body (m) | wheelbase L | rear overhang b | front overhang f | max_steer | R = L / tan(max_steer) "
            "| L1 | A90 (bay) | margin |", "|---|---|---|---|---|---|---|---|---|---|"]
    for name, spec in specs.items():
        g = _geometry(spec)
        W = g.width + BAY_EXTRA_WIDTH
        rows.append(f"| `{name}` | {g.length:g} x {g.width:g} | {g.wheelbase:g} | {g.rear_overhang:g} | "
                    f"{g.front_overhang:.3g} | {float(robot_from_spec(spec).model.max_steer):g} rad | "
                    f"{g.min_turning_radius:.3f} m | {parallel_min_length(g):.3f} m | "
                    f"{perpendicular_min_aisle(g, W):.3f} m ({W:g} m) | {spec['margin']:g} m |")
    return rows


def _case_rows(cases) -> list[str]:
    """The rows of SOURCE.md's table of the cases."""
    rows = []
    for c in cases:
        what = "slot" if c.kind == "parallel" else "aisle"
        ref = "L1" if c.kind == "parallel" else ("A90" if c.kind == "perpendicular" else "estimate")
        rows.append(f"| `{c.name}` | {c.car} | {c.kind} | {what} {c.size_m:.3f} m | {c.factor:g} x {ref} "
                    f"{c.reference_m:.3f} m | {start_goal_cells(c)} |")
    return rows


def folder_files(cases, case_yaml, suite_csv, source_md) -> dict[str, str]:
    """file name -> text of every file of a generated suite folder: one map per case (``case_yaml``),
    suite.csv and SOURCE.md (the parking suite's and the trailer suite's)."""
    files = {c.file_name: case_yaml(c) for c in cases}
    files["suite.csv"] = suite_csv(cases)
    files["SOURCE.md"] = source_md(cases)
    return files


def start_goal_cells(case) -> str:
    """A generated case's start and goal poses as two cells of a SOURCE.md table."""
    s, g = case.start, case.goal
    return f"({s[0]:.2f}, {s[1]:.2f}, {s[2]:.2f}) | ({g[0]:.2f}, {g[1]:.2f}, {g[2]:.3f})"


#: a car's name in the map names of a suite of one's own car
_CAR_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,39}")


def own_car(spec, where: str = "--robot-config", name: str | None = None) -> dict:
    """``{name: robot description}``: one's own car for :func:`suite`. ``spec`` is a robot description
    (a mapping, as a map's ``robot:`` block) of an ``rwd_car`` (the suite's formulas take the rear axle as
    the reference point) with a rectangular footprint around the rear axle. Its name: ``name``, else its
    ``name`` key (letters, digits and _, at most 40, starting with a letter: it goes into the map
    names). Its planning margin: its own ``margin`` if it states one, else the suite's
    (:data:`SUITE_MARGIN`). Errors name ``where`` and the key."""
    if not isinstance(spec, dict):
        raise InputError(where, "a robot description (a mapping with model: rwd_car, its parameters and a "
                         "rectangular footprint)", type(spec).__name__)
    if spec.get("model") != "rwd_car":
        raise InputError(f"{where}.model", "rwd_car (the parking suite's formulas take the rear axle as the "
                         "reference point)", spec.get("model", "missing"))
    robot = robot_from_spec(spec, where)
    try:
        geo = CarGeometry.from_robot(robot)
    except InputError as exc:
        raise exc.renamed(f"{where}.footprint") from None
    bay_side = geo.width / 2 + BAY_EXTRA_WIDTH          # the bays' neighbour, from the bay's centre line
    if geo.min_turning_radius < bay_side:
        raise InputError(f"{where}.max_steer", "a turning radius wheelbase / tan(max_steer) of at least half the "
                         f"car's width + {BAY_EXTRA_WIDTH:g} m = {bay_side:.3g} m (the suite's bays are sized for "
                         "a car that turns wider than its bay)", float(robot.model.max_steer),
                         detail=f"radius {geo.min_turning_radius:.3g} m")
    car_name = name if name is not None else spec.get("name")
    if not isinstance(car_name, str) or not _CAR_NAME.fullmatch(car_name):
        raise InputError("--name" if name is not None else f"{where}.name",
                         "a car name of letters, digits and _ (at most 40, starting with a letter: it goes into "
                         "the map names)", "missing" if car_name is None else car_name)
    out = dict(spec)
    out["name"] = car_name
    out.setdefault("margin", SUITE_MARGIN)
    return {car_name: out}


def own_source_md(cases: list[Case], specs: dict, command: str) -> str:
    """SOURCE.md of a suite of one's own car: what made it, the car, the references and the cases."""
    lines = ["# parking suite of one's own car", "",
             f"Generated, with `suite.csv` and the maps, by `{command}`: the parking suite's layouts",
             "(`nhstab.parking`, the same as the bundled suite's: see its SOURCE.md in nhstab's `maps/parking/`)",
             "sized from the geometry of the car below. Do not edit by hand: regenerate with that command.",
             "nhstab YAML maps: metres, radians, x right, y up. Each map carries the car as its `robot:` block.", "",
             "## The car", "", *_car_table(specs)]
    lines += ["", "L1 = b + sqrt(2 R w + (L + f)^2) is the single-maneuver minimum parallel slot (bumper to bumper);",
              "A90 = sqrt((R + w/2)^2 + (L + f)^2) - sqrt((R - w/2)^2 - (R - c)^2) the swept-path aisle of a",
              "reverse-in perpendicular bay (c = bay width - w/2); angled aisles are multiples of a numeric",
              "swept-path estimate. Parallel slots are "
              + ", ".join(f"{f:g}" for f in PARALLEL_FACTORS) + " x L1; perpendicular aisles "
              + ", ".join(f"{f:g}" for f in PERPENDICULAR_AISLE_FACTORS) + " x A90; 45 and 60 degree aisles "
              + " and ".join(f"{f:g}" for f in ANGLED_AISLE_FACTORS) + " x their estimate.", "",
              "## The cases", "",
              "| map | car | kind | size | = factor x reference | start | goal |", "|---|---|---|---|---|---|---|"]
    lines += _case_rows(cases)
    lines += ["", "`suite.csv` lists the same with full precision; `nhstab parking study --suite FOLDER` studies them.", ""]
    return "\n".join(lines)


def own_suite_files(specs: dict, command: str) -> dict[str, str]:
    """file name -> text of every file of a suite of one's own car (:func:`own_car`), made by ``command``."""
    cases = suite(specs)
    return folder_files(cases, lambda c: case_yaml(c, command), suite_csv,
                        lambda cs: own_source_md(cs, specs, command))


def suite_files(cases: list[Case] | None = None) -> dict[str, str]:
    """file name -> text of every file of the suite folder."""
    return folder_files(suite() if cases is None else cases, case_yaml, suite_csv, source_md)


def write_suite(out, check: bool = False, specs: dict | None = None, command: str | None = None) -> dict:
    """Write the suite into the folder ``out`` (atomically, file by file), or with ``check`` only
    compare: returns {"written" | "differ": [...], "missing": [...], "extra": [...]}. With ``specs``
    (:func:`own_car`): the suite of that car, made by ``command``."""
    files = suite_files() if specs is None else own_suite_files(specs, command or "nhstab parking suite")
    return write_generated(out, files, check)


# ---- the figure of the tightest parallel maneuver ---------------------------------------------------

def tightest_parallel_run(car: str = "rwd_car", seeds=(0, 1, 2), opts=None, folder=None, progress=None):
    """``nhstab run`` (the composite controller, default noise and gramian law unless ``opts`` say
    otherwise) on the bundled parallel slots of ``car``, tightest first, each with ``seeds`` in turn,
    until one reaches the goal. Returns (case row, seed, RunResult or None, tried): ``tried`` lists
    every attempt with its status, so the figure's caption can say what failed before it."""
    from dataclasses import replace


    if folder is None:
        folder = data_root() / "parking"
    folder = Path(folder)
    rows = sorted((r for r in read_suite_csv(folder / "suite.csv") if r["kind"] == "parallel" and r["car"] == car),
                  key=lambda r: r["factor"])
    if not rows:
        raise InputError("car", "a car of the parking suite (" + ", ".join(cars()) + ")", car)
    base = opts or RunOptions()
    tried = []
    for row in rows:
        m = load_map(folder / f"{row['name']}.yaml")
        robot = robot_from_spec(m.robot, source="map")
        for seed in seeds:
            result = execute(m, robot, m.start.as_array(), m.goal.as_array(), replace(base, seed=int(seed)))
            tried.append({"map": row["name"], "factor": row["factor"], "seed": int(seed), "status": result.status})
            if progress is not None:
                progress(f"{row['name']} seed {seed}: {result.status}")
            if result.status == "reached":
                return row, int(seed), result, tried
    return None, None, None, tried
