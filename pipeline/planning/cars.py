"""Exactly feasible car trajectories along a Reeds-Shepp path.

Two ways. :func:`exact_nominal` (the planner's default) drives the path's arcs and straights as
they are, each with its steering angle held, the car standing still to steer at the rate limit
where the angle changes: the nominal lies on the path. :func:`car_nominal` follows Laumond, Jacobs,
Taix and Murray, smoothing the path with sinusoidal steering (described below); it strays a little
from the path and needs the search to keep room for that.

A Reeds-Shepp path's curvature jumps where its arcs and straights meet, so a car with the steering
angle as a state cannot follow it. Take waypoints along the path (at every cusp, and at most
``spacing`` metres apart), give each the steering angle of the path's curvature there
(phi = atan(L kappa d), d the direction of travel), and join consecutive waypoints with sinusoidal
steering in chained form (``steering``): the steering angle is continuous and every piece ends
exactly at its waypoint.

Consecutive waypoints lie on one side of a cusp, so the local planner's first choice is the
constant-v1 steering (``steer_car(mode="constant_v1")``): the car drives the whole piece in the
path's direction of travel, without reversing. Where the path's curvature jumps inside a run (arc to
straight, or to the opposite arc) the car's continuous steering angle cannot follow it exactly; a
constant-v1 piece steers through the jump within the steering limit when the jump lies at least a
quarter of the piece's length from its ends (at a waypoint, the piece on one side would have to
undo the other side's curvature). So the waypoints of a run are spread evenly (at most ``spacing``
apart) and then moved a third of that away from the jumps. A piece that comes within the margin of
an obstacle, exceeds the steering limit, leaves the chart or would move against the path's direction
is replaced by shorter ones: by three, with a jump it contains in the middle of the middle one, or by
two through the path's midpoint, down to ``min_spacing``. Only a piece that cannot be split further
falls back to the phased sinusoidal steering (``steer_car(mode="phased")``), whose sinusoidal phases
drive back and forth; splitting first keeps the direction reversals to the path's cusps. Each piece
runs as fast as the speed and steering-rate limits allow.

At a cusp the path's curvature reverses over no distance, and at the ends the car is parked with its
wheels straight: there the car steers in place (phi' = omega_s at standstill, at the steering-rate
limit), a short stop (at most 2 max_steer / max_steer_rate seconds) that is brief against the
stabilizer's window for cars.
"""

from __future__ import annotations

import bisect
import math

import numpy as np

from ..collision import CollisionWorld
from ..errors import InputError, PipelineError
from ..geometry import Footprint, wrap_angle
from ..limits import nominal_grid
from ..models import Model
from ..models.base import SteeredCar
from ..nominal import Nominal
from .car_charts import CAR_MODELS, _assemble, _car_inputs, _car_kind, _pose_parts, _theta_phi, from_chained, steer_car
from .geometric import GeometricPath
from .steering import _constant_phase, _constant_v1_phase, _sin_phase
from .timing import TimingOptions


def _steer_phased(model: Model, xa: np.ndarray, xb: np.ndarray):
    """Steer xa -> xb with the phased sinusoids; phases with nothing to correct get (almost) no time, so
    the car never stands still for a whole phase (a dwell longer than the stabilizer's window would
    make its gramian singular)."""
    piece = steer_car(model, xa, xb, T=None)
    effort = []
    for ph in piece.plan.phases:
        if ph.kind == "constant":
            effort.append(abs(ph.v1) + abs(ph.v2))
        else:
            effort.append(abs(ph.a) + abs(ph.b))
    effort = np.asarray(effort, dtype=float)
    idle = effort <= 1e-9 * max(float(effort.max()), 1e-300)
    if idle.any() and not idle.all():
        piece = steer_car(model, xa, xb, T=None, phase_fractions=np.where(idle, 1e-6, 1.0))
    return piece


