"""Car paths where parking is hard: unparking maneuvers at the lock angle, joined by OMPL's search.

A car that parks in a tight slot or bay moves back and forth at full lock; a sampling planner in the
Reeds-Shepp space hardly ever finds such a narrow passage. Following Paromtchik and Laugier
(ICRA 1996), the planner instead *unparks*: from a confined end pose (the goal in its slot, or a
start in one) it drives out with maneuvers of its own, and the search only has to join the poses
where the car is out. The path to a confined goal is the time-reversed unparking path (a car's path
driven backwards with the same steering is a path of the car).

The unparking tree from a pose P (:func:`unparking_tree`):

1. straight runs forward and backward from P, as far as they stay free by the margin (at most 1.5
   car lengths); their poses every ``branch_spacing_m`` are branch points, P first, then the
   farthest (``far_branches_first``);
2. from each branch point, for both lock sides and both first directions, alternating arcs at the
   *lock* steering angle: forward with lock to one side, backward with lock to the other, ... (both
   turn the car the same way), each as far as it stays free (stopping ``maneuver_buffer_m`` short of
   what blocks it where there is room; at most a quarter turn), at most ``max_arcs`` arcs;
3. a pose is *out* when it is in the open (clearance ``open_clearance_m``, surely so by the distance
   field), or on a corridor (a free straight run of 1.5 car lengths from a cusp, or from where an
   arc has turned a multiple of 45 degrees from P's heading), or at the end of the opposite-lock arc
   that turns the car back to P's heading from a pose in the open (the S-shaped way out of a
   parallel slot). A sequence ends when the car is out or an arc is blocked at once; the tree stops
   when ``escaped_enough`` poses are out or after ``max_tree_poses`` checked poses.

Where the tree gets nowhere (slots shorter than the single-maneuver length L1), the shuffle search
(:func:`shuffle_search`) looks for a way out with short lock moves, including a change of lock while
driving on, the sideways shuffle.

:func:`car_paths` joins the two sides: ends with room are searched for directly first; then direct
local paths between the cheapest pairs of candidates; then OMPL with several start states and a
``GoalStates`` goal (backwards from the confined side), the cheapest candidates first, at the
robot's planning turning radius and then at the lock radius; further paths on request (new seeds,
trees with the other branch order). :func:`_finish` joins the legs, shortens the result with free
local paths where that is faster, and records the whole path's exact segments for the car's nominal
(:func:`nhstab.planning.cars.exact_nominal`).

**Steering authority.** The maneuvers steer at phi_lock = max_steer - ``steering_reserve_rad``
(default 0.05 rad: for the default rwd_car 0.55 rad, a turning radius of 4.08 m = 1.12 R_min), not
at the end stop: the feedback law adds its own steering to the nominal's and the plant stops the
steering angle at max_steer, so a nominal at the end stop would leave the feedback no way to turn
tighter when the car drifts outwards. The searched connections keep the robot's planning radius
(1.25 R_min) where they can, and go down to the lock radius only where the planning radius finds
no path.

**The full steering range, where the reserved lock finds nothing.** A slot or passage may need more
than the reserved lock gives. Where the maneuvers at the reserved lock get nowhere (neither the
unparking tree nor the shuffle search gets out), that side's tree and shuffle search run again at the
end stop (phi = max_steer, R_min); where no connection is found at the reserved lock, the search runs
once more with the full range: the maneuvers at the end stop and the connections at R_min, with
``full_range_share`` of the budget that was left for the last search at the lock radius. The path's
``info["lock"]`` records the lock angle and radius its maneuvers use and whether the full range was
used; the nominal then has no steering reserve on those segments (``metrics["steering_reserve"]``
of :func:`nhstab.planning.plan` lists the times).
"""
from __future__ import annotations

import math
import time
from dataclasses import dataclass, field, replace

import numpy as np

from ..clearance_field import disc_cover
from ..collision import CollisionWorld
from ..errors import InputError
from ..geometry import Footprint, wrap_angle
from ..models import Model
from .geometric import GeometricPath, PathOptions, local_length, local_path, local_segments, path_directions, plan_path

#: samples of the exact maneuvers and of the joined path [m] (as the geometric paths are sampled)
SAMPLE_STEP = 0.005
#: how a car's nominal follows its path: "exact" (each segment with its steering held, steering in
#: place between) or "sinusoidal" (Laumond-Murray chained-form pieces, :func:`nhstab.planning.cars.car_nominal`)
NOMINALS = ("exact", "sinusoidal")


@dataclass(frozen=True)
class CarOptions:
    """Options of the car planner's unparking maneuvers (see the module docstring).

    steering_reserve_rad: the maneuvers steer at max_steer minus this; max_arcs: arcs per unparking
    sequence; straight_reach_m: how far the straight runs reach (None: 1.5 car lengths);
    branch_spacing_m: branch points along them; open_clearance_m: ends with at least this clearance
    are planned for directly first (the search without maneuvers) with ``direct_share`` of the
    budget; default_radius_share: the share of the remaining search budget spent at the planning
    turning radius before the lock radius; candidates: open poses per side given to the search.
    """

    steering_reserve_rad: float = 0.05
    max_arcs: int = 8
    straight_reach_m: float | None = None
    branch_spacing_m: float = 0.5
    candidate_spacing_m: float = 0.5
    open_clearance_m: float = 0.75
    direct_share: float = 0.5
    default_radius_share: float = 0.3
    candidates: int = 48
    escaped_enough: int = 12
    first_candidates: int = 8
    shuffle_step_m: float = 0.1
    shuffle_grid_m: float = 0.03
    shuffle_cusp_s: float = 0.5
    shuffle_expansions: int = 3000
    shuffle_guidance_s_per_m: float = 20.0
    max_tree_poses: int = 4000
    direct_pairs: int = 8
    arc_speed_mps: float | None = None
    min_arc_m: float = 0.1
    maneuver_buffer_m: float = 0.1
    far_branches_first: bool = True
    attempts: int = 4
    nominal: str = "exact"
    probe_share: float = 0.1
    full_range: bool = True
    full_range_share: float = 0.4

    def validated(self) -> "CarOptions":
        def num(key, lo, hi=math.inf, lo_open=False):
            v = getattr(self, key)
            ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
            if not ok or (v <= lo if lo_open else v < lo) or v > hi:
                raise InputError(f"car.{key}", f"a finite number {'>' if lo_open else '>='} {lo:g}"
                                 + ("" if hi == math.inf else f" and <= {hi:g}"), v)

        num("steering_reserve_rad", 0.0)
        if self.nominal not in NOMINALS:
            raise InputError("car.nominal", "one of " + ", ".join(NOMINALS), self.nominal)
        num("branch_spacing_m", 0.0, lo_open=True)
        num("candidate_spacing_m", 0.0, lo_open=True)
        num("shuffle_step_m", 0.0, lo_open=True)
        num("shuffle_grid_m", 0.0, lo_open=True)
        num("shuffle_cusp_s", 0.0)
        num("shuffle_guidance_s_per_m", 0.0)
        num("open_clearance_m", 0.0)
        num("direct_share", 0.0, 1.0)
        num("probe_share", 0.0, 1.0)
        num("default_radius_share", 0.0, 1.0)
        num("full_range_share", 0.0, 1.0)
        if not isinstance(self.full_range, bool):
            raise InputError("car.full_range", "true or false", self.full_range)
        if self.straight_reach_m is not None:
            num("straight_reach_m", 0.0)
        if self.arc_speed_mps is not None:
            num("arc_speed_mps", 0.0, lo_open=True)
        num("min_arc_m", 0.0)
        num("maneuver_buffer_m", 0.0)

        for key in ("max_arcs", "candidates", "escaped_enough", "first_candidates", "max_tree_poses", "direct_pairs",
                    "attempts", "shuffle_expansions"):
            v = getattr(self, key)
            if not isinstance(v, (int, np.integer)) or isinstance(v, bool) or v < 1:
                raise InputError(f"car.{key}", "a positive integer", v)
        return self


