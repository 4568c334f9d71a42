"""Feedback laws about a nominal trajectory, all of the form u = u0(t) - K(t) (x - x0(t)).

* ``gramian``: the paper's law, K = gamma B^T P with P the inverse of the weighted window gramian,
  from :func:`nhstab.control.compute_schedule`: the future window P_c (default, Proposition 1); the
  causal ``frozen-time`` law (Proposition 1 on the linearisation frozen at the current time, for users
  who cannot use the future nominal); or the past window P_r of Remark 2, kept for study only: it is
  not stabilizing in general (a :class:`~nhstab.errors.NotStabilizingWarning` says so).
* ``tvlqr``: time-varying LQR about the same nominal, K = R^-1 B^T S with the Riccati equation
  -S' = A^T S + S A - S B R^-1 B^T S + Q integrated backwards from S(T) = Q (stated Q, R). Q is a
  stated diagonal, or ``q: footprint``: Q(t) weighs a state error by how far it moves the robot's
  outline at the nominal's pose (:func:`footprint_weights`).
* ``open-loop``: K = 0, u = u0 (what the nominal alone does under noise).

A :class:`FeedbackLaw` holds K on the nominal's uniform grid, linear in between, and evaluates one
control update in a few microseconds (:meth:`FeedbackLaw.control`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from ..control import WINDOWS, GainSchedule, StabilizerOptions, compute_schedule
from ..control.interpolant import GridInterpolant
from ..errors import InputError, NumericalError
from ..geometry import wrap_angle
from ..limits import MAX_GAMMA
from ..nominal import Nominal

CONTROLLERS = ("gramian", "tvlqr", "open-loop")
GAINS = ("default", "auto")
#: ``controller.q`` as a word: TVLQR's Q from the robot's outline (:func:`footprint_weights`)
Q_FOOTPRINT = "footprint"
#: with ``q: footprint``, the weight of a state that moves no corner of any body (a car's steering
#: angle; a disc's heading) [m^2 per unit^2]: small, so that such a state costs next to a corner's move
FOOTPRINT_FLOOR = 0.1


@dataclass(frozen=True)
class ControllerOptions:
    """kind: one of CONTROLLERS; window: the gramian's window ("future" = P_c, "frozen-time" = the
    causal law of :mod:`nhstab.control.frozen`, "past" = P_r, not stabilizing in general);
    alpha, delta, gamma: the gramian law's parameters (None: the robot's defaults); max_gain: the
    frozen-time law's hold threshold (None: :data:`nhstab.control.frozen.MAX_GAIN`); q, r: the
    diagonals of TVLQR's Q (per state) and R (per input), None for identity, and q = "footprint" for Q
    from the robot's outline (:func:`footprint_weights`; the law then needs the robot); gains: "default", or
    "auto" (gramian only): alpha, delta and gamma chosen per plan from a small grid, the narrowest
    error tube with a saturation bound under 1 % (:func:`nhstab.tubes.choose_gains`)."""

    kind: str = "gramian"
    window: str = "future"
    alpha: float | None = None
    delta: float | None = None
    gamma: float | None = None
    max_gain: float | None = None
    q: tuple[float, ...] | str | None = None
    r: tuple[float, ...] | None = None
    gains: str = "default"

    def validated(self, n: int, m: int) -> "ControllerOptions":
        if self.kind not in CONTROLLERS:
            raise InputError("controller", "one of " + ", ".join(CONTROLLERS), self.kind)
        if self.window not in WINDOWS:
            raise InputError("controller.window", "one of " + ", ".join(WINDOWS), self.window)
        for key in ("alpha", "delta", "max_gain"):
            v = getattr(self, key)
            if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"controller.{key}", "a positive finite number", v)
        if self.gamma is not None and not (isinstance(self.gamma, (int, float)) and not isinstance(self.gamma, bool)
                                           and 0.5 <= self.gamma <= MAX_GAMMA):
            raise InputError("controller.gamma", f"a number in [1/2 (Proposition 1), {MAX_GAMMA:g}]", self.gamma)
        if self.gains not in GAINS:
            raise InputError("controller.gains", "one of " + ", ".join(GAINS), self.gains)
        if self.gains == "auto" and self.kind != "gramian":
            raise InputError("controller.gains", f"default for the {self.kind} controller (auto tunes the gramian law)",
                             self.gains)
        for key, size in (("q", n), ("r", m)):
            v = getattr(self, key)
            if v is None or (key == "q" and v == Q_FOOTPRINT):
                continue
            if key == "q" and isinstance(v, str):
                raise InputError("controller.q", f"{size} positive finite numbers (a diagonal) or {Q_FOOTPRINT!r}", v)
            arr = np.asarray(v, dtype=float) if _numeric_list(v) else None
            if arr is None or arr.shape != (size,) or not np.all(np.isfinite(arr)) or np.any(arr <= 0):
                raise InputError(f"controller.{key}", f"{size} positive finite numbers (a diagonal)", v)
        return self

    def stabilizer_keys(self, robot) -> dict:
        """For :func:`nhstab.errors.user_keys`: each parameter of the gramian law named where its value
        comes from, ``controller.<key>`` where this sets it, else the robot's stabilizer key."""
        keys = robot.stabilizer_keys()
        for key in ("alpha", "delta", "gamma", "max_gain", "window"):
            if getattr(self, key) is not None:
                keys[key] = f"controller.{key}"
        return keys

    def stabilizer(self, defaults) -> StabilizerOptions:
        """The gain schedule's options: ``defaults`` (a robot's :class:`~nhstab.robot.RobotStabilizer` or
        a dict of StabilizerOptions keywords) with the values set here on top."""
        params = dict(defaults.as_dict() if hasattr(defaults, "as_dict") else defaults)
        for key in ("alpha", "delta", "gamma", "max_gain"):
            if getattr(self, key) is not None:
                params[key] = float(getattr(self, key))
        return StabilizerOptions(**params, window=self.window)

    def describe(self, n: int, m: int, defaults: dict) -> dict:
        if self.kind == "gramian":
            if self.gains == "auto":
                return {"kind": self.kind, "gains": "auto: alpha, delta, gamma chosen per plan (plans[i].gains_auto)",
                        "window": self.window}
            return {"kind": self.kind, **self.stabilizer(defaults).describe()}
        if self.kind == "tvlqr":
            if self.q == Q_FOOTPRINT:
                q = {"Q": f"footprint: the mean squared move of the corners of every body's outline, plus "
                          f"{FOOTPRINT_FLOOR:g} for a state that moves none"}
            else:
                q = {"Q_diagonal": list(self.q or (1.0,) * n)}
            return {"kind": self.kind, **q, "R_diagonal": list(self.r or (1.0,) * m), "S_T": "Q"}
        return {"kind": self.kind}