def direction_reversals(poses, min_run: float = 0.05) -> int:
    """How often a sequence of poses (x, y, theta) of a car's rear axle reverses between runs of at
    least ``min_run`` [m].

    Each step's direction is the sign of its displacement along the heading at its start (as the
    geometric path's directions are found); steps that do not move belong to no run. Runs of one sign
    (length: the steps' chords) shorter than ``min_run`` are dropped and the sign changes between the
    others counted. Applied to a path's dense samples and to a nominal's poses, it counts both the
    same way.
    """
    p = np.asarray(poses, dtype=float)
    d = np.diff(p[:, :2], axis=0)
    step = np.hypot(d[:, 0], d[:, 1])
    along = d[:, 0] * np.cos(p[:-1, 2]) + d[:, 1] * np.sin(p[:-1, 2])
    moving = step > 1e-12
    sign, dist = np.where(along[moving] >= 0, 1, -1), step[moving]
    if not len(sign):
        return 0
    starts = np.flatnonzero(np.concatenate([[True], sign[1:] != sign[:-1]]))
    kept = sign[starts][np.add.reduceat(dist, starts) >= min_run]
    return int(np.count_nonzero(kept[1:] != kept[:-1]))


class _SteerInPlace:
    """The car standing at a pose while its steering angle moves at a constant rate."""

    def __init__(self, model: Model, pose, phi0: float, phi1: float):
        self.model, self.pose, self.phi0, self.phi1 = model, pose, phi0, phi1
        rate = float(model.max_steer_rate)
        duration = abs(phi1 - phi0) / rate * 1.001
        self.rate = (phi1 - phi0) / duration
        self.t = np.array([0.0, duration])
        self.x = np.array([_state(model, pose, phi0), _state(model, pose, phi1)])
        self.max_abs_phi = max(abs(phi0), abs(phi1))
        self.max_speed = 0.0
        self.final_error = np.zeros(model.n)

    def states_at(self, t):
        t = np.asarray(t, dtype=float)
        phi = self.phi0 + self.rate * t
        x = np.broadcast_to(_state(self.model, self.pose, 0.0), t.shape + (self.model.n,)).copy()
        x[..., self.model.state_names.index("phi")] = phi
        return x

    def inputs_at(self, t):
        t = np.asarray(t, dtype=float)
        u = np.zeros(t.shape + (2,))
        u[..., 1] = self.rate
        return u


class _Arc:
    """The car driving a segment with its steering angle held (an arc of curvature tan(phi) / L, or a
    straight) at constant speed: the exact solution of the model, in closed form."""

    def __init__(self, model: Model, pose, phi: float, direction: int, length: float, speed: float):
        self.model, self.pose, self.phi, self.direction = model, np.asarray(pose, dtype=float), float(phi), int(direction)
        self.lay = _car_kind(model)[0]
        L = float(model.wheelbase)
        self.kappa = math.tan(self.phi) / L
        # body (rear-axle) speed: the rwd car's input; the fwd car's front wheels run at s / cos(phi)
        self.body_speed = float(speed) * math.cos(self.phi) if model.front_wheel_drive else float(speed)
        duration = max(float(length) / self.body_speed, 1e-9)
        self.t = np.linspace(0.0, duration, max(2, int(math.ceil(length / 0.05)) + 1))
        self.x = self.states_at(self.t)
        self.max_abs_phi = abs(self.phi)
        self.max_speed = float(speed)
        self.final_error = np.zeros(model.n)

    def _poses(self, t):
        u = self.direction * self.body_speed * np.asarray(t, dtype=float)
        x0, y0, th0 = self.pose
        k = self.kappa
        # the arc as a chord (no cancellation on nearly straight arcs; see parking.segment_poses)
        half = 0.5 * k * u
        chord = u * np.sinc(half / np.pi)
        return x0 + chord * np.cos(th0 + half), y0 + chord * np.sin(th0 + half), th0 + k * u

    def states_at(self, t):
        t = np.asarray(t, dtype=float)
        px, py, th = self._poses(t)
        phi = np.full_like(px, self.phi)
        return _assemble(self.lay, px, py, th, phi)

    def inputs_at(self, t):
        t = np.asarray(t, dtype=float)
        u = np.zeros(t.shape + (2,))
        u[..., 0] = self.direction * self.max_speed
        return u