# ---------------------------------------------------------------------------------------------
# exact maneuvers: segments driven with the steering angle held
# ---------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Segment:
    """A run with the steering angle ``phi`` held: ``direction`` +1 forward / -1 reverse, ``length`` [m]."""

    direction: int
    phi: float
    length: float

    def reversed(self) -> "Segment":
        return Segment(-self.direction, self.phi, self.length)


def segment_poses(pose, seg: Segment, wheelbase: float, s) -> np.ndarray:
    """Rear-axle poses (..., 3) after driving distances ``s`` (>= 0) along ``seg`` from ``pose``:
    theta = theta0 + kappa u, with u = direction s and kappa = tan(phi) / L; on an arc
    x = x0 + (sin theta - sin theta0) / kappa, y = y0 - (cos theta - cos theta0) / kappa, evaluated as
    the chord x = x0 + u c cos(theta0 + kappa u / 2), y = y0 + u c sin(theta0 + kappa u / 2) with
    c = sin(kappa u / 2) / (kappa u / 2): the same numbers without the cancellation of the quotient
    form on nearly straight arcs (kappa -> 0), where it is the straight line."""
    x0, y0, th0 = (float(v) for v in pose)
    u = seg.direction * np.asarray(s, dtype=float)
    k = math.tan(seg.phi) / wheelbase
    half = 0.5 * k * u
    chord = u * np.sinc(half / np.pi)              # np.sinc(x) = sin(pi x) / (pi x)
    mid = th0 + half
    return np.stack([x0 + chord * np.cos(mid), y0 + chord * np.sin(mid), th0 + k * u], axis=-1)


@dataclass(frozen=True)
class Maneuver:
    """Segments driven one after the other from ``start``."""

    start: np.ndarray
    segments: tuple = ()
    wheelbase: float = 1.0

    @property
    def end(self) -> np.ndarray:
        pose = np.asarray(self.start, dtype=float)
        for seg in self.segments:
            pose = segment_poses(pose, seg, self.wheelbase, seg.length)
        return pose

    @property
    def length(self) -> float:
        return float(sum(seg.length for seg in self.segments))

    @property
    def cusps(self) -> int:
        d = [seg.direction for seg in self.segments]
        return int(sum(a != b for a, b in zip(d[:-1], d[1:])))

    def then(self, seg: Segment) -> "Maneuver":
        return replace(self, segments=self.segments + (seg,))

    def reversed(self) -> "Maneuver":
        """The same motion driven backwards in time: from the end to the start."""
        return Maneuver(self.end, tuple(seg.reversed() for seg in reversed(self.segments)), self.wheelbase)

    def sampled(self, step: float = SAMPLE_STEP):
        """(samples (S, 3) from start to end, arc length (S,), runs [(i0, i1, phi, direction)]): each
        segment's sample index range."""
        out, sig, runs = [np.asarray(self.start, dtype=float)[None, :]], [np.zeros(1)], []
        pose, offset, count = np.asarray(self.start, dtype=float), 0.0, 1
        for seg in self.segments:
            if seg.length <= 0:
                continue
            n = max(1, int(math.ceil(seg.length / step)))
            s = seg.length * np.arange(1, n + 1) / n
            pts = segment_poses(pose, seg, self.wheelbase, s)
            out.append(pts)
            sig.append(offset + s)
            runs.append((count - 1, count - 1 + n, float(seg.phi), int(seg.direction)))
            count += n
            offset += seg.length
            pose = pts[-1]
        return np.vstack(out), np.concatenate(sig), runs


# ---------------------------------------------------------------------------------------------
# the unparking tree
# ---------------------------------------------------------------------------------------------
@dataclass
class Candidate:
    """An open pose the unparking tree reached from its root, and how (``maneuver``)."""

    pose: np.ndarray
    maneuver: Maneuver
    cost_s: float = 0.0                 # estimated time: driving at the speed limit, steering at each cusp
    #: on a run that got out: an arc that ran its whole quarter turn, or a straight of a car length
    escaped: bool = False


@dataclass
class Tree:
    root: np.ndarray
    candidates: list = field(default_factory=list)
    arcs: int = 0
    poses_checked: int = 0
    time_s: float = 0.0


class _Driver:
    """Drives segments from a pose as far as they stay free (checked in chunks, stops at the first
    blocked pose)."""

    CHUNK = 12

    def __init__(self, world: CollisionWorld, fp: Footprint, margin: float, wheelbase: float, step: float):
        self.world, self.fp, self.margin, self.L, self.step = world, fp, margin, wheelbase, step
        self.checked = 0

    def free_length(self, pose, direction: int, phi: float, cap: float, margin: float | None = None) -> float:
        """The longest free distance (a multiple of ``step``, at most ``cap``) along the segment. The
        poses are checked in chunks that double in size (a run blocked at once costs one small check,
        a long free one few calls)."""
        n_total = int(math.floor(cap / self.step + 1e-9))
        done, chunk = 0, self.CHUNK
        while done < n_total:
            n = min(chunk, n_total - done)
            s = self.step * np.arange(done + 1, done + n + 1)
            free = self.world.free_many(segment_poses(pose, Segment(direction, phi, 0.0), self.L, s), self.fp,
                                        self.margin if margin is None else margin)
            self.checked += n
            if not free.all():
                return self.step * (done + int(np.argmin(free)))
            done += n
            chunk *= 2
        return self.step * n_total if n_total else 0.0