def _numeric_list(v) -> bool:
    return isinstance(v, (list, tuple, np.ndarray)) and all(
        isinstance(x, (int, float, np.floating, np.integer)) and not isinstance(x, bool) for x in v)


@dataclass
class FeedbackLaw:
    """Gains K (N, m, n) on the nominal's uniform grid t (N,); u0 by the nominal's own interpolant."""

    kind: str
    nominal: Nominal
    t: np.ndarray
    K: np.ndarray
    schedule: GainSchedule | None = None
    info: dict = field(default_factory=dict)

    def __post_init__(self):
        nom = self.nominal
        self.interp = GridInterpolant(self.t, nom.x, nom.model.rhs(nom.x, nom.u), nom.u, self.K)
        self.t0, self.t_end, self.h = self.interp.t0, self.interp.t_end, self.interp.h
        self._angles = list(nom.model.angle_states)

    def reference(self, tau: float) -> tuple[np.ndarray, np.ndarray]:
        """x0(tau) (cubic Hermite with the model's slopes) and u0(tau) (linear), clamped to the span."""
        k, a = self.interp.locate(tau)
        return self.interp.state(k, a), self.interp.input(k, a)

    def gain(self, tau: float) -> np.ndarray:
        return self.interp.gain(*self.interp.locate(tau))

    def control(self, tau: float, x_measured: np.ndarray, u_feedforward: np.ndarray | None = None):
        """One control update: (u, x0(tau), e) with e = x_measured - x0(tau), angles wrapped.

        u_feedforward replaces u0(tau) (the run loop passes the mean of u0 over the hold interval)."""
        interp = self.interp
        k, a = interp.locate(tau)
        x0 = interp.state(k, a)
        e = x_measured - x0
        if self._angles:
            e[self._angles] = wrap_angle(e[self._angles])
        uff = interp.input(k, a) if u_feedforward is None else u_feedforward
        return uff - interp.gain(k, a) @ e, x0, e

    def mean_input(self, t_from: float, t_to: float) -> np.ndarray:
        """The mean of u0 over [t_from, t_to]: exact for the piecewise-linear u0, which is held at its
        end values outside the nominal's span."""
        i, j = np.searchsorted(self.t, [t_from, t_to], side="right")
        pts = [t_from, *self.t[i:j].tolist(), t_to]
        vals = np.array([self.interp.input(*self.interp.locate(p)) for p in pts])
        return np.sum(0.5 * (vals[1:] + vals[:-1]) * np.diff(pts)[:, None], axis=0) / (t_to - t_from)


