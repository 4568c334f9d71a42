"""The rear-axle car of ``rwd_car`` towing N >= 1 trailers (the standard N-trailer system).

Each trailer is hitched at the centre of the previous body's axle (zero hitch offset), and its own
axle lies ``d_i`` (the hitch length) behind the hitch. Body 0 is the car (the tractor): its rear
axle midpoint (x, y), heading theta_0 = theta, steering angle phi. Body i >= 1 is trailer i with
heading theta_i.

States (x, y, theta, phi, theta1, ..., thetaN); inputs (v = the car's rear-axle speed, omega_s =
steering rate)::

    x' = cos(theta) v,   y' = sin(theta) v,   theta' = tan(phi) v / L,   phi' = omega_s,
    theta_i' = v_(i-1) sin(theta_(i-1) - theta_i) / d_i,        i = 1 .. N,
    v_i = v_(i-1) cos(theta_(i-1) - theta_i),   v_0 = v        (body i's axle speed).

Derivation: trailer i's axle point p_i = p_(i-1) - d_i (cos theta_i, sin theta_i) cannot slip
sideways, so its velocity is along its heading. Its hitch p_(i-1) moves with speed v_(i-1) along
theta_(i-1); of that, the part along the bar, v_(i-1) cos(theta_(i-1) - theta_i), moves p_i (that is
v_i), and the part across it, v_(i-1) sin(theta_(i-1) - theta_i), turns the bar of length d_i about
p_i. For one trailer: theta1' = (v / d1) sin(theta - theta1).

The *hitch angles* are theta_(i-1) - theta_i; ``jackknife_limit`` bounds their magnitude (beyond it
the trailer would hit the body ahead: a jackknife). Plans keep within it, and a run whose hitch angle
goes beyond it ends as a collision of the rig with itself.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ..errors import InputError
from ..geometry import wrap_angle
from .base import (
    NOISE_KINDS,
    POSE_NOISE,
    Model,
    angle_limit,
    axle_turning_radius,
    check_max_steer,
    positive_param,
    with_noise,
)

#: the most trailers a model may tow (a bound on the state's size, not a physical limit)
MAX_TRAILERS = 8


def _hitch_lengths(value) -> tuple[float, ...]:
    """A tuple of positive finite hitch lengths from a number or a sequence of numbers."""
    if isinstance(value, (int, float, np.integer, np.floating)) and not isinstance(value, bool):
        value = (value,)
    if isinstance(value, np.ndarray):
        value = value.tolist()
    if not isinstance(value, (list, tuple)) or not 1 <= len(value) <= MAX_TRAILERS:
        raise InputError("car_trailer.hitch_lengths", f"a list of 1 to {MAX_TRAILERS} positive lengths [m]",
                         value)
    out = []
    for i, d in enumerate(value):
        ok = isinstance(d, (int, float, np.integer, np.floating)) and not isinstance(d, bool) and math.isfinite(d) \
            and d > 0
        if not ok:
            raise InputError(f"car_trailer.hitch_lengths[{i}]", "a positive finite length [m]", d)
        out.append(float(d))
    return tuple(out)


@dataclass(frozen=True)
class CarTrailer(Model):
    # the rwd_car towing a 2.5 x 1.8 m trailer whose axle is 3 m behind the hitch; the turning radius
    # is the trailer's axle path's (the planned point), 5 times its smallest steady turn: the hitch
    # angle changes only gradually, and on those arcs the steady steering angle is under half its limit
    # (nhstab.planning.trailer). Its stabilizer defaults are the trailer suite's law sweep's best
    # (docs/guide/trailer.md); on the trailer planner's plans the end strategy does not act.
    robot_defaults: ClassVar[dict] = {
        "footprint": {"rectangle": {"length": 4.2, "width": 1.8, "rear_overhang": 0.9}},
        "trailer_footprint": {"rectangle": {"length": 2.5, "width": 1.8, "rear_overhang": 1.0}},
        "margin": 0.3,
        "stabilizer": {"alpha": 0.02, "delta": 15.0, "gamma": 2.0, "end_strategy": "frozen"},
        "turning_radius": ("factor", 5.0),
    }
    #: the car's noise (phi's as a car's), and each trailer heading's as the car's heading
    noise_defaults: ClassVar[dict] = with_noise(POSE_NOISE, phi=(0.0, 0.005, 0.0), **{
        f"theta{i}": tuple(POSE_NOISE[kind]["theta"] for kind in NOISE_KINDS)
        for i in range(1, MAX_TRAILERS + 1)})
    plannable: ClassVar[bool] = True
    wheelbase: float = 2.5              # m, L of the car
    hitch_lengths: tuple = (3.0,)       # m, d_i: hitch (previous axle centre) to trailer i's axle
    max_speed: float = 1.5              # m/s, |v|
    max_steer: float = 0.6              # rad, |phi| (< pi/2)
    max_steer_rate: float = 1.0         # rad/s, |omega_s|
    jackknife_limit: float = 1.0        # rad, |theta_(i-1) - theta_i| (< pi/2)

    def __post_init__(self):
        for key in ("wheelbase", "max_speed", "max_steer_rate"):
            positive_param(key, getattr(self, key), "car_trailer")
        angle_limit("max_steer", self.max_steer, "car_trailer")
        check_max_steer("car_trailer", self.wheelbase, self.max_steer)
        angle_limit("jackknife_limit", self.jackknife_limit, "car_trailer", " (a hitch angle the chained chart covers)")
        d = _hitch_lengths(self.hitch_lengths)
        object.__setattr__(self, "hitch_lengths", d)
        N = len(d)
        object.__setattr__(self, "name", "car_trailer")
        object.__setattr__(self, "state_names", ("x", "y", "theta", "phi", *(f"theta{i}" for i in range(1, N + 1))))
        object.__setattr__(self, "input_names", ("v", "omega_s"))
        object.__setattr__(self, "angle_states", tuple(range(2, 4 + N)))
        object.__setattr__(self, "state_units", ("m", "m", "rad", "rad", *("rad",) * N))
        object.__setattr__(self, "input_units", ("m/s", "rad/s"))

    # ---- layout -----------------------------------------------------------------------------
    @property
    def trailers(self) -> int:
        """N, the number of trailers."""
        return len(self.hitch_lengths)

    @property
    def heading_columns(self) -> list[int]:
        """State indices of the body headings theta_0 = theta, theta_1, ..., theta_N."""
        return [2, *range(4, 4 + self.trailers)]

    @property
    def min_turning_radius(self) -> float:
        """The smallest radius of a steady turn of the *last trailer's axle* (the rig's planned point):
        on a steady turn every axle runs on a circle about one centre, R_(i-1)^2 = R_i^2 + d_i^2 (each
        bar is tangent to its axle's circle), with the car's R_0 >= L / tan(max_steer) and each hitch
        angle atan(d_i / R_i) <= jackknife_limit."""
        d = np.asarray(self.hitch_lengths)
        r0 = axle_turning_radius(self.wheelbase, self.max_steer)
        need = [r0 * r0 - float(np.sum(d * d))]
        tail = np.concatenate([np.cumsum((d * d)[::-1])[::-1][1:], [0.0]])     # sum of d_j^2 for j > i
        need += list((d / math.tan(self.jackknife_limit)) ** 2 - tail)
        return float(math.sqrt(max(max(need), 0.0)))

    def hitch_angles(self, x) -> np.ndarray:
        """theta_(i-1) - theta_i for i = 1 .. N, wrapped to [-pi, pi); shape (..., N)."""
        x = np.asarray(x, dtype=float)
        h = x[..., self.heading_columns]
        return wrap_angle(h[..., :-1] - h[..., 1:])

    def body_poses(self, x) -> np.ndarray:
        """Pose (x, y, heading) of every body's reference point, shape (..., N + 1, 3): the car's rear
        axle, then each trailer's axle, p_i = p_(i-1) - d_i (cos theta_i, sin theta_i)."""
        x = np.asarray(x, dtype=float)
        out = np.empty(x.shape[:-1] + (self.trailers + 1, 3))
        out[..., 0, :] = x[..., :3]
        px, py = x[..., 0], x[..., 1]
        for i, d in enumerate(self.hitch_lengths, start=1):
            th = x[..., 3 + i]
            px, py = px - d * np.cos(th), py - d * np.sin(th)
            out[..., i, 0], out[..., i, 1], out[..., i, 2] = px, py, th
        return out

    # ---- dynamics ---------------------------------------------------------------------------
    def g(self, x):
        x = np.asarray(x, dtype=float)
        th, phi = x[..., 2], x[..., 3]
        out = np.zeros(x.shape[:-1] + (self.n, 2))
        out[..., 0, 0] = np.cos(th)
        out[..., 1, 0] = np.sin(th)
        out[..., 2, 0] = np.tan(phi) / self.wheelbase
        out[..., 3, 1] = 1.0
        speed, prev = np.ones(x.shape[:-1]), th           # v_(i-1) / v and theta_(i-1)
        for i, d in enumerate(self.hitch_lengths, start=1):
            thi = x[..., 3 + i]
            dl = prev - thi
            out[..., 3 + i, 0] = speed * np.sin(dl) / d
            speed, prev = speed * np.cos(dl), thi
        return out

    def rhs(self, x, u):
        """x' = g(x) u written out (the same values as the generic f + g u, without building g)."""
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        th, phi, v = x[..., 2], x[..., 3], u[..., 0]
        out = np.empty(np.broadcast_shapes(x.shape[:-1], u.shape[:-1]) + (self.n,))
        out[..., 0] = np.cos(th) * v
        out[..., 1] = np.sin(th) * v
        out[..., 2] = (np.tan(phi) / self.wheelbase) * v
        out[..., 3] = u[..., 1]
        speed, prev = v, th
        for i, d in enumerate(self.hitch_lengths, start=1):
            thi = x[..., 3 + i]
            dl = prev - thi
            out[..., 3 + i] = speed * np.sin(dl) / d
            speed, prev = speed * np.cos(dl), thi
        return out

    def dgu_dx(self, x, u):
        """d(g(x) u)/dx. The trailers' rows by the recursion: with D_i = theta_(i-1) - theta_i and
        s_i = v_i / v = prod_(j<=i) cos D_j, theta_i' = v s_(i-1) sin(D_i) / d_i, so
        grad theta_i' = v (sin D_i grad s_(i-1) + s_(i-1) cos D_i grad D_i) / d_i and
        grad s_i = cos D_i grad s_(i-1) - s_(i-1) sin D_i grad D_i, grad D_i = e_(theta_(i-1)) - e_(theta_i)."""
        x = np.asarray(x, dtype=float)
        u = np.asarray(u, dtype=float)
        th, phi, v = x[..., 2], x[..., 3], u[..., 0]
        shape = np.broadcast_shapes(x.shape[:-1], u.shape[:-1])
        n = self.n
        out = np.zeros(shape + (n, n))
        out[..., 0, 2] = -np.sin(th) * v
        out[..., 1, 2] = np.cos(th) * v
        out[..., 2, 3] = v / (self.wheelbase * np.cos(phi) ** 2)
        s = np.ones(x.shape[:-1])
        grad_s = np.zeros(x.shape[:-1] + (n,))
        prev_col, prev = 2, th
        for i, d in enumerate(self.hitch_lengths, start=1):
            col = 3 + i
            thi = x[..., col]
            dl = prev - thi
            sd, cd = np.sin(dl), np.cos(dl)
            row = sd[..., None] * grad_s
            row[..., prev_col] += s * cd
            row[..., col] -= s * cd
            out[..., col, :] = np.asarray(v / d)[..., None] * row
            grad_next = cd[..., None] * grad_s
            grad_next[..., prev_col] -= s * sd
            grad_next[..., col] += s * sd
            s, grad_s = s * cd, grad_next
            prev_col, prev = col, thi
        return out

    # ---- parameters and limits ---------------------------------------------------------------
    def params(self) -> dict:
        return {"wheelbase": self.wheelbase, "hitch_lengths": list(self.hitch_lengths), "max_speed": self.max_speed,
                "max_steer": self.max_steer, "max_steer_rate": self.max_steer_rate,
                "jackknife_limit": self.jackknife_limit}

    def input_limits(self) -> np.ndarray:
        return np.array([[-self.max_speed, self.max_speed], [-self.max_steer_rate, self.max_steer_rate]])

    def state_limits(self) -> np.ndarray:
        """The steering angle stops at its limit; the hitch angles are bounded by the jackknife limit,
        which is a constraint plans keep and runs check, not a stop the plant applies."""
        lim = np.tile([-np.inf, np.inf], (self.n, 1))
        lim[3] = [-self.max_steer, self.max_steer]
        return lim