def unparking_tree(world: CollisionWorld, fp: Footprint, model: Model, root, margin: float, open_margin: float,
                   opts: CarOptions, speed: float, enough: int | None = None) -> Tree:
    """The unparking tree from ``root`` (module docstring): its open candidates, those that got out
    first, each group cheapest first. Branch points are expanded nearest first; the tree stops
    growing once ``enough`` candidates got out (default: ``opts.escaped_enough``)."""
    started = time.perf_counter()
    enough = opts.escaped_enough if enough is None else enough
    L = float(model.wheelbase)
    phi_lock = float(model.max_steer) - opts.steering_reserve_rad
    r_lock = lock_radius(model, opts)
    reach = fp.bounding_radius
    # sample so that no footprint point moves more than ~5 cm between checked poses
    step = min(0.05, 0.05 * r_lock / max(reach, 1e-9))
    drive = _Driver(world, fp, margin, L, step)
    length = float(np.ptp(fp.vertices[:, 0])) if fp.radius is None else 2 * fp.radius
    straight_reach = opts.straight_reach_m if opts.straight_reach_m is not None else 1.5 * length
    arc_cap = 0.5 * math.pi * r_lock
    steer_time = 2 * phi_lock / float(model.max_steer_rate)
    root = np.asarray(root, dtype=float)
    tree = Tree(root)
    base = Maneuver(root, (), L)
    min_move = max(2 * step, opts.min_arc_m)

    def cost(man: Maneuver) -> float:
        return man.length / speed + man.cusps * steer_time + (steer_time if man.segments else 0.0)

    def collect(found: list):
        """Keep the open ones of the poses reached (pose, maneuver, escaped)."""
        if not found:
            return
        P = np.array([f[0] for f in found])
        ok = world.free_many(P, fp, open_margin)
        drive.checked += len(P)
        out = in_open(P)         # in the open: out, however it got there
        tree.candidates.extend(Candidate(P[k], found[k][1], cost(found[k][1]), bool(found[k][2] or out[k]))
                               for k in np.flatnonzero(ok))

    def along(found: list, man: Maneuver, d: int, phi: float, s: float, escaped: bool):
        """Poses along a run every ~candidate_spacing_m (its end included) are candidates."""
        parts = max(1, int(round(s / opts.candidate_spacing_m)))
        for f in np.arange(1, parts + 1) / parts:
            part = man.then(Segment(d, phi, f * s))
            found.append((part.end, part, escaped))

    # branch points along the straight runs, nearest first (the root first)
    ahead = []
    for d in (1, -1):
        s_free = drive.free_length(root, d, 0.0, straight_reach)
        n = int(math.floor(s_free / opts.branch_spacing_m + 1e-9))
        dist = [k * opts.branch_spacing_m for k in range(1, n + 1)]
        if s_free > n * opts.branch_spacing_m + min_move:
            dist.append(s_free)
        ahead += [(x, d) for x in dist]
    # the root, then the branch points farthest out first (out of a bay the car drives straight
    # before it turns; in a slot the straight runs are short anyway)
    branches = [base] + [base.then(Segment(d, 0.0, x)) for x, d in sorted(ahead, reverse=opts.far_branches_first)]
    escape_straight = length                  # a free straight run this long gets the car out
    field = world.clearance_field()
    k_lock = math.tan(phi_lock) / L
    room = max(open_margin, opts.open_clearance_m)

    def in_open(P):
        if field is None:
            return np.array([world.clearance(q, fp) >= room for q in P])
        return field.surely_free(P, fp, room)

    def aligned(found: list, man: Maneuver, d: int, phi: float, s: float):
        """Poses in the open where the arc's heading is aligned with the root's or turned from it by a
        multiple of 45 degrees (along a lane or an aisle), and, from up to two open poses along the
        arc turned less than 54 degrees from the root, the arc of the opposite lock in the same
        direction that turns the car back to the root's heading (the S-shaped way out of a parallel
        slot): the car is out there."""
        start = man.end
        rate = d * math.tan(phi) / L                       # dtheta / dsigma along this arc
        dev0 = float(wrap_angle(start[2] - root[2]))
        hits = []
        for q in range(-2, 3):
            target = q * math.pi / 4
            sigma = (target - dev0) / rate if abs(rate) > 1e-12 else -1.0
            if 0.0 < sigma <= s:
                hits.append(sigma)
        if hits:
            P = segment_poses(start, Segment(d, phi, 0.0), L, np.array(hits))
            for sig, ok, p_ in zip(hits, in_open(P), P):
                part = man.then(Segment(d, phi, sig))
                if ok:
                    found.append((part.end, part, True))
                    continue
                # aligned with a corridor (an aisle narrower than the open room): a free straight run
                # of 1.5 car lengths along it
                for ds in (1, -1):
                    run = drive.free_length(p_, ds, 0.0, straight_reach)
                    if run >= straight_reach - step:
                        found.append((part.end, part, True))
                        along(found, part, ds, 0.0, run, True)
                        break
        parts = max(1, int(round(s / opts.candidate_spacing_m)))
        sig = s * np.arange(1, parts + 1) / parts
        P = segment_poses(start, Segment(d, phi, 0.0), L, sig)
        tried = 0
        for sg, p_, ok in zip(sig, P, in_open(P)):
            dev = float(wrap_angle(p_[2] - root[2]))
            if not ok or abs(dev) < 0.05 or abs(dev) > 0.3 * math.pi or tried >= 2:
                continue
            tried += 1
            back = abs(dev) / k_lock                        # the opposite lock, same direction: dev -> 0
            run = drive.free_length(p_, d, -phi, back)
            if run >= back - step:
                first_part = man.then(Segment(d, phi, float(sg)))
                along(found, first_part, d, -phi, back, True)


    for b in branches:
        found = [(b.end, b, False)]
        for side in (1, -1):
            for first in (1, -1):
                man, pose = b, b.end
                for k in range(opts.max_arcs):
                    d = first * (-1) ** k
                    phi = side * phi_lock * (-1) ** k
                    # stop short of what blocks the arc where there is room (a cusp pose at the margin
                    # leaves the feedback nothing), else as far as the margin allows
                    s = drive.free_length(pose, d, phi, arc_cap, margin + opts.maneuver_buffer_m)
                    if s < min_move and opts.maneuver_buffer_m > 0:
                        s = drive.free_length(pose, d, phi, arc_cap)
                    tree.arcs += 1
                    if s < min_move:
                        break
                    out = s >= arc_cap - step              # ran its whole quarter turn: the car is out
                    along(found, man, d, phi, s, out)
                    aligned(found, man, d, phi, s)
                    man = man.then(Segment(d, phi, s))
                    pose = man.end
                    if out:
                        break
                    # from the cusp, a straight run that reaches the open, or runs free for 1.5 car
                    # lengths (along an aisle or a lane, however narrow), gets it out
                    for ds in (-d, d):
                        run = drive.free_length(pose, ds, 0.0, straight_reach)
                        if run >= escape_straight:
                            parts = max(1, int(round(run / opts.candidate_spacing_m)))
                            sig = run * np.arange(1, parts + 1) / parts
                            along_free = run >= straight_reach - step
                            if along_free or in_open(segment_poses(pose, Segment(ds, 0.0, 0.0), L, sig)).any():
                                along(found, man, ds, 0.0, run, along_free)
                                out = True
                    if out or drive.checked > opts.max_tree_poses:
                        break
                if drive.checked > opts.max_tree_poses:
                    break
            if drive.checked > opts.max_tree_poses:
                break
        collect(found)
        tree.branches = getattr(tree, "branches", 0) + 1
        if sum(c.escaped for c in tree.candidates) >= enough or drive.checked > opts.max_tree_poses:
            break
    # the candidates that got out first, each group cheapest first
    tree.candidates.sort(key=lambda c: (not c.escaped, c.cost_s))
    tree.poses_checked = drive.checked
    tree.time_s = time.perf_counter() - started
    return tree