class _Joined:
    """The pieces one after the other as one trajectory. Many times at once are evaluated on flat
    tables of all the pieces' phases, with the pieces' own closed forms (``steering``), so the
    values are those of the pieces' ``states_at`` / ``inputs_at``; one time goes to its piece."""

    def __init__(self, model: Model, pieces: list):
        self.model, self.pieces = model, pieces
        self.lay, self.L = _car_kind(model)[0], float(model.wheelbase)
        self.lengths = np.array([float(p.t[-1]) for p in pieces])
        self.starts = np.concatenate([[0.0], np.cumsum(self.lengths)])
        self.duration = float(self.starts[-1])
        self._starts_list = self.starts.tolist()
        # per piece: its first phase row and its inner phase boundaries (+inf padded)
        self.first = np.zeros(len(pieces), dtype=int)
        self.bounds = np.full((len(pieces), 2), np.inf)
        # per piece, the chart's map back to the world (steer_car's to_world): origin, cos and sin of
        # its heading, theta(0) and the local theta(0)
        self.frame = np.zeros((len(pieces), 6))
        rows = []       # per phase: kind (0 constant, 3 / 4 sinusoid for z3 / z4, 1 constant v1, -1 a piece
        #                 evaluated by itself: steering in place or a held-steering arc), t0, v1, v2, a, b, w,
        #                 v2_cos, v2_sin, z_start (4)
        for j, p in enumerate(pieces):
            self.first[j] = len(rows)
            if isinstance(p, (_SteerInPlace, _Arc)):     # evaluated by the piece itself
                rows.append([-1, 0.0, 0, 0, 0, 0, 1.0, 0, 0, 0, 0, 0, 0])
                continue
            self.bounds[j, : len(p.plan.phase_times) - 2] = p.plan.phase_times[1:-1]
            alpha = p.frame["heading"]
            th0 = float(_theta_phi(self.lay, p.x0)[0])
            self.frame[j] = [*p.frame["origin"], math.cos(alpha), math.sin(alpha), th0, float(wrap_angle(th0 - alpha))]
            for ph in p.plan.phases:
                kind = {"constant": 0, "constant_v1": 1}.get(ph.kind, ph.k)
                rows.append([kind, ph.t0, ph.v1, ph.v2, ph.a, ph.b, ph.w, ph.v2_cos, ph.v2_sin, *ph.z_start])
        rows = np.array(rows, dtype=float)
        self._held_table(pieces)
        self.all_held = bool(np.all(rows[:, 0] < 0))
        self.kind = rows[:, 0].astype(int)
        self.t0, self.v1, self.v2, self.a, self.b, self.w, self.v2_cos, self.v2_sin = rows[:, 1:9].T
        self.z_start = rows[:, 9:].T                     # (4, rows)
        self._memo = None       # (0 or 1, times, the states or inputs there) not yet asked for

    def states(self, t) -> np.ndarray:
        """Model states at times t (clipped to the span), shape t.shape + (n,) (a scalar t as (1,))."""
        return self._evaluate(t, 0)

    def inputs(self, t) -> np.ndarray:
        """Model inputs at times t (clipped to the span), shape t.shape + (m,)."""
        return self._evaluate(t, 1)

    def _evaluate(self, t, which: int) -> np.ndarray:
        """States (which = 0) or inputs (1). Both come out of one evaluation, and a Nominal asks for
        the states and then the inputs at the same times, so the other one is kept (once) for that."""
        tt = np.atleast_1d(np.asarray(t, dtype=float))
        memo, self._memo = self._memo, None
        if memo is not None and memo[0] == which and memo[1].shape == tt.shape and np.array_equal(memo[1], tt):
            return memo[2]
        if tt.shape == (1,):     # the integrators' scalar calls: no table bookkeeping
            t1 = float(tt[0])
            j = min(max(bisect.bisect_right(self._starts_list, t1) - 1, 0), len(self.pieces) - 1)
            local = min(max(t1 - self._starts_list[j], 0.0), float(self.lengths[j]))
            piece = self.pieces[j]
            val = piece.states_at(local) if which == 0 else piece.inputs_at(local)
            return np.asarray(val, dtype=float).reshape(1, -1)
        both = self._table(tt.reshape(-1))
        both = [val.reshape(tt.shape + val.shape[-1:]) for val in both]
        self._memo = (1 - which, tt.copy(), both[1 - which])
        return both[which]

    def _table(self, tt: np.ndarray):
        j = np.clip(np.searchsorted(self.starts, tt, side="right") - 1, 0, len(self.pieces) - 1)
        local = np.clip(tt - self.starts[j], 0.0, self.lengths[j])
        if self.all_held:             # an exact nominal: arcs and steering in place only
            return self._held(j, local)
        row = self.first[j] + (self.bounds[j, 0] <= local) + (self.bounds[j, 1] <= local)
        kind = self.kind[row]
        tau = local - self.t0[row]
        z = np.empty((len(tt), 4))
        v = np.empty((len(tt), 2))
        for k in (0, 1, 3, 4):
            sel = np.flatnonzero(kind == k)
            if not len(sel):
                continue
            r, ts = row[sel], tau[sel]
            zs = self.z_start[:, r]
            v1, v2, a, b, w = self.v1[r], self.v2[r], self.a[r], self.b[r], self.w[r]
            if k == 0:
                z[sel] = _constant_phase(zs, v1, v2, ts)
                v[sel, 0], v[sel, 1] = v1, v2
            elif k == 1:
                bc, bs = self.v2_cos[r], self.v2_sin[r]
                z[sel] = _constant_v1_phase(zs, v1, v2, bc, bs, w, ts)
                v[sel, 0], v[sel, 1] = v1, v2 + bc * np.cos(w * ts) + bs * np.sin(w * ts)
            else:
                z[sel] = _sin_phase(zs, k, a, b, w, ts)
                v[sel, 0], v[sel, 1] = a * np.sin(w * ts), b * np.cos((k - 2) * w * ts)
        x = np.empty((len(tt), self.model.n))
        u = np.empty((len(tt), self.model.m))
        in_place = kind < 0
        steer = np.flatnonzero(~in_place) if in_place.any() else slice(None)
        zl = z[steer]
        px, py, th, phi = _pose_parts(self.lay, from_chained(self.model, zl))
        ox, oy, ca, sa, th0, th_l0 = self.frame[j[steer]].T
        cx, cy, cth, cphi = _pose_cols(self.model) + [self.lay.phi]
        x[steer, cx], x[steer, cy] = ox + ca * px - sa * py, oy + sa * px + ca * py
        x[steer, cth], x[steer, cphi] = th0 + (th - th_l0), phi
        u[steer] = _car_inputs(self.lay, self.L, zl, v[steer])
        if in_place.any():      # steering in place and held-steering arcs: their own closed forms
            sel = np.flatnonzero(in_place)
            x[sel], u[sel] = self._held(j[sel], local[sel])
        return x, u

    def _held_table(self, pieces: list) -> None:
        """Per piece, the parameters of the closed forms of :class:`_Arc` and :class:`_SteerInPlace`, so
        that :meth:`_held` evaluates all of them at once with the same operations as their
        ``states_at`` / ``inputs_at`` (the same values, bit for bit: tests/control/test_fast_paths.py)."""
        P = len(pieces)
        self.h_arc = np.zeros(P, dtype=bool)        # an arc (else steering in place, or not held)
        self.h_pose = np.zeros((P, 3))
        self.h_speed = np.zeros(P)                  # direction * body speed (arc), rate (steering)
        self.h_kappa = np.zeros(P)                  # the arc's curvature
        self.h_phi = np.zeros(P)                    # held angle (arc), start angle (steering)
        self.h_input = np.zeros(P)                  # direction * max speed (arc)
        for q, p in enumerate(pieces):
            if isinstance(p, _Arc):
                self.h_arc[q] = True
                self.h_pose[q] = p.pose
                self.h_speed[q] = p.direction * p.body_speed
                self.h_kappa[q] = p.kappa
                self.h_phi[q], self.h_input[q] = p.phi, p.direction * p.max_speed
            elif isinstance(p, _SteerInPlace):
                self.h_pose[q] = p.pose
                self.h_speed[q], self.h_phi[q] = p.rate, p.phi0

    def _held(self, j: np.ndarray, local: np.ndarray):
        """States and inputs of the pieces ``j`` (arcs or steering in place) at their local times."""
        x = np.empty((len(j), self.model.n))
        u = np.zeros((len(j), 2))
        cx, cy, cth, cphi = _pose_cols(self.model) + [self.lay.phi]
        x[:, cx], x[:, cy], x[:, cth] = self.h_pose[j].T
        arc = self.h_arc[j]
        steer = np.flatnonzero(~arc)
        if len(steer):
            js = j[steer]
            x[steer, cphi] = self.h_phi[js] + self.h_speed[js] * local[steer]
            u[steer, 1] = self.h_speed[js]
        arcs = np.flatnonzero(arc)
        if len(arcs):                 # _Arc._poses: the arc as a chord
            ja = j[arcs]
            s = self.h_speed[ja] * local[arcs]
            x0, y0, th0 = self.h_pose[ja].T
            k = self.h_kappa[ja]
            half = 0.5 * k * s
            chord = s * np.sinc(half / np.pi)
            x[arcs, cx] = x0 + chord * np.cos(th0 + half)
            x[arcs, cy] = y0 + chord * np.sin(th0 + half)
            x[arcs, cth] = th0 + k * s
            x[arcs, cphi] = self.h_phi[ja]
            u[arcs, 0] = self.h_input[ja]
        return x, u