def build_law(nominal: Nominal, options: ControllerOptions, defaults,
              schedule: GainSchedule | None = None, robot=None) -> FeedbackLaw:
    """The feedback law of ``options.kind`` along ``nominal``; ``defaults``: the robot's stabilizer
    (a :class:`~nhstab.robot.RobotStabilizer`, or a dict of its keys) for what ``options`` leaves unset.
    ``robot`` (:class:`~nhstab.robot.Robot`): its outline, for TVLQR with ``q: footprint``.

    For the gramian law a schedule already computed with the same options (the planner computes one
    for the future window) is reused. Raises SingularGramianError where the gramian is singular.
    """
    model = nominal.model
    opts = options.validated(model.n, model.m)
    nom = nominal if nominal.is_uniform() else nominal.resampled(len(nominal.t))
    if opts.kind == "gramian":
        stab = opts.stabilizer(defaults).validated()
        if schedule is None or schedule.options.describe() != stab.describe():
            schedule = compute_schedule(nom, stab)
        return FeedbackLaw("gramian", schedule.nominal, schedule.t, schedule.K, schedule,
                           {"max_gain_norm": schedule.diagnostics["max_gain_norm"],
                            "rate_bound": schedule.diagnostics["rate_bound"],
                            "rate_bound_printed": schedule.diagnostics["rate_bound_printed"]})
    if opts.kind == "open-loop":
        return FeedbackLaw("open-loop", nom, nom.t, np.zeros((len(nom.t), model.m, model.n)))
    r = np.asarray(opts.r or np.ones(model.m), dtype=float)
    if opts.q == Q_FOOTPRINT:
        if robot is None:
            raise InputError("controller.q", "a diagonal when no robot outline is given", opts.q)
        t = nom.t
        x_mid, _ = nom.at(0.5 * (t[1:] + t[:-1]))
        K = tvlqr_gains(nom, footprint_weights(robot, nom.x), r, Q_mid=footprint_weights(robot, x_mid))
    else:
        K = tvlqr_gains(nom, np.asarray(opts.q or np.ones(model.n), dtype=float), r)
    norms = np.linalg.norm(K, ord=2, axis=(1, 2))
    return FeedbackLaw("tvlqr", nom, nom.t, K, None, {"max_gain_norm": float(norms.max())})


def footprint_weights(robot, states, floor: float = FOOTPRINT_FLOOR) -> np.ndarray:
    """Q (N, n, n) at the states (N, n): e^T Q e is, to first order, the mean squared distance the
    corners of the robot's bodies move when the state moves by e (every body's corners: the vertices of
    its outline's convex hull; a disc's centre), plus ``floor`` e_i^2 for a state that moves no corner.

    Per body with pose (p, theta) and corners c_j in its frame, a corner moves by J_p e + R'(theta) c_j
    J_theta e, where J are the body pose's derivatives by the state (central differences of
    :meth:`~nhstab.robot.Robot.body_poses`, step 1e-6: good to about 1e-9 relative, rounding). Its
    mean over the corners needs only their mean c and mean squared length |c|^2:
    J_p^T J_p + 2 sym(J_p^T R'(theta) c J_theta) + |c|^2 J_theta^T J_theta."""
    x = np.atleast_2d(np.asarray(states, dtype=float))
    N, n = x.shape
    h = 1e-6
    J = np.empty((N, len(robot.footprints), 3, n))
    for i in range(n):
        step = np.zeros(n)
        step[i] = h
        d = robot.body_poses(x + step) - robot.body_poses(x - step)
        d[..., 2] = wrap_angle(d[..., 2])          # a heading that wraps between the two
        J[..., i] = d / (2.0 * h)
    theta = robot.body_poses(x)[..., 2]
    Q = np.zeros((N, n, n))
    for b, fp in enumerate(robot.footprints):
        if fp.vertices is None:
            c_mean, c_sq = np.zeros(2), 0.0
        else:
            corners = fp.vertices[_hull(fp.vertices)]
            c_mean, c_sq = corners.mean(axis=0), float(np.mean(np.sum(corners ** 2, axis=1)))
        Jp, Jt = J[:, b, :2], J[:, b, 2]
        cs, sn = np.cos(theta[:, b]), np.sin(theta[:, b])
        arm = np.stack([-sn * c_mean[0] - cs * c_mean[1], cs * c_mean[0] - sn * c_mean[1]], axis=1)   # R' c
        cross = np.einsum("tpi,tp,tj->tij", Jp, arm, Jt)
        Q += (np.einsum("tpi,tpj->tij", Jp, Jp) + cross + cross.transpose(0, 2, 1)
              + c_sq * np.einsum("ti,tj->tij", Jt, Jt))
    Q /= len(robot.footprints)
    idle = np.all(np.diagonal(Q, axis1=1, axis2=2) <= 1e-12, axis=0)       # moves no corner at any state
    Q[:, idle, idle] += floor
    return Q