def shuffle_search(world: CollisionWorld, fp: Footprint, model: Model, root, margin: float, open_margin: float,
                   opts: CarOptions, speed: float, deadline: float = math.inf) -> Tree:
    """Unparking by short moves, where the full-lock tree finds no way out (slots shorter than the
    single-maneuver length): a best-first search over moves of ``shuffle_step_m`` forward or
    backward with the steering at the lock angle to either side, from ``root``, poses merged on a
    lattice of ``shuffle_grid_m`` and 0.02 rad. A move's cost is its time at ``speed`` plus the time to
    steer in place to its angle at the rate limit, plus ``shuffle_cusp_s`` per reversal. Its moves
    include changing the lock while driving on (the sideways shuffle drivers use in tight slots:
    forward left, forward right), which the alternating tree never does.

    The search stops at ``escaped_enough`` poses where the car is out (open by ``open_margin`` and
    with clearance ``open_clearance_m``: surely so by the distance field), after ``shuffle_expansions``
    poses, or at ``deadline``. Merging poses on a lattice can lose the way out of a very tight slot
    (two poses in one cell, only the one dropped can go on; measured: the van of the parking suite in
    its 0.9 x L1 slot exhausts the 3 cm lattice after 246 poses): a search that runs out of poses
    without getting out is repeated on a lattice twice as fine, down to ``shuffle_grid_m`` / 4, while
    the deadline allows. The poses of a batch of the best ``SHUFFLE_BATCH`` open ones are expanded
    together (one collision query for all their moves). Candidates: the poses that got out, each
    with its merged moves as its maneuver."""
    started = time.perf_counter()
    tree = Tree(np.asarray(root, dtype=float))
    expanded = checked = 0
    grid = opts.shuffle_grid_m
    tree.lattices = []
    for level in range(3):
        found, exhausted, n_exp, n_chk = _shuffle(world, fp, model, tree.root, margin, open_margin, opts, speed,
                                                  deadline, grid, opts.shuffle_expansions - expanded)
        expanded += n_exp
        checked += n_chk
        tree.lattices.append({"grid_m": grid, "expanded": n_exp, "escaped": len(found), "exhausted": exhausted})
        tree.candidates = found
        if found or not exhausted or expanded >= opts.shuffle_expansions or time.perf_counter() >= deadline:
            break
        grid /= 2
    tree.arcs, tree.poses_checked = expanded, checked
    tree.candidates.sort(key=lambda c: c.cost_s)
    tree.time_s = time.perf_counter() - started
    return tree


#: open poses of the shuffle search expanded together (one collision query for all their moves)
SHUFFLE_BATCH = 8


def _shuffle(world: CollisionWorld, fp: Footprint, model: Model, root, margin: float, open_margin: float,
             opts: CarOptions, speed: float, deadline: float, g: float, budget: int):
    """One best-first shuffle search on a lattice of ``g`` m and 0.02 rad (see :func:`shuffle_search`):
    (candidates, exhausted: no open pose left, poses expanded, poses checked)."""
    import heapq


    L = float(model.wheelbase)
    phi_lock = float(model.max_steer) - opts.steering_reserve_rad
    rate = float(model.max_steer_rate)
    h = opts.shuffle_step_m
    n_sub = max(1, int(math.ceil(h / 0.05 - 1e-9)))
    sub = h * np.arange(1, n_sub + 1) / n_sub
    # lock moves only: straight moves are the unparking tree's (its branches)
    prims = [(d, p) for d in (1, -1) for p in (phi_lock, -phi_lock)]
    n_prim = len(prims)
    field = world.clearance_field()
    centres, radii = disc_cover(fp)
    centres, radii = np.asarray(centres, dtype=float).reshape(-1, 2), np.asarray(radii, dtype=float)
    target = max(open_margin, opts.open_clearance_m)

    def key(p):
        return (int(round(p[0] / g)), int(round(p[1] / g)), int(round(p[2] / 0.02)))

    def h_cost(P):
        """Greedy guidance towards room: the clearance still missing at poses P (a lower bound by the
        distance field and the footprint's disc cover), in seconds (A* with an inadmissible heuristic:
        a way out, not the shortest one)."""
        if field is None:
            return np.zeros(len(P))
        c, s_ = np.cos(P[:, 2])[:, None], np.sin(P[:, 2])[:, None]
        xs = P[:, 0, None] + c * centres[:, 0] - s_ * centres[:, 1]
        ys = P[:, 1, None] + s_ * centres[:, 0] + c * centres[:, 1]
        low = np.min(field.at(xs, ys) - radii, axis=1)
        return opts.shuffle_guidance_s_per_m * np.maximum(0.0, target - low)

    def is_out(P):
        if field is not None:
            return field.surely_free(P, fp, target)
        return np.array([world.clearance(p, fp) >= opts.open_clearance_m for p in P])

    def maneuver(k):
        moves = []
        while k in parent:
            pk, _, d, ph = parent[k]
            moves.append(Segment(d, ph, h))
            k = pk
        segs = []
        for seg in reversed(moves):
            if segs and segs[-1].direction == seg.direction and segs[-1].phi == seg.phi:
                segs[-1] = Segment(seg.direction, seg.phi, segs[-1].length + seg.length)
            else:
                segs.append(seg)
        return Maneuver(root, tuple(segs), L)

    root = np.asarray(root, dtype=float)
    k0 = key(root)
    best = {k0: 0.0}
    parent = {}                                  # key -> (parent key, pose, d, phi)
    heap = [(float(h_cost(root[None, :])[0]), 0, k0, tuple(root), 0, 0.0, 0.0)]
    counter, expanded, checked = 1, 0, 0
    found: list = []
    while heap and expanded < budget and len(found) < opts.escaped_enough and time.perf_counter() < deadline:
        batch = []
        while heap and len(batch) < SHUFFLE_BATCH:
            item = heapq.heappop(heap)
            if best.get(item[2], math.inf) >= item[6] - 1e-12:
                batch.append(item)
        if not batch:
            break
        expanded += len(batch)
        P = np.array([it[3] for it in batch])
        out = is_out(P)
        out[[it[2] == k0 for it in batch]] = False
        for it, o in zip(batch, out):
            if o:
                man = maneuver(it[2])
                found.append(Candidate(man.end, man, it[6], True))
        batch = [it for it, o in zip(batch, out) if not o]
        if not batch:
            continue
        # every move of every pose of the batch: the moves' ends first, then the way there
        poses = np.stack([np.concatenate([segment_poses(np.array(it[3]), Segment(d, ph, 0.0), L, sub)
                                          for d, ph in prims]) for it in batch]).reshape(len(batch), n_prim, n_sub, 3)
        ends = poses[:, :, -1].reshape(-1, 3)
        free = world.free_many(ends, fp, margin).reshape(len(batch), n_prim)
        checked += len(ends)
        if n_sub > 1 and free.any():
            inner = poses[free][:, :-1].reshape(-1, 3)
            free[free] = world.free_many(inner, fp, margin).reshape(int(free.sum()), n_sub - 1).all(axis=1)
            checked += len(inner)
        bi, pi = np.nonzero(free)
        if not len(bi):
            continue
        Q = poses[bi, pi, -1]
        hq = h_cost(Q)
        for b, p_, q, hh in zip(bi, pi, Q, hq):
            _, _, k, _, last_d, last_phi, cost = batch[b]
            d, ph = prims[p_]
            c = cost + h / speed + abs(ph - last_phi) / rate + (opts.shuffle_cusp_s if last_d and d != last_d else 0.0)
            kq = key(q)
            if c < best.get(kq, math.inf) - 1e-12:
                best[kq] = c
                parent[kq] = (k, q, d, ph)
                heapq.heappush(heap, (c + float(hh), counter, kq, tuple(q), d, ph, c))
                counter += 1
    exhausted = not heap and len(found) < opts.escaped_enough
    return found, exhausted, expanded, checked


