"""Many trials about one shared nominal at once: the tracking phase of the composite controller,
vectorised over trials.

Robustness studies run many trials that share one nominal (same map, robot, plan and feedback law)
and differ only in their random initial error, sensor noise and process noise. For such trials the
composite controller (:class:`nhstab.execution.runner.CompositeRun`) never senses anything new,
never replans and follows the nominal to its end, so a trial is its tracking loop alone.
:func:`simulate_shared` runs K of them as one (K, n) stack.

Exact: every trial is bit-identical (``np.array_equal``) to the single-run loop with
``RunOptions(seed=seeds[i])``: the same random streams (``SeedSequence([seed, stream, 0])``, drawn in
blocks, which numpy's Generator makes equal to the loop's successive draws), the same arithmetic
in the same order (the reference, gains and feedforward evaluated by the law's own methods, the
error wrapped as :meth:`FeedbackLaw.control` wraps it, one BLAS matrix-vector product per trial as
``K @ e`` does it, :meth:`Plant.step` on the stack, which treats every row as it treats one state).
tests/test_batch_vector.py checks this against a per-trial loop and against
:func:`nhstab.execution.execute` on a planned nominal.

Measured (one core of a shared 2-core AVX-512 machine, OMP/MKL/OpenBLAS threads 1, the Hilare
sinusoid at 50 Hz: 315 steps, 4 RK4 substeps, best of 2-5): 15 trials/s for K = 1 (the per-step
Python overhead), 1,000 for K = 100, 2,600 for K = 1,000 and 10,000, with or without records. At
K = 10,000, 60 % of the time is :meth:`Plant.step` (sixteen evaluations of the model's vector
fields per step) and 20 % the per-trial generators and their block draws.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np

from ..errors import InputError
from ..execution.config import NoiseOptions
from ..execution.controllers import FeedbackLaw
from ..execution.plant import Plant
from ..execution.runner import seed_for
from ..models import Model

TRIAL_STATUSES = ("completed", "numerical_failure")
#: trials simulated together; bounds the memory of the pre-drawn noise (2 x chunk x S x n floats)
DEFAULT_CHUNK = 4096


@dataclass
class SharedResult:
    """K trials about one nominal, sampled at t_k = k T, k = 0 .. S - 1: the S - 1 control samples
    and the end sample.

    The last sample is the end of the nominal (tau >= t_end): measured like every sample, no input
    applied (u and u_ff are 0 there, as in the run log). ``e`` is the true tracking error x - x0
    with angle states wrapped to [-pi, pi) (the controller acts on the measured error y - x0). A
    trial that fails ("numerical_failure": a non-finite input or state) is frozen: its samples from
    the first one the single-run loop would not record are NaN, ``t_fail`` is that sample's time.

    Summaries per trial: ``rms_error_norm`` and ``max_error_norm`` of ||e|| over the control samples
    it recorded (the run summary's tracking statistics), ``final_error_norm`` and
    ``final_position_error`` (||e|| over the first two states, x and y for the robots) at the end
    sample, NaN for a failed trial. With ``record=False`` the per-sample arrays are None.
    """

    t: np.ndarray                    # (S,)
    x0: np.ndarray                   # (S, n) the reference x0(tau)
    u_ff: np.ndarray                 # (S, m) the feedforward: the mean of u0 over each hold interval
    seeds: np.ndarray                # (K,) root seeds
    status: np.ndarray               # (K,) one of TRIAL_STATUSES
    t_fail: np.ndarray               # (K,) NaN for a completed trial
    rms_error_norm: np.ndarray       # (K,)
    max_error_norm: np.ndarray       # (K,)
    final_error_norm: np.ndarray     # (K,)
    final_position_error: np.ndarray  # (K,)
    x_final: np.ndarray              # (K, n) the true state at the end sample (NaN if failed)
    x: np.ndarray | None = None      # (K, S, n) true states
    y: np.ndarray | None = None      # (K, S, n) measurements
    u: np.ndarray | None = None      # (K, S, m) applied inputs
    e: np.ndarray | None = None      # (K, S, n) tracking error x - x0, angles wrapped
    info: dict = field(default_factory=dict)

    @property
    def completed(self) -> np.ndarray:
        return self.status == "completed"


def _int_seeds(seeds) -> np.ndarray:
    ok = isinstance(seeds, (Sequence, np.ndarray)) and not isinstance(seeds, (str, bytes)) and len(seeds) > 0
    if ok:
        ok = all(isinstance(s, (int, np.integer)) and not isinstance(s, bool) and s >= 0 for s in seeds)
    if not ok:
        raise InputError("seeds", "a non-empty sequence of non-negative integers", seeds)
    return np.array([int(s) for s in seeds], dtype=np.int64)


def _positive(name: str, v, integer: bool = False) -> float | int:
    ok = isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) and math.isfinite(v) \
        and v > 0 and (not integer or float(v).is_integer())
    if not ok:
        raise InputError(name, "a positive integer" if integer else "a positive finite number", v)
    return int(v) if integer else float(v)


@dataclass
class _Shared:
    """What every trial shares: the sample times and, per control step, x0, u_ff, K and impulses."""

    t: np.ndarray            # (S,)
    x0: np.ndarray           # (S, n)
    u_ff: np.ndarray         # (S, m)
    K: np.ndarray            # (S - 1, m, n)
    impulses: list           # per control step: the jumps added after it, in order


def _shared(law: FeedbackLaw, T: float, t_stop: float, impulses: list) -> _Shared:
    """The loop's schedule: step k at tau = k T while tau < t_stop - 1e-9, then the end sample."""
    taus = []
    k = 0
    while k * T < t_stop - 1e-9:
        taus.append(k * T)
        k += 1
    steps = len(taus)
    taus.append(steps * T)
    model = law.nominal.model
    x0 = np.array([law.reference(tau)[0] for tau in taus]).reshape(steps + 1, model.n)
    u_ff = np.zeros((steps + 1, model.m))
    K = np.empty((steps, model.m, model.n))
    for i, tau in enumerate(taus[:-1]):
        u_ff[i] = law.mean_input(tau, tau + T)
        K[i] = law.gain(tau)
    pending = list(impulses)
    jumps = []
    for i in range(steps):
        t_next = (i + 1) * T
        now = []
        while pending and pending[0][0] < t_next - 1e-12:
            now.append(pending.pop(0)[1])
        jumps.append(now)
    return _Shared(np.array(taus), x0, u_ff, K, jumps)


def _wrap(e: np.ndarray, angles: list) -> np.ndarray:
    """Angle columns of e wrapped to [-pi, pi) in place, with FeedbackLaw.control's arithmetic."""
    if angles:
        e[:, angles] = (e[:, angles] + math.pi) % (2.0 * math.pi) - math.pi
    return e


def simulate_shared(law: FeedbackLaw, seeds: Sequence[int], noise: NoiseOptions, *, rate_hz: float = 50.0,
                    substeps: int = 4, saturate: bool = True, t_end: float | None = None, record: bool = True,
                    model: Model | None = None, chunk: int = DEFAULT_CHUNK) -> SharedResult:
    """K = len(seeds) trials tracking ``law``'s nominal, each bit-identical to the composite
    controller's loop with ``RunOptions(seed=seeds[i], noise=noise, rate_hz=..., substeps=...,
    saturate=...)`` following this law from t = 0 (no sensing, monitoring or replanning).

    ``model`` is the robot: the plant, its input limits (saturation) and state limits; by default
    the nominal's model. A nominal planned with headroom < 1 carries the derated robot (smaller
    limits), so pass the real one, as the run does. ``t_end`` stops at tau >= t_end instead of the
    nominal's end (t_end <= law.t_end). ``record`` False keeps the summaries and the final state
    only. ``chunk`` trials are simulated together (memory); results do not depend on it.
    """
    if not isinstance(law, FeedbackLaw):
        raise InputError("law", "a FeedbackLaw (pipeline.execution.build_law)", type(law).__name__)
    seeds = _int_seeds(seeds)
    if not isinstance(noise, NoiseOptions):
        raise InputError("noise", "a NoiseOptions", type(noise).__name__)
    nominal_model = law.nominal.model
    if model is None:
        model = nominal_model
    elif not (isinstance(model, Model) and model.name == nominal_model.name):
        raise InputError("model", f"a {nominal_model.name} model (the nominal's robot)", model)
    noise.validated(model.state_names)
    rate_hz = _positive("rate_hz", rate_hz)
    substeps = _positive("substeps", substeps, integer=True)
    chunk = _positive("chunk", chunk, integer=True)
    if not isinstance(saturate, bool):
        raise InputError("saturate", "true or false", saturate)
    if not isinstance(record, bool):
        raise InputError("record", "true or false", record)
    t_stop = law.t_end
    if t_end is not None:
        t_stop = _positive("t_end", t_end)
        if t_stop > law.t_end:
            raise InputError("t_end", f"at most the nominal's end, {law.t_end:.6g} s", t_end)

    T = 1.0 / rate_hz
    names = model.state_names
    sh = _shared(law, T, t_stop, noise.impulse_list(names))
    S, n, m, Kn = len(sh.t), model.n, model.m, len(seeds)
    out = {"rms": np.empty(Kn), "max": np.empty(Kn), "final": np.empty(Kn), "final_pos": np.empty(Kn),
           "x_final": np.empty((Kn, n)), "fail": np.full(Kn, S)}
    rec = {"x": np.empty((Kn, S, n)), "y": np.empty((Kn, S, n)), "u": np.empty((Kn, S, m)),
           "e": np.empty((Kn, S, n))} if record else None
    streams = {"sigma0": noise.vector("initial", names), "sensor": noise.vector("sensor", names),
               "process": noise.vector("process", names) * math.sqrt(T), "gaussian": noise.distribution == "gaussian"}
    plant = Plant(model, T, substeps)
    for lo in range(0, Kn, chunk):
        _run_chunk(law, plant, sh, streams, seeds[lo:lo + chunk], saturate, slice(lo, lo + chunk), out, rec)

    failed = out["fail"] < S
    if rec is not None:
        gone = np.arange(S)[None, :] >= out["fail"][:, None]
        for key in rec:
            rec[key][gone] = np.nan
    for key in ("final", "final_pos"):
        out[key][failed] = np.nan
    out["x_final"][failed] = np.nan
    t_fail = np.full(Kn, np.nan)
    t_fail[failed] = sh.t[out["fail"][failed]]
    info = {"period_s": T, "rate_hz": rate_hz, "substeps": substeps, "saturate": saturate, "steps": S - 1,
            "t_stop_s": t_stop, "law": law.kind, "noise": noise.describe(names), "chunk": chunk,
            "streams": "numpy SeedSequence([root, stream, 0]); streams initial=0, sensor=1, process=2 "
                       "(as a single run)"}
    return SharedResult(sh.t, sh.x0, sh.u_ff, seeds, np.where(failed, TRIAL_STATUSES[1], TRIAL_STATUSES[0]), t_fail,
                        out["rms"], out["max"], out["final"], out["final_pos"], out["x_final"],
                        **(rec or {}), info=info)


def _draws(seeds: np.ndarray, n: int, steps: int, gaussian: bool):
    """Per trial, in the loop's order: the initial draw (n,), the sensor draws (steps + 1, n) and
    the process draws (steps, n), each a block from its stream."""
    init = np.empty((len(seeds), n))
    sensor = np.empty((len(seeds), steps + 1, n))
    process = np.empty((len(seeds), steps, n))
    for i, seed in enumerate(seeds):
        rng0 = np.random.default_rng(seed_for(seed, "initial"))
        init[i] = rng0.standard_normal(n) if gaussian else rng0.uniform(-1.0, 1.0, n)
        sensor[i] = np.random.default_rng(seed_for(seed, "sensor")).standard_normal((steps + 1, n))
        process[i] = np.random.default_rng(seed_for(seed, "process")).standard_normal((steps, n))
    return init, sensor, process


def _run_chunk(law: FeedbackLaw, plant: Plant, sh: _Shared, streams: dict, seeds: np.ndarray, saturate: bool,
               rows: slice, out: dict, rec: dict | None) -> None:
    """One chunk of trials through the loop; summaries into ``out`` and samples into ``rec`` at ``rows``."""
    model = plant.model
    n, steps = model.n, len(sh.t) - 1
    angles = list(model.angle_states)
    u_lo, u_hi = model.input_limits().T
    init, z_sensor, z_process = _draws(seeds, n, steps, streams["gaussian"])
    sig_s, sig_p = streams["sensor"], streams["process"]
    Kc = len(seeds)
    fail = np.full(Kc, steps + 1)
    alive = np.ones(Kc, dtype=bool)
    sq_sum = np.zeros(Kc)
    sq_max = np.zeros(Kc)
    # non-finite values of failed trials are expected and reported by status, not by warnings
    with np.errstate(over="ignore", invalid="ignore"):
        x = np.clip(law.nominal.x[0] + streams["sigma0"] * init, *model.state_limits().T)
        for k in range(steps):
            y = x + sig_s * z_sensor[:, k]
            e_ctrl = _wrap(y - sh.x0[k], angles)
            u = sh.u_ff[k] - np.matmul(sh.K[k], e_ctrl[:, :, None])[:, :, 0]
            if saturate:
                u = np.clip(u, u_lo, u_hi)
            alive = _mark(alive, np.isfinite(u).all(axis=1), fail, k)
            e = _wrap(x - sh.x0[k], angles)
            sq = np.einsum("ij,ij->i", e, e)
            sq_sum += np.where(alive, sq, 0.0)
            np.maximum(sq_max, np.where(alive, sq, 0.0), out=sq_max)
            if rec is not None:
                _store(rec, rows, k, x, y, u, e)
            x = plant.step(x, u)
            x = x + sig_p * z_process[:, k]
            for jump in sh.impulses[k]:
                x = x + jump
            alive = _mark(alive, np.isfinite(x).all(axis=1), fail, k + 1)
        y = x + sig_s * z_sensor[:, steps]
        e = _wrap(x - sh.x0[steps], angles)
        if rec is not None:
            _store(rec, rows, steps, x, y, np.zeros((Kc, model.m)), e)
        counts = np.minimum(fail, steps)
        out["rms"][rows] = np.sqrt(sq_sum / counts)
        out["max"][rows] = np.where(counts > 0, np.sqrt(sq_max), np.nan)
        out["final"][rows] = np.sqrt(np.einsum("ij,ij->i", e, e))
        out["final_pos"][rows] = np.sqrt(np.einsum("ij,ij->i", e[:, :2], e[:, :2]))
    out["x_final"][rows] = x
    out["fail"][rows] = fail


def _mark(alive: np.ndarray, finite: np.ndarray, fail: np.ndarray, sample: int) -> np.ndarray:
    """Trials alive and finite; those that stop here record ``sample`` as their first lost one."""
    now = alive & finite
    fail[alive & ~finite] = sample
    return now


def _store(rec: dict, rows: slice, k: int, x, y, u, e) -> None:
    rec["x"][rows, k] = x
    rec["y"][rows, k] = y
    rec["u"][rows, k] = u
    rec["e"][rows, k] = e
