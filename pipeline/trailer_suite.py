"""The trailer suite (``nhstab trailer suite``): dock bays entered in reverse and 90 degree turns from an
aisle into a corridor, sized from the geometry of the car with a trailer that drives them.

A rig here is the car of ``car_trailer`` towing one trailer (:class:`RigGeometry`): the car's
wheelbase L, width w0, body reaching a0 ahead of and b0 behind its rear axle; the hitch at the car's
rear axle, the trailer's axle d behind it; the trailer's width w1, body reaching a1 ahead of and b1
behind its axle; the steering limit and the jackknife limit.

**The swept-path estimate.** On a steady turn every body rotates about one centre C. The car's rear
axle runs on a circle of radius R0, the trailer's axle on one of radius R1, and the bar from the hitch
to the trailer's axle is tangent to the trailer axle's circle, so R0^2 = R1^2 + d^2 and the hitch
angle is atan(d / R1). The physical minimum is the smallest R1 that both limits allow
(:attr:`nhstab.models.car_trailer.CarTrailer.min_turning_radius`): R0 >= L / tan(max_steer) and
atan(d / R1) <= jackknife_limit. In each body's frame (x forward from its axle, y to the left, a left
turn) C lies at (0, R_i), and the body is the rectangle [-b_i, a_i] x [-w_i/2, w_i/2]. Its farthest
point from C is an outer corner at the longer end,

    r_out,i = sqrt((R_i + w_i/2)^2 + max(a_i, b_i)^2),

and its nearest point the foot of the perpendicular from C onto the inner side, at the axle when the
body spans it (-b_i <= 0 <= a_i), else the inner corner nearest the axle:

    r_in,i = sqrt((R_i - w_i/2)^2 + c_i^2),   c_i = clamp(0, -b_i, a_i).

The swept path of the steady turn is the annulus between r_in = min_i r_in,i and r_out = max_i r_out,i,
and its width is the estimate

    S = r_out - r_in,

in practice the car's outer front corner (off-tracking outward) minus the trailer's inner side at its
axle (off-tracking inward). For the built-in rig (L 2.5 m, max_steer 0.6 rad, d 3 m, car 4.2 x 1.8 m
with b0 0.9 m, trailer 2.5 x 1.8 m with b1 1.0 m): R0 = 3.654 m, R1 = 2.086 m, r_out = 5.624 m,
r_in = 1.186 m, S = 4.438 m. tests/test_trailer_suite.py checks S against the model: the steady
turn integrated, the bodies' union over a full circle measured with shapely.

**Dock bays** (:func:`dock_case`). A dock wall with doors at a pitch P; rigs stand at the doors,
straight, the trailer's rear ``DOCK_SETBACK`` from the wall, the car's nose to the aisle. The free
door's bay, between the two parked rigs beside it, is G = 2 P - W wide (W the rig's width), and the
suite sets G = factor x W for :data:`BAY_FACTORS`. ``NEIGHBOURS_EACH_SIDE`` rigs are parked either
side, and blocks close the row beyond them. The aisle in front of the row, whose line the parked
rigs' noses touch, is A = factor x S wide for :data:`AISLE_FACTORS`, with a wall across it. The rig
starts in the aisle, on its centre line, before the row, heading along it; its goal is the free bay,
trailer first.

**Turns** (:func:`turn_case`). An aisle along x and a corridor along y meet at a right angle (an L:
a wall along the aisle's far side and the corridor's outer side, a block in the inner corner), both
factor x S wide for :data:`TURN_FACTORS`. The rig starts in the aisle heading along it and ends in
the corridor heading along it, forward.

The rig of every case is the built-in ``car_trailer`` with its parameters written out and the suite's
planning margin :data:`SUITE_MARGIN` (the map's ``robot:`` block; the turning radius and the
stabilizer are the robot's defaults). :func:`write_suite` writes the maps, ``suite.csv`` and
``SOURCE.md``.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass

import numpy as np

from .errors import InputError
from .parking import Box, _num, folder_files, generated_map_yaml, start_goal_cells
from .records import write_generated
from .robot import default_robot, robot_from_spec

#: dock bays: the gap between the parked rigs beside the free door, as multiples of the rig's width
BAY_FACTORS = (1.1, 1.2, 1.3, 1.5)
#: the dock's aisle widths, as multiples of the swept-path estimate S
AISLE_FACTORS = (1.2, 1.5, 2.0)
#: the turns' aisle and corridor widths, as multiples of S
TURN_FACTORS = (1.2, 1.5, 2.0)
#: the suite's planning margin [m]: below the 0.09 m a rig keeps to each neighbour in a 1.1 x width bay
SUITE_MARGIN = 0.05

# layout [m]
DOCK_SETBACK = 0.3          # the parked trailers' rears (and the goal's) from the dock wall
NEIGHBOURS_EACH_SIDE = 2    # parked rigs either side of the free door
WALL = 0.5                  # thickness of walls
LEAD = 4.0                  # aisle beyond the row's ends, and before the turn, beyond the rig's length
START_GAP = 1.0             # the start's trailer rear from the map's edge (and the turn goal's nose)


@dataclass(frozen=True)
class RigGeometry:
    """A car towing one trailer (hitch at the car's rear axle): the two rectangles, each referenced to
    its axle, and the limits that fix the smallest steady turn."""

    wheelbase: float            # L [m]
    hitch: float                # d [m], hitch (the car's rear axle) to the trailer's axle
    car_width: float            # w0 [m]
    car_front: float            # a0 [m], car body ahead of its rear axle
    car_rear: float             # b0 [m], car body behind its rear axle
    trailer_width: float        # w1 [m]
    trailer_front: float        # a1 [m], trailer body ahead of its axle
    trailer_rear: float         # b1 [m], trailer body behind its axle
    max_steer: float            # rad
    jackknife_limit: float      # rad

    @classmethod
    def from_robot(cls, robot) -> "RigGeometry":
        model = robot.model
        if model.name != "car_trailer" or robot.trailers != 1:
            raise InputError("robot", "a car_trailer with one trailer", f"{model.name} with {robot.trailers} trailers")
        (a0, b0, w0), (a1, b1, w1) = (_rectangle(fp, which) for fp, which in
                                      zip(robot.footprints, ("footprint", "trailer_footprint")))
        return cls(float(model.wheelbase), float(model.hitch_lengths[0]), w0, a0, b0, w1, a1, b1,
                   float(model.max_steer), float(model.jackknife_limit))

    @property
    def width(self) -> float:
        """W [m]: the rig's width (the wider body)."""
        return max(self.car_width, self.trailer_width)

    @property
    def length(self) -> float:
        """The straight rig's length [m], from the car's nose to the farthest rear point."""
        return self.car_front + max(self.car_rear, self.hitch + self.trailer_rear)

    def steady_turn(self) -> tuple[float, float, float]:
        """(R0, R1, hitch angle) of the tightest steady turn: the car's rear axle radius, the trailer
        axle's, atan(d / R1)."""
        d = self.hitch
        r0_min = self.wheelbase / math.tan(self.max_steer)
        r1 = math.sqrt(max(r0_min ** 2 - d * d, (d / math.tan(self.jackknife_limit)) ** 2))
        return math.hypot(r1, d), r1, math.atan2(d, r1)

    def swept_radii(self, r1: float | None = None) -> tuple[float, float]:
        """(r_in, r_out) of the steady turn whose trailer axle runs at ``r1`` (default: the tightest)."""
        if r1 is None:
            _, r1, _ = self.steady_turn()
        r0 = math.hypot(r1, self.hitch)
        bodies = ((r0, self.car_front, self.car_rear, self.car_width),
                  (r1, self.trailer_front, self.trailer_rear, self.trailer_width))
        outer = max(math.hypot(R + w / 2, max(a, b)) for R, a, b, w in bodies)
        inner = min(math.hypot(max(R - w / 2, 0.0), min(max(0.0, -b), a)) for R, a, b, w in bodies)
        return inner, outer

    def swept_path(self, r1: float | None = None) -> float:
        """S [m]: the width of the steady turn's swept annulus (module docstring)."""
        inner, outer = self.swept_radii(r1)
        return outer - inner


def _rectangle(fp, key: str) -> tuple[float, float, float]:
    """(ahead, behind, width) of an axis-aligned rectangle footprint, symmetric about the body's axis."""
    v = None if fp.vertices is None else np.asarray(fp.vertices, dtype=float)
    if v is None or len(v) != 4:
        raise InputError(key, "a rectangle (4 vertices) for the trailer suite's rig", fp.label or "a disc")
    xs, ys = np.unique(np.round(v[:, 0], 12)), np.unique(np.round(v[:, 1], 12))
    if len(xs) != 2 or len(ys) != 2 or abs(ys[0] + ys[1]) > 1e-9:
        raise InputError(key, "an axis-aligned rectangle, symmetric about the body's axis", v.tolist())
    return float(xs[1]), float(-xs[0]), float(ys[1] - ys[0])


def rig_spec() -> dict:
    """The suite's rig: the built-in car_trailer, every parameter written out, with the suite's margin
    (the turning radius and the stabilizer left to the robot's defaults)."""
    robot = default_robot("car_trailer")
    g = RigGeometry.from_robot(robot)
    params = robot.model.params()
    return {"model": "car_trailer", "name": "rig",
            **{k: params[k] for k in ("wheelbase", "hitch_lengths", "max_speed", "max_steer", "max_steer_rate",
                                      "jackknife_limit")},
            "footprint": {"rectangle": {"length": g.car_front + g.car_rear, "width": g.car_width,
                                        "rear_overhang": g.car_rear}},
            "trailer_footprint": {"rectangle": {"length": g.trailer_front + g.trailer_rear, "width": g.trailer_width,
                                                "rear_overhang": g.trailer_rear}},
            "margin": SUITE_MARGIN}


def rig_geometry(spec: dict | None = None) -> RigGeometry:
    return RigGeometry.from_robot(robot_from_spec(rig_spec() if spec is None else spec))


# ---- the cases ------------------------------------------------------------------------------------

@dataclass
class Case:
    """One problem of the trailer suite."""

    name: str
    kind: str                 # dock | turn
    bay_factor: float | None  # dock: bay gap / rig width
    aisle_factor: float       # aisle (and corridor) width / S
    bay_m: float | None       # dock: the free bay's gap between the parked rigs [m]
    aisle_m: float            # aisle width [m] (a turn's corridor is as wide)
    width_m: float            # W, the rig's width [m]
    swept_m: float            # S, the swept-path estimate [m]
    bounds: tuple
    obstacles: list           # of Box
    start: tuple              # the car's rear axle, heading; the trailer straight behind
    goal: tuple
    robot: dict
    description: str

    @property
    def file_name(self) -> str:
        return f"{self.name}.yaml"


def _parked_rig(g: RigGeometry, x: float, y_car: float, heading: float, label: str) -> list[Box]:
    """The two bodies of a straight rig whose car's rear axle is at (x, y_car), as boxes."""
    c, s = math.cos(heading), math.sin(heading)
    out = []
    for along, a, b, w, what in ((0.0, g.car_front, g.car_rear, g.car_width, "car"),
                                 (-g.hitch, g.trailer_front, g.trailer_rear, g.trailer_width, "trailer")):
        mid = along + (a - b) / 2
        out.append(Box(x + c * mid, y_car + s * mid, a + b, w, heading, f"{label}: {what}"))
    return out


def dock_case(bay_factor: float, aisle_factor: float, spec: dict | None = None) -> Case:
    """Reverse into a free dock bay of ``bay_factor`` x W between parked rigs, off an aisle of
    ``aisle_factor`` x S (module docstring)."""
    spec = rig_spec() if spec is None else spec
    g = rig_geometry(spec)
    W, S = g.width, g.swept_path()
    gap, aisle = bay_factor * W, aisle_factor * S
    pitch = (gap + W) / 2
    y_dock = DOCK_SETBACK + g.length                       # the aisle line (the parked noses) at y = 0
    y_car = y_dock - DOCK_SETBACK - g.trailer_rear - g.hitch
    n = NEIGHBOURS_EACH_SIDE
    x_left = g.length + LEAD                               # the left row-end block ends here
    # the outermost parked rig's outer side is (pitch - W) from the block, like the gaps between rigs
    xc = x_left + (pitch - W) + W / 2 + n * pitch
    x_right = xc + n * pitch + W / 2 + (pitch - W)
    x_max = x_right + g.length + LEAD
    obstacles = [Box(x_max / 2, y_dock + WALL / 2, x_max, WALL, 0.0, "dock wall"),
                 Box(x_left / 2, y_dock / 2, x_left, y_dock, 0.0, "row end"),
                 Box((x_right + x_max) / 2, y_dock / 2, x_max - x_right, y_dock, 0.0, "row end"),
                 Box(x_max / 2, -aisle - WALL / 2, x_max, WALL, 0.0, "wall across the aisle")]
    for j in range(-n, n + 1):
        if j:
            obstacles += _parked_rig(g, xc + j * pitch, y_car, -math.pi / 2, f"parked at door {j:+d}")
    start = (START_GAP + g.trailer_rear + g.hitch, -aisle / 2, 0.0)
    goal = (xc, y_car, -math.pi / 2)
    desc = (f"The rig ({W:g} m wide, swept path S = {S:.2f} m) reverses its trailer into a dock bay {gap:.2f} m "
            f"= {bay_factor:g} x its width between parked rigs, off an aisle {aisle:.2f} m = {aisle_factor:g} x S; "
            "start in the aisle.")
    name = f"trailer_dock_bay{round(100 * bay_factor):03d}_aisle{round(100 * aisle_factor):03d}"
    return Case(name, "dock", bay_factor, aisle_factor, gap, aisle, W, S,
                (0.0, -aisle - WALL, x_max, y_dock + WALL), obstacles, start, goal, spec, desc)


def turn_case(factor: float, spec: dict | None = None) -> Case:
    """Drive from an aisle into a corridor at a right angle, both ``factor`` x S wide (module docstring)."""
    spec = rig_spec() if spec is None else spec
    g = rig_geometry(spec)
    W, S = g.width, g.swept_path()
    width = factor * S
    x_c = g.length + LEAD                                 # the corridor's inner side
    x_max = x_c + width + WALL
    y_top = width + g.length + LEAD
    obstacles = [Box(x_max / 2, -WALL / 2, x_max, WALL, 0.0, "wall along the aisle"),
                 Box(x_c + width + WALL / 2, (y_top - WALL) / 2, WALL, y_top + WALL, 0.0, "wall along the corridor"),
                 Box(x_c / 2, (width + y_top) / 2, x_c, y_top - width, 0.0, "inner corner block")]
    start = (START_GAP + g.trailer_rear + g.hitch, width / 2, 0.0)
    goal = (x_c + width / 2, y_top - START_GAP - g.car_front, math.pi / 2)
    desc = (f"The rig ({W:g} m wide, swept path S = {S:.2f} m) turns 90 degrees from an aisle into a corridor, both "
            f"{width:.2f} m = {factor:g} x S wide; start in the aisle, goal in the corridor.")
    name = f"trailer_turn_{round(100 * factor):03d}"
    return Case(name, "turn", None, factor, None, width, W, S, (0.0, -WALL, x_max, y_top), obstacles, start, goal,
                spec, desc)


def suite() -> list[Case]:
    """Every case: dock bays (each bay factor at each aisle factor), then the turns."""
    return ([dock_case(b, a) for b in BAY_FACTORS for a in AISLE_FACTORS]
            + [turn_case(f) for f in TURN_FACTORS])


# ---- files ------------------------------------------------------------------------------------------

def case_yaml(case: Case) -> str:
    """The case as an nhstab YAML map."""
    size = (f"bay {case.bay_m:.6f} m = {case.bay_factor:g} x W = {case.bay_factor:g} x {case.width_m:g} m, "
            if case.kind == "dock" else "") + \
        f"aisle {case.aisle_m:.6f} m = {case.aisle_factor:g} x S = {case.aisle_factor:g} x {case.swept_m:.6f} m"
    lines = [f"# {case.file_name} -- generated by `nhstab trailer suite --out maps/trailer/suite` (nhstab.trailer_suite);",
             "# do not edit by hand: change pipeline/trailer_suite.py and regenerate. See SOURCE.md in this folder.",
             f"# {case.kind}: {size}"]
    return generated_map_yaml(lines, case)


CSV_COLUMNS = ("name", "kind", "bay_factor", "aisle_factor", "bay_m", "aisle_m", "width_m", "swept_m", "start_x",
               "start_y", "start_theta", "goal_x", "goal_y", "goal_theta", "description")


def suite_csv(cases: list[Case]) -> str:
    buf = io.StringIO()
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(CSV_COLUMNS)
    for c in cases:
        w.writerow([c.name, c.kind, "" if c.bay_factor is None else f"{c.bay_factor:g}", f"{c.aisle_factor:g}",
                    "" if c.bay_m is None else _num(c.bay_m), _num(c.aisle_m), _num(c.width_m), _num(c.swept_m),
                    *(_num(v) for v in c.start), *(_num(v) for v in c.goal), c.description])
    return buf.getvalue()


def read_suite_csv(path) -> list[dict]:
    """The rows of a trailer suite.csv (numbers as floats; a turn's bay entries None)."""
    with open(path, encoding="utf-8", newline="") as fh:
        rows = list(csv.DictReader(fh))
    for r in rows:
        for k in CSV_COLUMNS:
            if k not in ("name", "kind", "description"):
                r[k] = float(r[k]) if r[k] != "" else None
    return rows


def source_md(cases: list[Case]) -> str:
    """SOURCE.md of the suite folder: where the maps come from, the formula, the table."""
    g = rig_geometry()
    r0, r1, hitch = g.steady_turn()
    r_in, r_out = g.swept_radii()
    S = g.swept_path()
    lines = ["# trailer/suite — the trailer suite", "",
             "Generated, with `suite.csv` and this file, by `nhstab trailer suite --out maps/trailer/suite` from the",
             "geometry in `pipeline/trailer_suite.py` (`nhstab.trailer_suite`); do not edit by hand. Original to",
             "nhstab, same licence as nhstab (BSD-3-Clause). nhstab YAML maps: metres, radians, x right, y up.", "",
             "## The rig", "",
             "The built-in `car_trailer` (every parameter written out in each map's `robot:` block, the turning",
             f"radius and the stabilizer left to the robot's defaults) with a planning margin of {SUITE_MARGIN:g} m, "
             "below the",
             f"{(BAY_FACTORS[0] - 1) * g.width / 2:.2f} m it keeps to each neighbour in the narrowest bay.", "",
             "| wheelbase L | hitch d | car (a0 + b0) x w0 | trailer (a1 + b1) x w1 | max_steer | jackknife limit "
             "| rig width W | rig length |", "|---|---|---|---|---|---|---|---|",
             f"| {g.wheelbase:g} m | {g.hitch:g} m | ({g.car_front:g} + {g.car_rear:g}) x {g.car_width:g} m | "
             f"({g.trailer_front:g} + {g.trailer_rear:g}) x {g.trailer_width:g} m | {g.max_steer:g} rad | "
             f"{g.jackknife_limit:g} rad | {g.width:g} m | {g.length:g} m |", "",
             "## The swept-path estimate S", "",
             "On a steady turn every body rotates about one centre; the car's rear axle runs at R0, the trailer's",
             "axle at R1 with R0^2 = R1^2 + d^2 (the bar is tangent to the trailer axle's circle) and hitch angle",
             "atan(d / R1). The tightest turn has R0 = L / tan(max_steer), unless the jackknife limit binds first",
             "(R1 >= d / tan(jackknife_limit)). Each body, the rectangle [-b, a] x [-w/2, w/2] in its frame with",
             "the centre at (0, R), reaches out to an outer corner and in to its inner side at the axle:", "",
             "    r_out = max over bodies of sqrt((R + w/2)^2 + max(a, b)^2)",
             "    r_in  = min over bodies of sqrt((R - w/2)^2 + clamp(0, -b, a)^2)",
             "    S     = r_out - r_in", "",
             f"For this rig: R0 = {r0:.3f} m, R1 = {r1:.3f} m, hitch angle {hitch:.3f} rad; r_out = {r_out:.3f} m (the "
             f"car's outer front corner), r_in = {r_in:.3f} m (the trailer's inner side at its axle): "
             f"**S = {S:.3f} m**.",
             "`tests/test_trailer_suite.py` checks S against the steady turn integrated with the model and",
             "measured with shapely.", "",
             "## Dock bays", "",
             f"A dock wall along the top; doors at a pitch P, rigs standing at them straight, the trailer's rear "
             f"{DOCK_SETBACK:g} m",
             "from the wall, the car's nose to the aisle; the free door's bay, between the two rigs parked beside",
             f"it, is G = 2 P - W wide, and G = {', '.join(f'{f:g}' for f in BAY_FACTORS)} x W. "
             f"{NEIGHBOURS_EACH_SIDE} rigs are parked either side (each body a",
             "box of its own size), blocks close the row beyond them (P - W from the last rig), and the aisle in",
             "front of the row (the parked noses flush with its line) is A = "
             f"{', '.join(f'{f:g}' for f in AISLE_FACTORS)} x S wide, with a wall",
             "across it. The start: in the aisle on its centre line before the row, heading along it, the trailer",
             f"straight behind, its rear {START_GAP:g} m from the map's edge. The goal: the free bay, trailer first.", "",
             "## Turns", "",
             "An aisle along x and a corridor along y meet at a right angle (an L: walls along the aisle's far",
             "side and the corridor's outer side, a block in the inner corner), both "
             f"{', '.join(f'{f:g}' for f in TURN_FACTORS)} x S wide. The start:",
             "in the aisle heading along it; the goal: in the corridor heading along it, forward, the car's nose",
             f"{START_GAP:g} m from the map's edge.", "",
             "## The cases", "",
             "| map (example:NAME) | kind | bay | aisle | start | goal |", "|---|---|---|---|---|---|"]
    for c in cases:
        bay = "-" if c.kind != "dock" else f"{c.bay_m:.3f} m = {c.bay_factor:g} x W"
        lines.append(f"| `{c.name}` | {c.kind} | {bay} | {c.aisle_m:.3f} m = {c.aisle_factor:g} x S | "
                     f"{start_goal_cells(c)} |")
    lines += ["", "`suite.csv` lists the same with full precision. `tests/test_trailer_suite.py` checks that the",
              "committed files equal the generator's output, that every bay and aisle is its factor times W or S",
              "and that no obstacle touches the start's or the goal's rig (shapely).", ""]
    return "\n".join(lines)


def suite_files(cases: list[Case] | None = None) -> dict[str, str]:
    """file name -> text of every file of the suite folder."""
    return folder_files(suite() if cases is None else cases, case_yaml, suite_csv, source_md)


def write_suite(out, check: bool = False) -> dict:
    """Write the suite into the folder ``out``, or with ``check`` only compare: returns
    {"written" | "differ": [...], "missing": [...], "extra": [...]}."""
    return write_generated(out, suite_files(), check)