# ---------------------------------------------------------------------------------------------
# the car planner's path: direct, unparking maneuvers, search
# ---------------------------------------------------------------------------------------------
def lock_radius(model: Model, opts: CarOptions) -> float:
    """The maneuvers' turning radius L / tan(max_steer - reserve)."""
    phi = float(model.max_steer) - opts.steering_reserve_rad
    if phi <= 0:
        raise InputError("car.steering_reserve_rad", f"below the car's max_steer {model.max_steer:g} rad",
                         opts.steering_reserve_rad)
    return model.turning_radius_at(phi)


def car_paths(world: CollisionWorld, fp: Footprint, model: Model, start, goal, opts: PathOptions, pad: float,
              search_margin: float, clearances: dict, parking: CarOptions | None = None,
              speed: float | None = None, info: dict | None = None):
    """A car's geometric paths from start to goal, best guess first (module docstring): exact
    maneuvers at the ends where needed, a searched connection between them. A generator: each next
    path is another solution (the next direct pair, or a search with the next seed), for a caller
    that wants a better one; it stops when ``opts.time_limit_s`` (from the first call) is spent.

    ``opts.margin`` is the margin every pose keeps; the searched connections between open poses keep
    ``pad`` more (the car's local planner strays a little from them); ``search_margin`` is the margin
    the search keeps when it starts or ends at the given start or goal themselves
    (:func:`nhstab.planning.search_margin`); ``clearances``: the start's and goal's clearance.
    ``info`` (a dict) collects what was done: the stages, their times, the radii and margins."""
    parking = (parking or CarOptions()).validated()
    started = time.perf_counter()
    # the searches end early enough for the caller to make a nominal of what they found: the caller
    # may set info["reserve_s"] (default: 15 % of the budget, at most 1 s) and update it as it learns
    info = {} if info is None else info
    info.setdefault("reserve_s", min(0.15 * float(opts.time_limit_s), 1.0))
    end_of_budget = started + float(opts.time_limit_s)
    speed = speed or float(model.max_speed)
    r_default = float(opts.turning_radius)
    r_lock = min(lock_radius(model, parking), r_default)
    radii = [r_default] if r_lock >= r_default - 1e-9 else [r_default, r_lock]
    open_margin = float(opts.margin) + pad
    phi_lock = float(model.max_steer) - parking.steering_reserve_rad
    # the full steering range (module docstring): only where the reserved lock finds nothing
    full = replace(parking, steering_reserve_rad=0.0)
    r_full = min(lock_radius(model, full), r_default)
    can_widen = parking.full_range and parking.steering_reserve_rad > 0 and r_full < r_lock - 1e-9
    info.update({"stages": [], "lock_radius_m": r_lock, "search_margin_m": search_margin,
                 "open_margin_m": open_margin, "validity_calls": 0, "validity_time_s": 0.0,
                 "lock": {"reserve_rad": float(parking.steering_reserve_rad), "angle_rad": phi_lock,
                          "radius_m": r_lock, "full_range": False, "full_range_angle_rad": float(model.max_steer),
                          "full_range_radius_m": r_full, "widened": []}})
    seeds = iter(range(opts.seed, opts.seed + 1_000_000))

    def left() -> float:
        return end_of_budget - info["reserve_s"] - time.perf_counter()

    def shortcut(a, b):
        """A free local path a -> b (a Leg) at the planning radius, else the lock radius; or None."""
        for radius in radii:
            o = replace(opts, margin=search_margin, turning_radius=radius)
            coarse, _, _ = local_path(o, a, b, step=min(0.05, o.resolution))
            if _all_free(world, coarse, fp, search_margin):
                return _local_leg(o, a, b, float(model.wheelbase), "shortcut")
        return None

    def run_ompl(a, b, radius, budget, margin, more_starts=(), more_goals=()):
        o = replace(opts, margin=margin, turning_radius=radius, time_limit_s=max(budget, 1e-3), seed=next(seeds))
        p = plan_path(world, fp, a, b, o, more_starts=more_starts, more_goals=more_goals)
        info["stages"].append({"stage": "search", "radius_m": radius, "margin_m": margin, "budget_s": budget,
                               "seed": o.seed, "status": p.status, "planner_status": p.planner_status,
                               "starts": 1 + len(more_starts), "goals": 1 + len(more_goals),
                               "time_s": p.planning_time_s})
        info["validity_calls"] += p.validity_calls
        info["validity_time_s"] += p.validity_time_s
        return p

    # 1. ends with room: the search without maneuvers, as for any map
    if min(clearances.values()) >= parking.open_clearance_m:
        p = run_ompl(start, goal, r_default, parking.direct_share * float(opts.time_limit_s), search_margin)
        if p.status == "exact":
            yield _finish(p, p.waypoints, None, None, info, started, "search", model)
    # 2. the candidates of each side. An end with room (clearance open_clearance_m) is its own only
    # candidate; an end on a corridor (a free straight run of 1.5 car lengths ahead or behind) too at
    # first, with its unparking tree grown only if the search from it fails; a confined end gets its
    # unparking tree at once.
    L = float(model.wheelbase)
    length = float(np.ptp(fp.vertices[:, 0])) if fp.radius is None else 2 * fp.radius
    sides, lazy = {}, set()
    for key, pose in (("start", start), ("goal", goal)):
        root = np.asarray(pose, dtype=float)
        sides[key] = [Candidate(root, Maneuver(root, (), L), 0.0, True)]
        is_open = bool(world.free_many(root[None, :], fp, open_margin)[0])
        if is_open and clearances[key] >= parking.open_clearance_m:
            continue
        if is_open:
            runs = [_Driver(world, fp, opts.margin, L, 0.05).free_length(root, d, 0.0, 1.5 * length) for d in (1, -1)]
            if max(runs) >= 1.5 * length - 0.05:
                lazy.add(key)
                continue
        sides[key] = None

    grown = set()

    def grow(key, options=None, shuffle=True, widened=False):
        pose = start if key == "start" else goal
        grown.add(key)
        t = unparking_tree(world, fp, model, np.asarray(pose, dtype=float), opts.margin, open_margin,
                           options or parking, speed)
        info["stages"].append({"stage": f"unparking {key}" + (" (full steering range)" if widened else ""),
                               "branches": getattr(t, "branches", 0), "arcs": t.arcs,
                               "poses_checked": t.poses_checked, "open_candidates": len(t.candidates),
                               "escaped": sum(c.escaped for c in t.candidates), "time_s": t.time_s})
        if not any(c.escaped for c in t.candidates) and (options is None or widened) and shuffle:
            t.candidates = shuffled(key, options if widened else None) + t.candidates
        root = np.asarray(pose, dtype=float)
        # a side without open poses searches from its end itself, at the margin the end allows
        return t.candidates[: parking.candidates] or [Candidate(root, Maneuver(root, (), L), 0.0, True)]

    def shuffled(key, options=None):
        """The shuffle search's candidates from the side's end; it gets at most half of what is left
        (the connection needs the rest)."""
        pose = np.asarray(start if key == "start" else goal, dtype=float)
        sh = shuffle_search(world, fp, model, pose, opts.margin, open_margin, options or parking, speed,
                            deadline=time.perf_counter() + 0.5 * max(left(), 0.0))
        info["stages"].append({"stage": f"shuffle {key}" + (" (full steering range)" if options is not None else ""),
                               "expanded": sh.arcs, "poses_checked": sh.poses_checked,
                               "escaped": len(sh.candidates), "lattices": sh.lattices, "time_s": sh.time_s})
        return sh.candidates

    def widen(key):
        """The side's maneuvers at the full steering range (its tree, and its shuffle search if the
        tree gets nowhere), their candidates first, then the reserved lock's."""
        more = grow(key, full, widened=True)
        sides[key] = ([c for c in more if c.escaped] + sides[key] + [c for c in more if not c.escaped])[
            : 2 * parking.candidates]
        info["lock"]["widened"].append(key)

    def search_margin_now():
        return open_margin if all(world.free_many(np.array([c.pose for c in sides[k]]), fp, open_margin).all()
                                  for k in sides) else search_margin

    # 4. (defined here, used below) OMPL between the two sides' open poses, each radius in turn; then
    # further searches with new seeds at the radius that worked. RRTConnect puts every start state in
    # its tree at once but takes goal states in one by one, growing the goal tree from each before it
    # takes the next, so a first goal state in a slot can stall it: the side with more candidates (the
    # confined end's) gives the start states, and the search runs backwards when that is the goal side
    # (a Reeds-Shepp path driven backwards is one; a Dubins path is not, so Dubins searches run
    # forwards). The goal states are ordered by clearance, the most open first.
    def search(radius, budget, few: int | None = None):
        S, G = sides["start"], sides["goal"]
        if few is not None:          # the cheapest candidates only (those that got out first)
            S, G = S[:few], G[:few]
        backwards = opts.space != "dubins" and len(G) > len(S)
        A, B = (G, S) if backwards else (S, G)
        B = sorted(B, key=lambda c: -world.clearance(c.pose, fp)) if len(B) > 1 else B
        p = run_ompl(A[0].pose, B[0].pose, radius, budget, margin, [c.pose for c in A[1:]], [c.pose for c in B[1:]])
        if p.status != "exact":
            return None
        a_end, b_end = A[p.info["start_index"]], B[p.info["goal_index"]]
        if backwards:
            return _finish(p, p.waypoints[::-1], b_end.maneuver, a_end.maneuver, info, started, "search", model, shortcut,
                           backwards=True)
        return _finish(p, p.waypoints, a_end.maneuver, b_end.maneuver, info, started, "search", model, shortcut)

    stuck = set()
    for key in ("start", "goal"):
        if sides[key] is None:
            sides[key] = grow(key, shuffle=False)
            if not any(c.escaped for c in sides[key]):
                stuck.add(key)
    # the trees' open poses are worth a probe where some got at least half a car length from their end
    # (out of a bay into an aisle); in a slot shorter than L1 they all stay inside it
    reached = {k: max((float(np.hypot(*(c.pose[:2] - c.maneuver.start[:2]))) for c in sides[k]), default=0.0)
               for k in stuck}
    margin = search_margin_now()
    worked = None
    if stuck and left() > 0 and min(reached.values()) >= 0.5 * length:
        # No unparking sequence got out (into the open or onto a corridor). Out of a bay off a narrow
        # aisle the tree's open poses are out all the same (the open room of 0.75 m is not there to
        # reach): a short search from them first (probe_share of the budget); only if it finds nothing,
        # the shuffle search (slots shorter than L1), whose way out is added to the candidates.
        found = search(r_default, min(left(), parking.probe_share * float(opts.time_limit_s)))
        info["stages"][-1]["probe"] = True
        if found is not None:
            worked = r_default
            stuck = set()
            yield found
    if stuck and worked is None:
        for key in sorted(stuck):
            sides[key] = (shuffled(key) + sides[key])[: parking.candidates]
            if can_widen and not any(c.escaped for c in sides[key]) and left() > 0:
                # the reserved lock found no way out of this end: the full steering range there
                widen(key)
        margin = search_margin_now()
    S, G = sides["start"], sides["goal"]
    # 3. direct local paths between the cheapest pairs (maneuvers plus the local path's estimated
    # time), at each radius; each free one is a solution
    for radius in radii:
        o = replace(opts, margin=margin, turning_radius=radius)
        pairs = sorted((cs.cost_s + cg.cost_s + local_length(o, cs.pose, cg.pose) / speed, i, j)
                       for i, cs in enumerate(S[: parking.direct_pairs]) for j, cg in enumerate(G[: parking.direct_pairs]))
        tried = found = 0
        t0 = time.perf_counter()
        for _, i, j in pairs[: parking.direct_pairs]:
            if left() <= 0:
                return
            samples, _, _ = local_path(o, S[i].pose, G[j].pose, step=min(0.05, o.resolution))
            tried += 1
            if _all_free(world, samples, fp, margin):
                found += 1
                p = _path_from_waypoints(o, np.array([S[i].pose, G[j].pose]), "Exact solution (direct connection)",
                                         "direct")
                info["stages"].append({"stage": "direct", "radius_m": radius, "pairs_tried": tried, "found": True,
                                       "time_s": time.perf_counter() - t0})
                yield _finish(p, p.waypoints, S[i].maneuver, G[j].maneuver, info, started, "direct", model, shortcut)
                t0 = time.perf_counter()
        info["stages"].append({"stage": "direct", "radius_m": radius, "pairs_tried": tried, "found": False,
                               "time_s": time.perf_counter() - t0})
    if lazy and worked is None:        # the corridor ends as they are, with a share of the budget, before their trees
        found = search(r_default, left() * parking.default_radius_share)
        if found is not None:
            worked = r_default
            yield found
        else:
            for key in sorted(lazy):
                sides[key] = grow(key)
            margin = open_margin if all(world.free_many(np.array([c.pose for c in sides[k]]), fp, open_margin).all()
                                        for k in sides) else search_margin
    if worked is None and max(len(sides["start"]), len(sides["goal"])) > parking.first_candidates:
        # the cheapest candidates first: the search joins whichever it reaches, and these make the
        # shortest maneuvers
        found = search(r_default, left() * parking.default_radius_share * 0.5, parking.first_candidates)
        if found is not None:
            worked = r_default
            yield found
    if worked is None:
        for k, radius in enumerate(list(radii)):
            last = 1.0 - (parking.full_range_share if can_widen and r_full not in radii else 0.0)
            budget = left() * (parking.default_radius_share if k < len(radii) - 1 else last)
            if budget <= 0:
                return
            found = search(radius, budget)
            if found is not None:
                worked = radius
                yield found
                break
    if worked is None and can_widen and r_full not in radii and left() > 0:
        # nothing at the reserved lock: the full steering range, maneuvers and connections
        for key in sorted(k for k in sides if k in grown and k not in info["lock"]["widened"]):
            widen(key)
        radii.append(r_full)
        margin = search_margin_now()
        found = search(r_full, left())
        if found is not None:
            worked = r_full
            yield found
    if worked is None:
        info["failure"] = ("no connection between the open poses of the unparking maneuvers (turning radii "
                           f"{', '.join(f'{r:.4g}' for r in radii)} m)")
        return
    # another path was asked for (the last was not worth tracking): the trees again with their branch
    # points nearest first (shorter straight runs at the ends, which keep the end of the gain schedule
    # low), searched first on their own, then together with the first trees' candidates
    if grown and left() > 0:
        other = replace(parking, far_branches_first=not parking.far_branches_first)
        first = {k: list(sides[k]) for k in sides}
        for key in sorted(grown):
            sides[key] = [c for c in grow(key, other) if c.escaped] or first[key]
        found = search(worked, left() * 0.5)
        if found is not None:
            yield found
        for key in sorted(grown):
            sides[key] = (sides[key] + first[key])[: 2 * parking.candidates]
    while left() > 0:
        found = search(worked, left())
        if found is None:
            return
        yield found


