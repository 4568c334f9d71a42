"""Exactly feasible car trajectories along a Reeds-Shepp path (Laumond, Jacobs, Taix, Murray).

A Reeds-Shepp path's curvature jumps where its arcs and straights meet, so a car with the steering
angle as a state cannot follow it. Take waypoints along the path (every ``spacing`` metres and at
every cusp), give each the steering angle of the path's curvature there (phi = atan(L kappa d), d the
direction of travel), and join consecutive waypoints with sinusoidal steering in chained form
(``steering``): the steering angle is continuous and every piece ends exactly at its waypoint. A
piece that comes within the margin of an obstacle, exceeds the steering limit or leaves the chart is
replaced by two pieces through the path's midpoint between its waypoints, down to ``min_spacing``.
Each piece runs as fast as the speed and steering-rate limits allow.

At a cusp the path's curvature reverses over no distance, and at the ends the car is parked with its
wheels straight: there the car steers in place (phi' = omega_s at standstill, at the steering-rate
limit), a short stop (at most 2 max_steer / max_steer_rate seconds) that is brief against the
stabilizer's window for cars.
"""

from __future__ import annotations

import math

import numpy as np

from ..collision import CollisionWorld
from ..errors import InputError, PipelineError
from ..geometry import Footprint
from ..models import Model
from ..nominal import Nominal
from .geometric import GeometricPath
from .steering import steer_car
from .timing import TimingOptions


def _steer(model: Model, xa: np.ndarray, xb: np.ndarray):
    """Steer xa -> xb; phases with nothing to correct get (almost) no time, so the car never stands
    still for a whole phase (a dwell longer than the stabilizer's window would make its gramian
    singular)."""
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
        x[..., 3 if self.model.name == "rwd_car" else 2] = phi
        return x

    def inputs_at(self, t):
        t = np.asarray(t, dtype=float)
        u = np.zeros(t.shape + (2,))
        u[..., 1] = self.rate
        return u


class CarPlanningError(PipelineError):
    """The local planner could not join two waypoints feasibly, even after subdividing."""


def _state(model: Model, pose, phi: float) -> np.ndarray:
    x, y, th = pose
    return np.array([x, y, th, phi]) if model.name == "rwd_car" else np.array([x, y, phi, th])


def _pose_cols(model: Model):
    return [0, 1, 2] if model.name == "rwd_car" else [0, 1, 3]


def car_nominal(model: Model, path: GeometricPath, timing: TimingOptions, world: CollisionWorld, fp: Footprint,
                margin: float, spacing: float = 1.0, min_spacing: float = 0.05,
                steer_fraction: float = 0.95) -> tuple[Nominal, dict]:
    if model.name not in ("rwd_car", "fwd_car"):
        raise InputError("model", "rwd_car or fwd_car", model.name)
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

    def phi_arrive(i):
        return arrive[i] if i in special else phi_at(i)

    def phi_depart(i):
        return depart[i] if i in special else phi_at(i)

    # waypoints every `spacing` of arc length, and at every cusp
    marks = np.searchsorted(sigma, np.arange(spacing, sigma[-1], spacing))
    idx = sorted(special | {int(i) for i in marks if 0 < i < n - 1})
    pieces, subdivisions, in_place = [], 0, 0

    def add_in_place(i):
        nonlocal in_place
        if abs(phi_arrive(i) - phi_depart(i)) > 1e-9:
            pieces.append(_SteerInPlace(model, samples[i], phi_arrive(i), phi_depart(i)))
            in_place += 1

    add_in_place(0)
    stack = [(a, b) for a, b in zip(idx[:-1], idx[1:])][::-1]
    max_speed = timing.max_speed or float(model.input_limits()[0, 1])
    while stack:
        a, b = stack.pop()
        xa, xb = _state(model, samples[a], phi_depart(a)), _state(model, samples[b], phi_arrive(b))
        ok, piece = False, None
        try:
            piece = _steer(model, xa, xb)
            ok = piece.max_abs_phi <= float(model.max_steer) + 1e-9 and piece.max_speed <= max_speed * 1.001
            if ok:
                ok = bool(world.free_many(piece.x[:, _pose_cols(model)], fp, margin).all())
        except InputError:
            ok = False
        if ok:
            pieces.append(piece)
            if b in special:
                add_in_place(b)
            continue
        if sigma[b] - sigma[a] <= min_spacing or b - a < 2:
            where = np.round(samples[a], 3).tolist()
            raise CarPlanningError(f"no feasible sinusoidal steering between path points at sigma = {sigma[a]:.3f} "
                                   f"and {sigma[b]:.3f} m (from {where}), even subdivided to {min_spacing:g} m")
        mid = (a + b) // 2
        subdivisions += 1
        stack.extend([(mid, b), (a, mid)])
    # one continuous-time trajectory from the pieces
    starts = np.concatenate([[0.0], np.cumsum([p.t[-1] for p in pieces])])
    duration = float(starts[-1])

    import bisect

    starts_list = starts.tolist()

    def _eval(tt, what):
        tt = np.asarray(tt, dtype=float)
        if tt.shape == (1,):            # the integrators' scalar calls: no array bookkeeping
            t1 = float(tt[0])
            j = min(max(bisect.bisect_right(starts_list, t1) - 1, 0), len(pieces) - 1)
            local = min(max(t1 - starts_list[j], 0.0), float(pieces[j].t[-1]))
            val = pieces[j].states_at(local) if what == "x" else pieces[j].inputs_at(local)
            return np.asarray(val, dtype=float).reshape(1, -1)
        tt = np.atleast_1d(tt)
        k = np.clip(np.searchsorted(starts, tt, side="right") - 1, 0, len(pieces) - 1)
        out = np.empty(tt.shape + ((model.n,) if what == "x" else (model.m,)))
        for j in np.unique(k):
            sel = k == j
            local = np.clip(tt[sel] - starts[j], 0.0, pieces[j].t[-1])
            out[sel] = pieces[j].states_at(local) if what == "x" else pieces[j].inputs_at(local)
        return out

    def x_func(tt):
        return _eval(tt, "x")

    def u_func(tt):
        return _eval(tt, "u")

    npts = max(2, int(math.ceil(duration / timing.dt)) + 1)
    t = np.linspace(0.0, duration, npts)
    nominal = Nominal.from_functions(model, x_func, u_func, t)
    return nominal, {"duration_s": duration, "pieces": len(pieces), "subdivisions": subdivisions,
                     "steer_in_place": in_place,
                     "waypoint_spacing_m": spacing, "dt_s": float(t[1] - t[0]),
                     "path_deviation_m": float(max(np.linalg.norm(p.final_error[:2]) for p in pieces))}
