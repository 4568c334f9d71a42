"""Many trials about one shared nominal at once: the tracking phase of the composite controller,
vectorised over trials.

Robustness studies run many trials that share one nominal (same map, robot, plan and feedback law)
and differ only in their random initial error, sensor noise and process noise. For such trials the
composite controller (:class:`nhstab.execution.runner.CompositeRun`) never senses anything new,
never replans and follows the nominal to its end, so a trial is its tracking loop alone.
:func:`simulate_shared` runs K of them as one stack.

Exact: every trial is bit-identical (``np.array_equal``) to the single-run loop with
``RunOptions(seed=seeds[i])``: the same random streams (PCG64 seeded by ``SeedSequence([seed,
stream, 0])``, whose words are computed for all seeds at once; drawn in blocks of samples into
preallocated arrays, which numpy's Generator makes equal to the loop's successive draws), the
same arithmetic in the same order (the reference, gains and feedforward of all samples at once
with the law's own operations, element by element; the error wrapped as
:meth:`FeedbackLaw.control` wraps it; one BLAS matrix-vector product per trial as ``K @ e`` does
it; :meth:`Plant.stack_stepper` on the stack, which treats every trial as :meth:`Plant.step`
treats one state). tests/batch/test_batch_vector.py checks this against a per-trial loop and against
:func:`nhstab.execution.execute` on a planned nominal.

The stack is state-major, (n, K): a sample's reference broadcasts along contiguous rows, and the
plant step evaluates each function once per control step for all trials, substeps and RK4 stages.
What is left is what exactness fixes: one libm cosine and sine per heading and stage (numpy's
float64 sin and cos are the C library's, element by element), the normal draws of every trial's
own generators (numpy's ziggurat) and one BLAS call per trial and step.

The noise is drawn in blocks of about 8 MB per stream, not for all samples up front (370 MB for
K = 4,000 on the rwd_car parallel-parking nominal). ``nhstab bench batch`` measures the speed.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field

import numpy as np
from numpy.random.bit_generator import ISeedSequence

from ..control.interpolant import GridInterpolant
from ..errors import InputError
from ..execution.config import NoiseOptions, distance_factor, position_states
from ..execution.controllers import FeedbackLaw
from ..execution.plant import Plant, _clip
from ..execution.seeds import _SEED_STREAMS, seed_for
from ..geometry import wrap_angle
from ..models import Model

TRIAL_STATUSES = ("completed", "numerical_failure")
#: trials simulated together (the work arrays: about 150 floats per trial, and the noise blocks)
DEFAULT_CHUNK = 4096
#: the noise is drawn in blocks of samples, about this many floats per stream and block (a block has
#: at least 64 samples): 2 x chunk x block x n floats in all (8 MB per stream), not 2 x chunk x S x n
NOISE_BLOCK_FLOATS = 1 << 20


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
    interp = getattr(law, "interp", None)
    if type(law) is FeedbackLaw and type(interp) is GridInterpolant and interp.u_func is None:
        x0, u_ff, K = _schedule(law, np.array(taus), T, model.n, model.m)
    else:
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


def _locate(interp: GridInterpolant, tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """GridInterpolant.locate for an array of times, its arithmetic element by element."""
    s = (np.minimum(np.maximum(tau, interp.t0), interp.t_end) - interp.t0) / interp.h
    k = np.minimum(s.astype(np.int64), interp.last)
    return k, s - k


def _input(interp: GridInterpolant, tau: np.ndarray) -> np.ndarray:
    """GridInterpolant.input (linear u0) at an array of times, (..., m)."""
    k, a = _locate(interp, tau)
    a = a[..., None]
    return (1.0 - a) * interp.u[k] + a * interp.u[k + 1]


def _schedule(law: FeedbackLaw, taus: np.ndarray, T: float, n: int, m: int):
    """x0(tau), the mean of u0 over [tau, tau + T] and K(tau) at every step, as the law's reference,
    mean_input and gain compute them one time at a time: the same operations on the same values in
    the same order, element by element, for all times at once. A mean input over more than two
    trapezoids (a hold interval that spans more than one grid point: T > the nominal's step) is the
    law's own, one interval at a time."""
    interp = law.interp
    k, a = _locate(interp, taus)
    a2 = a * a
    a3 = a2 * a
    h00, h10, h01, h11 = (w[:, None] for w in (2 * a3 - 3 * a2 + 1, a3 - 2 * a2 + a, 3 * a2 - 2 * a3, a3 - a2))
    x0 = (h00 * interp.x[k] + h10 * interp.xd[k] + h01 * interp.x[k + 1] + h11 * interp.xd[k + 1]).reshape(-1, n)
    tau = taus[:-1]
    k, a = k[:-1], a[:-1, None, None]
    K = (1.0 - a) * interp.K[k] + a * interp.K[k + 1]
    # mean_input: the trapezoids between tau, the grid points in (tau, tau + T] and tau + T, summed
    t_to = tau + T
    first = np.searchsorted(law.t, tau, side="right")
    count = np.searchsorted(law.t, t_to, side="right") - first + 1
    u_ff = np.zeros((len(taus), m))
    for c in (1, 2):
        sel = np.flatnonzero(count == c)
        pts = np.empty((len(sel), c + 1))
        pts[:, 0], pts[:, -1] = tau[sel], t_to[sel]
        if c == 2:
            pts[:, 1] = law.t[first[sel]]
        vals = _input(interp, pts)
        terms = 0.5 * (vals[:, 1:] + vals[:, :-1]) * (pts[:, 1:] - pts[:, :-1])[:, :, None]
        total = terms[:, 0] if c == 1 else terms[:, 0] + terms[:, 1]
        u_ff[sel] = total / (t_to[sel] - tau[sel])[:, None]
    for i in np.flatnonzero(count > 2):
        u_ff[i] = law.mean_input(float(tau[i]), float(t_to[i]))
    return x0, u_ff, K


def simulate_shared(law: FeedbackLaw, seeds: Sequence[int], noise: NoiseOptions, *, rate_hz: float = 50.0,
                    substeps: int = 4, saturate: bool = True, t_end: float | None = None, record: bool = True,
                    model: Model | None = None, chunk: int = DEFAULT_CHUNK, on_states=None,
                    x_start=None) -> SharedResult:
    """K = len(seeds) trials tracking ``law``'s nominal, each bit-identical to the composite
    controller's loop with ``RunOptions(seed=seeds[i], noise=noise, rate_hz=..., substeps=...,
    saturate=...)`` following this law from t = 0 (no sensing, monitoring or replanning).

    ``model`` is the robot: the plant, its input limits (saturation) and state limits; by default
    the nominal's model. A nominal planned with headroom < 1 carries the derated robot (smaller
    limits), so pass the real one, as the run does. ``t_end`` stops at tau >= t_end instead of the
    nominal's end (t_end <= law.t_end). ``record`` False keeps the summaries and the final state
    only. ``chunk`` trials are simulated together (memory); results do not depend on it.
    ``x_start`` (n,): the mean of the initial state instead of the nominal's first state (the trials
    start at x_start + the initial error, clipped to the state limits): the rest of a maneuver from a
    measured state (a run starts at the nominal's first state).

    ``on_states(rows, k, x, u)``, if given, sees the true states as they are produced, to reduce
    them without recording (K, S, n) arrays: it is called at every sample k = 0 .. S - 1 (the end
    sample included), chunk by chunk (all samples of one chunk, then the next chunk), with ``rows``
    the chunk's slice of the K trials, ``x`` (Kc, n) the chunk's true states at t_k (what the run
    log records as x, and ``record=True`` as ``x[rows, k]``) and ``u`` (Kc, m) the inputs applied
    from t_k (after saturation; None at the end sample, where none is applied). Both are the
    engine's arrays, read-only and overwritten after the call: copy what you keep. A trial that
    failed (a non-finite input or state) is passed on with whatever the stack holds for it (not
    NaN, possibly non-finite): use ``status`` and ``t_fail`` of the result to discard its samples
    from t_fail on (the run loop records none: at t_fail its state or its input is non-finite). The hook
    runs inside the engine's ``np.errstate(over="ignore", invalid="ignore")``.
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
    if on_states is not None and not callable(on_states):
        raise InputError("on_states", "a callable on_states(rows, k, x, u) or None", on_states)
    start = law.nominal.x[0]
    if x_start is not None:
        start = np.asarray(x_start, dtype=float)
        if start.shape != (model.n,) or not np.all(np.isfinite(start)):
            raise InputError("x_start", f"{model.n} finite numbers (a state of the robot)",
                             x_start if start.size <= 12 else f"shape {start.shape}")
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
               "process": noise.process_step_std(names, T), "gaussian": noise.distribution == "gaussian",
               "start": start, "per_metre": position_states(names) if noise.per_metre else None}
    plant = Plant(model, T, substeps)
    for lo in range(0, Kn, chunk):
        _run_chunk(law, plant, sh, streams, seeds[lo:lo + chunk], saturate, slice(lo, min(lo + chunk, Kn)), out, rec,
                   on_states)

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


class _Words(ISeedSequence):
    """A seed sequence's state words computed beforehand: what PCG64 asks of its seed sequence."""

    def __init__(self, words: np.ndarray):
        self.words = words

    def generate_state(self, n_words, dtype=np.uint32):
        if n_words != len(self.words) or np.dtype(dtype) != np.dtype(np.uint64):
            raise ValueError("precomputed for PCG64: 4 uint64 words")
        return self.words


def _seed_words(seeds: np.ndarray, stream: int) -> np.ndarray:
    """SeedSequence([seed, stream, 0]).generate_state(4, np.uint64) of every seed (0 <= seed < 2**63)
    at once, (K, 4): numpy's SeedSequence (O'Neill's seed_seq_fe: the entropy's uint32 words hashed
    into a pool of four, mixed, and the pool hashed out) in uint32 arithmetic on arrays. A seed below
    2**32 is one entropy word, a larger one two."""
    seeds = np.asarray(seeds, dtype=np.uint64)
    lo, hi = (seeds & np.uint64(0xFFFFFFFF)).astype(np.uint32), (seeds >> np.uint64(32)).astype(np.uint32)
    out = np.empty((len(seeds), 4), dtype=np.uint64)
    M32, SHIFT = 0xFFFFFFFF, np.uint32(16)

    def hashmix(value, h):
        value = value ^ np.uint32(h)
        h = (h * 0x931E8875) & M32
        value = value * np.uint32(h)
        return value ^ (value >> SHIFT), h

    with np.errstate(over="ignore"):
        for two_words in (False, True):
            sel = np.flatnonzero((hi > 0) == two_words)
            if len(sel) == 0:
                continue
            G = len(sel)
            entropy = [lo[sel], *([hi[sel]] if two_words else []), np.full(G, stream, np.uint32),
                       np.zeros(G, np.uint32)]
            entropy += [np.zeros(G, np.uint32)] * (4 - len(entropy))
            h, pool = 0x43B0D7E5, []
            for word in entropy:
                word, h = hashmix(word, h)
                pool.append(word)
            for src in range(4):
                for dst in range(4):
                    if src != dst:
                        mixed, h = hashmix(pool[src], h)
                        r = np.uint32(0xCA01F9DD) * pool[dst] - np.uint32(0x4973F715) * mixed
                        pool[dst] = r ^ (r >> SHIFT)
            h, state = 0x8B51F9DD, []
            for i in range(8):
                v = pool[i % 4] ^ np.uint32(h)
                h = (h * 0x58F38DED) & M32
                v = v * np.uint32(h)
                state.append((v ^ (v >> SHIFT)).astype(np.uint64))
            out[sel] = np.stack([state[2 * i] | (state[2 * i + 1] << np.uint64(32)) for i in range(4)], axis=1)
    return out


def _generators(seeds: np.ndarray, stream: str) -> list:
    """``np.random.default_rng(seed_for(seed, stream))`` for every seed, the run's generators: PCG64
    seeded with the SeedSequence's words computed for all seeds at once (:func:`_seed_words`),
    checked against seed_for's own SeedSequence on a seed of each entropy length (else the slow way)."""
    words = _seed_words(seeds, _SEED_STREAMS[stream])
    for i in {int(np.argmax(seeds < 2**32)), int(np.argmax(seeds >= 2**32))}:
        if not np.array_equal(words[i], seed_for(int(seeds[i]), stream).generate_state(4, np.uint64)):
            return [np.random.default_rng(seed_for(int(seed), stream)) for seed in seeds]
    return [np.random.Generator(np.random.PCG64(_Words(w))) for w in words]


class _Noise:
    """A chunk's random streams, as the loop draws them: per trial the initial draw (n,) at once,
    the sensor draws (S samples) and the process draws (S - 1 steps) in blocks of ``block`` samples,
    each trial's generator filling its rows of a (Kc, block, n) array in place (``out=``: the same
    values as drawing the whole (S, n) array at once, which is the loop's successive draws). A block
    is then scaled by sigma in place: ``sample(which, b)`` is sigma * z of every trial at the block's
    sample b, state-major (n, Kc), the product the loop adds to x."""

    def __init__(self, seeds: np.ndarray, n: int, steps: int, streams: dict, block: int):
        Kc = len(seeds)
        self.block = block
        self.init = np.empty((Kc, n))
        for i, rng0 in enumerate(_generators(seeds, "initial")):
            if streams["gaussian"]:
                rng0.standard_normal(out=self.init[i])
            else:
                self.init[i] = rng0.uniform(-1.0, 1.0, n)
        self.gens = list(zip(_generators(seeds, "sensor"), _generators(seeds, "process")))
        self.sig = (streams["sensor"], streams["process"])
        self.counts = (steps + 1, steps)
        self.raw = (np.empty((Kc, block, n)), np.empty((Kc, block, n)))

    def fill(self, first: int) -> None:
        """The samples first .. first + block - 1 of both streams (those that exist)."""
        for which, raw in enumerate(self.raw):
            b = min(self.block, self.counts[which] - first)
            if b <= 0:
                continue
            part = raw[:, :b]
            for gens, rows in zip(self.gens, part):
                gens[which].standard_normal(out=rows)
            np.multiply(part, self.sig[which], out=part)

    def sample(self, which: int, b: int) -> np.ndarray:
        return self.raw[which][:, b].T


class _Wrap:
    """The angle rows of a state-major error (n, Kc) wrapped to [-pi, pi) in place with
    FeedbackLaw.control's arithmetic, (e + pi) % (2 pi) - pi. When every e + pi is in [0, 2 pi)
    (the usual case) the remainder is e + pi itself (fmod is exact; a -0.0 that it would make +0.0
    gives the same -pi), and is skipped."""

    def __init__(self, angles: list):
        self.angles = angles
        lo = angles[0] if angles else 0
        self.rows = slice(lo, lo + len(angles)) if angles == list(range(lo, lo + len(angles))) else None

    def __call__(self, e: np.ndarray) -> np.ndarray:
        if not self.angles:
            return e
        if self.rows is None:
            e[self.angles] = wrap_angle(e[self.angles])
            return e
        a = e[self.rows]
        np.add(a, math.pi, out=a)
        if not (np.minimum.reduce(a, axis=None) >= 0.0 and np.maximum.reduce(a, axis=None) < 2.0 * math.pi):
            np.remainder(a, 2.0 * math.pi, out=a)
        np.subtract(a, math.pi, out=a)
        return e


def _all_finite(a: np.ndarray) -> bool:
    """Every entry finite: a sum of finite values is finite or overflows; a non-finite one makes it
    non-finite. So a finite sum proves it, and only a non-finite one needs the entries looked at."""
    return math.isfinite(np.add.reduce(a, axis=None))


def _run_chunk(law: FeedbackLaw, plant: Plant, sh: _Shared, streams: dict, seeds: np.ndarray, saturate: bool,
               rows: slice, out: dict, rec: dict | None, on_states) -> None:
    """One chunk of trials through the loop; summaries into ``out`` and samples into ``rec`` at ``rows``.

    The chunk's states, measurements, errors and inputs are state-major, (n, Kc) and (m, Kc): the
    reference and feedforward of a sample broadcast along the rows. The gain product is taken on a
    trial-major copy of the error, (Kc, n, 1), one BLAS matrix-vector product per trial as ``K @ e``
    in the loop; the squared error norm likewise with einsum, as before."""
    model = plant.model
    n, m, steps = model.n, model.m, len(sh.t) - 1
    Kc = len(seeds)
    noise = _Noise(seeds, n, steps, streams, min(max(64, NOISE_BLOCK_FLOATS // (Kc * n)), steps + 1))
    step = plant.stack_stepper(Kc)
    wrap = _Wrap(list(model.angle_states))
    x0, u_ff = sh.x0[:, :, None], sh.u_ff[:, :, None]
    u_lo, u_hi = model.input_limits()[:, :1], model.input_limits()[:, 1:]
    fail = np.full(Kc, steps + 1)
    alive = np.ones(Kc, dtype=bool)
    everyone = True              # no trial has failed: alive is all True
    sq_sum = np.zeros(Kc)
    sq_max = np.zeros(Kc)
    x, x_next, y, e_ctrl, e = (np.empty((n, Kc)) for _ in range(5))
    per_metre = streams.get("per_metre")
    if per_metre is not None:
        ix, iy = per_metre
        dx, dy = np.empty(Kc), np.empty(Kc)
    u = np.empty((m, Kc))
    rows_ctrl, rows_e = np.empty((Kc, n)), np.empty((Kc, n))      # trial-major copies: gain product, norm
    Ke = np.empty((Kc, m, 1))
    Ke_T, e_cols = Ke[:, :, 0].T, rows_ctrl[:, :, None]
    sq = np.empty(Kc)
    if on_states is not None:        # what the caller sees: trial-major copies, read-only
        seen_x, seen_u = np.empty((Kc, n)), np.empty((Kc, m))
        shown_x, shown_u = seen_x.view(), seen_u.view()
        shown_x.flags.writeable = shown_u.flags.writeable = False
    # non-finite values of failed trials are expected and reported by status, not by warnings
    with np.errstate(over="ignore", invalid="ignore"):
        np.copyto(x, np.clip(streams["start"] + streams["sigma0"] * noise.init, *model.state_limits().T).T)
        for k in range(steps):
            b = k % noise.block
            if b == 0:
                noise.fill(k)
            np.add(x, noise.sample(0, b), out=y)
            wrap(np.subtract(y, x0[k], out=e_ctrl))
            np.copyto(rows_ctrl, e_ctrl.T)
            np.matmul(sh.K[k], e_cols, out=Ke)
            np.subtract(u_ff[k], Ke_T, out=u)
            if saturate:
                _clip(u, u_lo, u_hi, out=u)
            if not (everyone and _all_finite(u)):
                alive = _mark(alive, np.isfinite(u).all(axis=0), fail, k)
                everyone = bool(alive.all())
            wrap(np.subtract(x, x0[k], out=e))
            np.copyto(rows_e, e.T)
            np.einsum("ij,ij->i", rows_e, rows_e, out=sq)
            if not everyone:
                sq = np.where(alive, sq, 0.0)
            sq_sum += sq
            np.maximum(sq_max, sq, out=sq_max)
            if rec is not None:
                _store(rec, rows, k, x, y, u, e)
            if on_states is not None:
                np.copyto(seen_x, x.T)
                np.copyto(seen_u, u.T)
                on_states(rows, k, shown_x, shown_u)
            step(x, u, x_next)
            if per_metre is None:
                np.add(x_next, noise.sample(1, b), out=x_next)
            else:                    # std intensity * sqrt(distance moved), as the loop: dx * dx + dy * dy
                np.subtract(x_next[ix], x[ix], out=dx)
                np.subtract(x_next[iy], x[iy], out=dy)
                np.multiply(dx, dx, out=dx)
                np.multiply(dy, dy, out=dy)
                np.add(dx, dy, out=dx)
                np.add(x_next, noise.sample(1, b) * distance_factor(dx), out=x_next)
            for jump in sh.impulses[k]:
                np.add(x_next, jump[:, None], out=x_next)
            if not (everyone and _all_finite(x_next)):
                alive = _mark(alive, np.isfinite(x_next).all(axis=0), fail, k + 1)
                everyone = bool(alive.all())
            x, x_next = x_next, x
        if steps % noise.block == 0:
            noise.fill(steps)
        np.add(x, noise.sample(0, steps % noise.block), out=y)
        wrap(np.subtract(x, x0[steps], out=e))
        np.copyto(rows_e, e.T)
        if rec is not None:
            _store(rec, rows, steps, x, y, np.zeros((m, Kc)), e)
        if on_states is not None:
            np.copyto(seen_x, x.T)
            on_states(rows, steps, shown_x, None)
        counts = np.minimum(fail, steps)
        out["rms"][rows] = np.sqrt(sq_sum / counts)
        out["max"][rows] = np.where(counts > 0, np.sqrt(sq_max), np.nan)
        out["final"][rows] = np.sqrt(np.einsum("ij,ij->i", rows_e, rows_e))
        out["final_pos"][rows] = np.sqrt(np.einsum("ij,ij->i", rows_e[:, :2], rows_e[:, :2]))
    out["x_final"][rows] = x.T
    out["fail"][rows] = fail


def _mark(alive: np.ndarray, finite: np.ndarray, fail: np.ndarray, sample: int) -> np.ndarray:
    """Trials alive and finite; those that stop here record ``sample`` as their first lost one."""
    now = alive & finite
    fail[alive & ~finite] = sample
    return now


def _store(rec: dict, rows: slice, k: int, x, y, u, e) -> None:
    """Sample k of the chunk's state-major arrays into the (K, S, ...) records."""
    rec["x"][rows, k] = x.T
    rec["y"][rows, k] = y.T
    rec["u"][rows, k] = u.T
    rec["e"][rows, k] = e.T