def failed_path(opts: PathOptions, info: dict, started: float) -> GeometricPath:
    """The "no path" result of :func:`car_paths`, with what was tried."""
    why = info.get("failure", "no path within the time limit")
    last = [s for s in info.get("stages", []) if s.get("stage") == "search"]
    status = last[-1]["planner_status"] if last else "no search"
    return GeometricPath("failed", f"{why}; OMPL: {status}", np.zeros((0, 3)), np.zeros((0, 3)), np.zeros(0),
                         np.zeros(0), 0.0, 0, time.perf_counter() - started, info.get("validity_calls", 0),
                         info.get("validity_time_s", 0.0), opts, {**info, "planner_used": None})


def _all_free(world: CollisionWorld, poses: np.ndarray, fp: Footprint, margin: float, chunk: int = 64) -> bool:
    """Are all poses free by the margin? Checked in chunks, stopping at the first that is not."""
    for k in range(0, len(poses), chunk):
        if not world.free_many(poses[k:k + chunk], fp, margin).all():
            return False
    return True


def _path_from_waypoints(opts: PathOptions, waypoints: np.ndarray, status: str, used: str) -> GeometricPath:
    """A path known by its waypoints only (the legs are sampled by :func:`_finish`)."""
    return GeometricPath("exact", status, np.asarray(waypoints, dtype=float), np.zeros((0, 3)), np.zeros(0),
                         np.zeros(0), 0.0, 0, 0.0, 0, 0.0, opts, {"planner_used": used})