class CarPlanningError(PipelineError):
    """The local planner could not join two waypoints feasibly, even after subdividing."""


def _curvature_jumps(kappa: np.ndarray, special: list[int]) -> np.ndarray:
    """Sample indices where the path's curvature changes, except within two samples of a special point
    (cusps and ends: there the car steers in place, and the interval across a cusp has a stray value)."""
    jumps = np.flatnonzero(np.abs(np.diff(kappa)) > 1e-6) + 1
    near = np.abs(jumps[:, None] - np.asarray(special)[None, :]).min(axis=1) <= 2
    return jumps[~near]


def _waypoints(sigma: np.ndarray, special: list[int], jumps: np.ndarray, spacing: float) -> list[int]:
    """Sample indices of the waypoints: the special points, and in each run between two of them points
    evenly spread at most ``spacing`` apart (no slivers), each moved to a third of that spacing from the
    nearest curvature jump if it was closer."""
    out = list(special)
    js = sigma[jumps]
    for s, e in zip(special[:-1], special[1:]):
        length = sigma[e] - sigma[s]
        count = max(1, int(math.ceil(length / spacing - 1e-9)))
        h = length / count
        targets = sigma[s] + h * np.arange(1, count)
        if len(js) and len(targets):
            nearest = js[np.argmin(np.abs(targets[:, None] - js[None, :]), axis=1)]
            away = nearest + np.where(targets >= nearest, h / 3, -h / 3)
            targets = np.where(np.abs(targets - nearest) < h / 3, away, targets)
        inner = np.searchsorted(sigma, targets)
        out += [int(i) for i in inner if s < i < e]
    return sorted(set(out))