def _hull(v: np.ndarray) -> np.ndarray:
    """Indices of the convex hull's vertices of points (k, 2) (all of them for k < 3 or a degenerate set)."""
    from scipy.spatial import ConvexHull, QhullError
    try:
        return ConvexHull(v).vertices
    except QhullError:
        return np.arange(len(v))


def tvlqr_gains(nominal: Nominal, q: np.ndarray, r: np.ndarray, Q_mid: np.ndarray | None = None) -> np.ndarray:
    """K(t) = R^-1 B^T S(t) on the nominal's (uniform) grid; S from the Riccati equation
    -S' = A^T S + S A - S B R^-1 B^T S + Q, backwards from S(T) = Q.

    ``q``: Q's diagonal (n,), or Q at every grid point (N, n, n) with ``Q_mid`` (N - 1, n, n) at the
    midpoints (a time-varying Q).

    Classical RK4 backwards over the grid, A(t) and B(t) from the model's Jacobians at the grid points
    and at the midpoints of the nominal's interpolant (tested against the algebraic Riccati solution
    on a time-invariant nominal)."""
    model = nominal.model
    t = nominal.t
    h = float(t[1] - t[0])
    q = np.asarray(q, dtype=float)
    r_inv = 1.0 / r
    if q.ndim == 1:
        Q_g = np.broadcast_to(np.diag(q), (len(t),) + (len(q),) * 2)
        Q_m = Q_g[1:]
    else:
        Q_g, Q_m = q, Q_mid
    A_g, B_g = model.linearize(nominal.x, nominal.u)
    x_mid, u_mid = nominal.at(0.5 * (t[1:] + t[:-1]))
    A_m, B_m = model.linearize(x_mid, u_mid)
    BRB_g = np.einsum("tim,m,tjm->tij", B_g, r_inv, B_g)
    BRB_m = np.einsum("tim,m,tjm->tij", B_m, r_inv, B_m)

    def rate(S, A, BRB, Q):       # dS/ds for s = T - t (backwards time)
        d = A.T @ S + S @ A - S @ BRB @ S + Q
        return 0.5 * (d + d.T)

    S = np.empty(Q_g.shape)
    S[-1] = Q_g[-1]
    for k in range(len(t) - 1, 0, -1):
        Sk = S[k]
        k1 = rate(Sk, A_g[k], BRB_g[k], Q_g[k])
        k2 = rate(Sk + 0.5 * h * k1, A_m[k - 1], BRB_m[k - 1], Q_m[k - 1])
        k3 = rate(Sk + 0.5 * h * k2, A_m[k - 1], BRB_m[k - 1], Q_m[k - 1])
        k4 = rate(Sk + h * k3, A_g[k - 1], BRB_g[k - 1], Q_g[k - 1])
        S[k - 1] = Sk + (h / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)
    K = r_inv[None, :, None] * np.einsum("tnm,tnk->tmk", B_g, S)
    if not np.all(np.isfinite(K)):
        raise NumericalError("the TVLQR gains are not finite (the Riccati equation blew up)")
    return K