@dataclass
class Leg:
    """A piece of a car path between two poses where a shortcut may join: one segment of a maneuver,
    or one local path (Reeds-Shepp / Dubins) of the search. ``samples`` (S, 3) from its start to its
    end pose, ``sigma`` their arc length from 0, ``segments`` its exact segments."""

    samples: np.ndarray
    sigma: np.ndarray
    segments: list
    kind: str               # "maneuver" | "search" | "shortcut"


def _segments_of(opts: PathOptions, a, b, wheelbase: float) -> list:
    """The local path a -> b as Segments (direction, steering angle, length)."""
    return [Segment(int(d), math.atan(wheelbase * k * d), float(length))
            for d, k, length in local_segments(opts, a, b) if length > 0]


def _local_leg(opts: PathOptions, a, b, wheelbase: float, kind: str) -> Leg:
    """The local path a -> b as a Leg, sampled from its exact segments (closed forms)."""
    segments = _segments_of(opts, a, b, wheelbase)
    samples, sigma, _ = Maneuver(np.asarray(a, dtype=float), tuple(segments), wheelbase).sampled()
    samples[-1] = b if abs(float(wrap_angle(samples[-1, 2] - b[2]))) < 1e-6 else samples[-1]
    return Leg(samples, sigma, segments, kind)