def _split(a: int, b: int, sigma: np.ndarray, jumps: np.ndarray) -> list[int]:
    """Inner split points of the piece a -> b: around the curvature jump nearest its middle (the jump in
    the middle of the middle piece), or else the path's midpoint; [] if it cannot be split."""
    inner = jumps[(jumps > a) & (jumps < b)]
    if len(inner):
        j = int(inner[np.argmin(np.abs(sigma[inner] - 0.5 * (sigma[a] + sigma[b])))])
        r = 0.5 * min(sigma[j] - sigma[a], sigma[b] - sigma[j])
        i1, i2 = (int(i) for i in np.searchsorted(sigma, [sigma[j] - r, sigma[j] + r]))
        if a < i1 < j < i2 < b:
            return [i1, i2]
    return [(a + b) // 2] if b - a >= 2 else []


def _state(model: Model, pose, phi: float) -> np.ndarray:
    """The car's state at ``pose`` (x, y, theta) with steering angle ``phi``, in its state order."""
    x, y, th = pose
    out = [x, y, None, None]
    lay = _car_kind(model)[0]
    out[lay.theta], out[lay.phi] = th, phi
    return np.array(out)


def _pose_cols(model: Model):
    """State indices of x, y, theta (from the model's state names)."""
    names = model.state_names
    return [names.index("x"), names.index("y"), names.index("theta")]


def car_nominal(model: Model, path: GeometricPath, timing: TimingOptions, world: CollisionWorld, fp: Footprint,
                margin: float, spacing: float = 1.0, min_spacing: float = 0.05,
                steer_fraction: float = 0.95, arc_speed: float | None = None) -> tuple[Nominal, dict]:
    """The car's nominal along ``path`` (module docstring). The path's exact runs
    (``path.info["exact_runs"]``: sample ranges (i0, i1, phi, direction) of segments driven with the
    steering angle ``phi`` held, e.g. the parking maneuvers of :mod:`nhstab.planning.parking`) are
    driven exactly, at ``arc_speed`` (default: the speed limit), stopping at both ends of each to steer."""
    if not isinstance(model, SteeredCar):
        raise InputError("model", " or ".join(CAR_MODELS), model.name)
    L = float(model.wheelbase)
    samples, sigma, direction = path.samples, path.sigma, path.direction
    d_theta, d_sigma = np.diff(samples[:, 2]), np.diff(sigma)
    kappa = np.where(d_sigma > 1e-12, d_theta / np.maximum(d_sigma, 1e-300), 0.0)
    n = len(samples)
    steer_cap = steer_fraction * float(model.max_steer)

    def steer_for(k: int) -> float:
        """The steering angle that makes the car follow sample interval k."""
        k = int(np.clip(k, 0, n - 2))
        return float(np.clip(math.atan(L * kappa[k] * direction[k]), -steer_cap, steer_cap))

    def phi_at(i: int) -> float:
        # inside a run: the curvature of the interval ahead, snapped to the arc or straight it belongs
        # to by looking one interval further
        k = min(i, n - 2)
        k2 = min(k + 1, n - 2)
        return steer_for(k if abs(kappa[k] - kappa[k2]) < 1e-6 else k2)

    cusp_idx = [int(i) for i in np.flatnonzero(direction[1:] != direction[:-1]) + 1]
    special = set(cusp_idx) | {0, n - 1}
    arrive = {i: (steer_for(i - 1) if i > 0 else 0.0) for i in special}
    depart = {i: (steer_for(i) if i < n - 1 else 0.0) for i in special}
    arrive[0] = depart[n - 1] = 0.0          # parked with the wheels straight at both ends
    if n - 1 in arrive:
        arrive[n - 1] = steer_for(n - 2)
    runs = sorted((int(i0), int(i1), float(phi), int(d)) for i0, i1, phi, d in path.info.get("exact_runs", ()))
    for i0, i1, phi, d in runs:
        if not (0 <= i0 < i1 <= n - 1) or abs(phi) > float(model.max_steer) + 1e-12:
            raise InputError("path", "exact runs inside the path, steering within the limit", (i0, i1, phi))
        for i in (i0, i1):
            if i not in special:
                special.add(i)
                arrive[i], depart[i] = steer_for(i - 1) if i > 0 else 0.0, steer_for(i) if i < n - 1 else 0.0
        depart[i0], arrive[i1] = phi, phi
    arrive[0] = depart[n - 1] = 0.0
    run_of = {}
    for i0, i1, phi, d in runs:
        run_of[i0] = (i1, phi, d)

    def phi_arrive(i):
        return arrive[i] if i in special else phi_at(i)

    def phi_depart(i):
        return depart[i] if i in special else phi_at(i)

    # waypoints at the cusps and ends, and at most `spacing` apart between them, away from curvature jumps
    jumps = _curvature_jumps(kappa, sorted(special))
    idx = _waypoints(sigma, sorted(special), jumps, spacing)
    inside = np.zeros(n, dtype=bool)
    for i0, i1, _, _ in runs:
        inside[i0 + 1:i1] = True
    idx = [i for i in idx if not inside[i]]
    pieces, subdivisions, in_place, phased, arcs = [], 0, 0, 0, 0

    def add_in_place(i):
        nonlocal in_place
        if abs(phi_arrive(i) - phi_depart(i)) > 1e-9:
            pieces.append(_SteerInPlace(model, samples[i], phi_arrive(i), phi_depart(i)))
            in_place += 1

    add_in_place(0)
    stack = [(a, b) for a, b in zip(idx[:-1], idx[1:])][::-1]
    max_speed = timing.max_speed or float(model.input_limits()[0, 1])

    def feasible(piece) -> bool:
        return (piece.max_abs_phi <= float(model.max_steer) + 1e-9 and piece.max_speed <= max_speed * 1.001
                and bool(world.free_many(piece.x[:, _pose_cols(model)], fp, margin).all()))

    while stack:
        a, b = stack.pop()
        if a in run_of and run_of[a][0] == b:          # an exact run: the held-steering arc itself
            _, phi, d = run_of[a]
            piece = _Arc(model, samples[a], phi, d, float(sigma[b] - sigma[a]), arc_speed or max_speed)
            end = piece.states_at(piece.t[-1])
            piece.final_error = model.state_error(end, _state(model, samples[b], phi))
            pieces.append(piece)
            arcs += 1
            add_in_place(b)
            continue
        xa, xb = _state(model, samples[a], phi_depart(a)), _state(model, samples[b], phi_arrive(b))
        piece = None
        try:
            piece = steer_car(model, xa, xb, T=None, mode="constant_v1")
            # the piece drives the path's direction (v1 = cos(theta - alpha) s has the sign of s)
            if math.copysign(1.0, piece.plan.phases[0].v1) != direction[a] or not feasible(piece):
                piece = None
        except InputError:
            piece = None
        cuts = _split(a, b, sigma, jumps) if piece is None and sigma[b] - sigma[a] > min_spacing else []
        if cuts:
            subdivisions += 1
            ends = [a, *cuts, b]
            stack.extend(list(zip(ends[:-1], ends[1:]))[::-1])
            continue
        if piece is None:       # cannot be split further: the phased sinusoids
            try:
                piece = _steer_phased(model, xa, xb)
                piece = piece if feasible(piece) else None
            except InputError:
                piece = None
            if piece is None:
                where = np.round(samples[a], 3).tolist()
                raise CarPlanningError(f"no feasible sinusoidal steering between path points at sigma = "
                                       f"{sigma[a]:.3f} and {sigma[b]:.3f} m (from {where}), even subdivided to "
                                       f"{min_spacing:g} m")
            phased += 1
        pieces.append(piece)
        if b in special:
            add_in_place(b)
    # one continuous-time trajectory from the pieces
    joined = _Joined(model, pieces)
    duration = joined.duration
    npts = nominal_grid(duration, timing.dt, "arc_speed" if arc_speed else "max_speed", arc_speed or max_speed,
                        min(arc_speed or max_speed, max_speed))
    t = np.linspace(0.0, duration, npts)
    nominal = Nominal.from_functions(model, joined.states, joined.inputs, t)
    return nominal, {"duration_s": duration, "pieces": len(pieces), "subdivisions": subdivisions,
                     "steer_in_place": in_place, "phased_pieces": phased, "held_steering_arcs": arcs,
                     "direction_reversals": direction_reversals(nominal.x[:, _pose_cols(model)]),
                     "waypoint_spacing_m": spacing, "dt_s": float(t[1] - t[0]),
                     "path_deviation_m": float(max(np.linalg.norm(p.final_error[:2]) for p in pieces))}


def exact_nominal(model: Model, path: GeometricPath, timing: TimingOptions,
                  arc_speed: float | None = None) -> tuple[Nominal, dict]:
    """The car driving its path exactly: every segment of ``path.info["segments"]`` ((direction,
    steering angle, length), the path's arcs and straights) with its steering angle held, at the
    speed limit (or ``arc_speed``), the car stopping to steer in place at the rate limit wherever the
    steering angle changes (at cusps, where an arc meets a straight or the opposite arc, and at the
    ends, where the wheels are straight). Each piece starts where the previous one ended, so the
    nominal is the model's exact solution; ``path_deviation_m`` is how far its end lies from the
    path's end (round-off and the segments' recovery, ~1e-7 m)."""
    if not isinstance(model, SteeredCar):
        raise InputError("model", " or ".join(CAR_MODELS), model.name)
    if "segments" not in path.info:
        raise InputError("path", "a car path with its segments (nhstab.planning.parking)", "no segments")
    lim = float(model.max_steer)
    segs = []
    for d, phi, length in path.info["segments"]:
        if length <= 1e-9:
            continue
        if abs(phi) > lim + 1e-9:
            raise InputError("path", f"segments steering within the limit {lim:g} rad", phi)
        phi = float(np.clip(phi, -lim, lim))
        if segs and segs[-1][0] == d and abs(segs[-1][1] - phi) < 1e-9:
            segs[-1][2] += length
        else:
            segs.append([int(d), phi, float(length)])
    speed = arc_speed or timing.max_speed or float(model.input_limits()[0, 1])
    speed = min(speed, float(model.input_limits()[0, 1]))
    pose = np.asarray(path.samples[0], dtype=float)
    pieces, phi_now, stops = [], 0.0, 0
    for d, phi, length in segs:
        if abs(phi - phi_now) > 1e-12:
            pieces.append(_SteerInPlace(model, pose, phi_now, phi))
            stops += 1
        arc = _Arc(model, pose, phi, d, length, speed)
        pieces.append(arc)
        end = arc.states_at(arc.t[-1])
        pose = end[_pose_cols(model)]
        phi_now = phi
    if abs(phi_now) > 1e-12:
        pieces.append(_SteerInPlace(model, pose, phi_now, 0.0))
        stops += 1
    if not pieces:
        raise InputError("path", "a path that moves", "length 0")
    joined = _Joined(model, pieces)
    duration = joined.duration
    npts = nominal_grid(duration, timing.dt, "max_speed", speed, speed)
    t = np.linspace(0.0, duration, npts)
    nominal = Nominal.from_functions(model, joined.states, joined.inputs, t)
    deviation = float(np.hypot(*(pose[:2] - path.samples[-1, :2])))
    return nominal, {"duration_s": duration, "pieces": len(pieces), "held_steering_arcs": len(segs),
                     "steer_in_place": stops, "phased_pieces": 0, "subdivisions": 0,
                     "direction_reversals": direction_reversals(nominal.x[:, _pose_cols(model)]),
                     "dt_s": float(t[1] - t[0]), "path_deviation_m": deviation}