def _maneuver_legs(man) -> list:
    legs = []
    if man is None:
        return legs
    pose = np.asarray(man.start, dtype=float)
    for seg in man.segments:
        if seg.length <= 0:
            continue
        one = Maneuver(pose, (seg,), man.wheelbase)
        samples, sigma, _ = one.sampled()
        legs.append(Leg(samples, sigma, [seg], "maneuver"))
        pose = samples[-1]
    return legs


def _finish(p: GeometricPath, waypoints, start_man, goal_man, info: dict, started: float, how: str, model,
            shortcut=None, backwards: bool = False) -> GeometricPath:
    """One car path: the start side's maneuver, the searched local paths through ``waypoints`` (in the
    direction of travel; ``backwards``: the search ran from the goal side, so each local path is the
    reverse of the one it checked), the goal side's maneuver reversed. ``info["segments"]`` holds the
    whole path's exact segments (direction, steering angle, length) for the car's nominal, and
    ``info["exact_runs"]`` the maneuvers' sample index ranges (i0, i1, phi, direction).

    ``shortcut(a, b)``: a free local path's Leg from pose a to pose b, or None. Where a maneuver was
    used, the path is shortened with it: the earliest pose where a leg starts (a waypoint of the
    search or a cusp of the goal side's maneuver) from which a free local path reaches the goal's
    final straight run (or the goal) faster (driving at the speed limit, steering in place at the
    rate limit) replaces what lies between, and likewise at the start side. A
    maneuver is kept only where the search's local paths cannot do its work; a final (first) straight
    run into the goal (out of the start) is kept, so that the car drives into the goal, not only steers."""
    L = float(model.wheelbase)
    o = p.options
    legs = _maneuver_legs(start_man)
    n_start = len(legs)
    search_legs = []
    for a, b in zip(waypoints[:-1], waypoints[1:]):
        if backwards:         # the checked local path is b -> a: drive it backwards
            leg = _local_leg(o, b, a, L, "search")
            leg = Leg(leg.samples[::-1].copy(), leg.sigma[-1] - leg.sigma[::-1],
                      [seg.reversed() for seg in reversed(leg.segments)], "search")
        else:
            leg = _local_leg(o, a, b, L, "search")
        search_legs.append(leg)
    legs += search_legs
    goal_legs = _maneuver_legs(goal_man.reversed() if goal_man is not None and goal_man.segments else None)
    legs += goal_legs
    cut = {"goal": False, "start": False}
    speed, rate = float(model.max_speed), float(model.max_steer_rate)

    def cost(segs, phi_in, phi_out):
        """Time to drive segments at the speed limit, steering in place between them at the rate limit."""
        t, phi = 0.0, phi_in
        for seg in segs:
            t += seg.length / speed + abs(seg.phi - phi) / rate
            phi = seg.phi
        return t + abs(phi_out - phi) / rate

    def phi_before(i):
        return legs[i - 1].segments[-1].phi if i > 0 else 0.0

    def phi_after(j):
        return legs[j].segments[0].phi if j < len(legs) else 0.0

    def worth(i, j, leg):
        """Is ``leg`` a faster way than legs[i:j]?"""
        old = [seg for lg in legs[i:j] for seg in lg.segments]
        return cost(leg.segments, phi_before(i), phi_after(j)) < cost(old, phi_before(i), phi_after(j)) - 1e-9

    if shortcut is not None and goal_legs:
        tail = len(legs) - 1 if abs(legs[-1].segments[0].phi) < 1e-12 else len(legs)
        target = legs[tail].samples[0] if tail < len(legs) else legs[-1].samples[-1]
        for i in range(n_start, tail):
            leg = shortcut(legs[i].samples[0], target)
            if leg is not None and worth(i, tail, leg):
                legs = legs[:i] + [leg] + legs[tail:]
                cut["goal"] = True
                break
    if shortcut is not None and n_start:
        head = 1 if abs(legs[0].segments[0].phi) < 1e-12 else 0
        source = legs[head].samples[0]
        last = len(legs) - (0 if cut["goal"] or not goal_legs else len(goal_legs))
        for i in range(last, head, -1):
            end = legs[i - 1].samples[-1]
            leg = shortcut(source, end)
            if leg is not None and worth(head, i, leg):
                legs = legs[:head] + [leg] + legs[i:]
                cut["start"] = True
                break
    # one sampled path
    out, sig, runs, segments = [legs[0].samples[:1]], [np.zeros(1)], [], []
    offset, count = 0.0, 1
    for leg in legs:
        gap = np.abs(np.r_[leg.samples[0, :2] - out[-1][-1, :2], wrap_angle(leg.samples[0, 2] - out[-1][-1, 2])]).max()
        if gap > 1e-6:
            raise RuntimeError(f"the path's legs do not meet (gap {gap:.3g})")
        out.append(leg.samples[1:])
        sig.append(offset + leg.sigma[1:])
        if leg.kind == "maneuver":
            seg = leg.segments[0]
            runs.append((count - 1, count - 1 + len(leg.samples) - 1, float(seg.phi), int(seg.direction)))
        count += len(leg.samples) - 1
        offset += float(leg.sigma[-1])
        segments += leg.segments
    samples = np.vstack(out)
    samples[:, 2] = np.unwrap(samples[:, 2])
    sigma = np.concatenate(sig)
    direction, cusps = path_directions(samples)
    starts = [0] + list(np.cumsum([len(leg.samples) - 1 for leg in legs]))
    waypoints_out = samples[starts]
    lock = dict(info["lock"]) if "lock" in info else None
    if lock is not None:            # this path's own: does it steer beyond the reserved lock anywhere?
        lock["widened"] = list(lock.get("widened", []))
        lock["full_range"] = bool(any(abs(seg.phi) > lock["angle_rad"] + 1e-9 for seg in segments))
    info = {**p.info, **info, **({"lock": lock} if lock is not None else {}),
            "stages": [dict(st) for st in info.get("stages", [])],
            "start_maneuver_segments": len(start_man.segments) if start_man is not None else 0,
            "goal_maneuver_segments": len(goal_man.segments) if goal_man is not None else 0,
            "shortcut": cut, "exact_runs": runs, "how": how,
            "segments": [(int(seg.direction), float(seg.phi), float(seg.length)) for seg in segments]}
    info.setdefault("validity_calls", p.validity_calls)
    return GeometricPath("exact", p.planner_status, waypoints_out, samples, sigma, direction, float(sigma[-1]),
                         cusps, time.perf_counter() - started, info.get("validity_calls", p.validity_calls),
                         info.get("validity_time_s", p.validity_time_s), p.options, info)
