"""The stepper's hot path: a control loop's call of one measured state on buffers made once (:class:`FastPath`), and
the stop on buffers too (:class:`StopPlan`), for :class:`~seqmotion.deploy.onnx_stepper.OnnxStepper`.

The sessions are bound to preallocated arrays (onnxruntime's I/O binding, one thread), the decoder's windows are
slices of a history of states, and the plan's states are predicted one per call (closed form, or the bundle's
``dynamics_sample.onnx``): a chunk boundary costs one decoder run, like any call, and no call makes a NumPy array or
a Python container. What the next call needs that no measurement changes (the predicted window's decoder run)
can be made between calls (``OnnxStepper.prepare``), so a call holds one decoder run. Its outputs are the shared
code's (:mod:`seqmotion.core.stepper`), bit for bit. Shipped in every ONNX bundle beside ``onnx_stepper.py``.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

try:  # inside the seqmotion package
    from ..core.stepper import MAX_ABS_STATE
except ImportError:  # the standalone copy that export-onnx writes beside the graphs
    from stepper import MAX_ABS_STATE  # type: ignore[no-redef]


def first_line(exc: BaseException) -> str:
    """onnxruntime's message on one line (its own are several, with a source location)."""
    return " ".join(str(exc).split())[:400] or type(exc).__name__

F32, F64 = np.dtype(np.float32), np.dtype(np.float64)


class Bound:
    """One graph's session run on fixed NumPy buffers (onnxruntime's I/O binding): the inputs are read from, and
    the outputs written into, the arrays given here, so a run hands no array between Python and onnxruntime.
    The arrays must be C-contiguous and are kept alive here; the caller fills the inputs in place."""

    __slots__ = ("binding", "buffers", "session", "where")

    def __init__(self, model: Any, key: str, session: Any, inputs: dict[str, np.ndarray],
                 outputs: dict[str, np.ndarray]) -> None:
        binding = session.io_binding()
        taken = {i.name for i in session.get_inputs()}  # a graph may not read every input
        for name, array in inputs.items():
            if name in taken:
                binding.bind_cpu_input(name, array)
        for name, array in outputs.items():
            binding.bind_output(name, "cpu", 0, array.dtype.type, list(array.shape), array.ctypes.data)
        self.binding, self.session, self.where = binding, session, model.where(key)
        self.buffers = (inputs, outputs)

    def __call__(self) -> None:
        try:
            # no RunOptions: onnxruntime's Python wrapper reads their configuration on every run (~30 µs)
            self.session.run_with_iobinding(self.binding)
        except Exception as exc:  # onnxruntime's own: a graph that does not run at these shapes
            raise ValueError(f"{self.where}: onnxruntime failed running it: {first_line(exc)}") from None


class Finite:
    """Whether a fixed array holds only finite numbers, through a flag buffer made once (``ndarray.all`` would
    make its result and scratch arrays)."""

    __slots__ = ("array", "flags", "size")

    def __init__(self, array: np.ndarray) -> None:
        self.array, self.flags, self.size = array, np.zeros(array.shape, dtype=bool), array.size

    def __call__(self) -> bool:
        np.isfinite(self.array, out=self.flags)
        return np.count_nonzero(self.flags) == self.size


def refuse_nan(where: str, finite: Finite) -> None:
    """Never hand on what a graph computed with NaN or inf (``OnnxModel._run``'s refusal)."""
    if not finite():
        raise ValueError(f"{where}: its output holds NaN or inf: refused (inputs far outside the model's range, or a "
                         "graph that is not this model's)")


class StopViews:
    """What a stop of n samples reads and writes (:class:`StopPlan`): views of its buffers and the violation's
    bound session at this n, made once per n."""

    def __init__(self, plan: StopPlan, n: int) -> None:
        r, rows, s, d = plan.ns, plan.rows, plan.s, plan.d
        self.i = plan.index[:, :n]
        self.v_lin = np.zeros((1, n, d))
        self.v, self.expo, self.a = np.zeros((r, n, d)), np.zeros((r, n, d)), np.zeros((r, n, d))
        self.clipped, self.still = np.zeros((r, n, d), dtype=bool), np.zeros((r, n), dtype=bool)
        self.still3 = self.still[..., None]
        self.vmax = np.zeros((r, n))
        self.accel = plan.accel[:r, :n]
        self.coast = plan.accel[r:, :n]
        self.accel_pad = plan.accel[:, n:]
        self.outputs = plan.outputs[:, :n]
        self.outputs_pad = plan.outputs[:, n:]
        self.rows = [self.outputs[k] for k in range(rows)]
        self.states = plan.states[:, :n]
        self.outputs_finite, self.states_finite = Finite(self.outputs), Finite(self.states)
        if plan.constraint:
            self.v_states = np.zeros((rows, n + 1, s), dtype=np.float32)
            self.v_first, self.v_rest = self.v_states[:, 0], self.v_states[:, 1:]
            self.v_accel = np.zeros((rows, n, d), dtype=np.float32)
            self.v_out = np.zeros((rows, n), dtype=np.float32)
            self.violation_finite = Finite(self.v_out)
            self.violation = Bound(plan.model, "violation", plan.model.violation_session,
                                    {"states": self.v_states, "accel": self.v_accel}, {"violation": self.v_out})
            self.worst = np.zeros(rows, dtype=np.float32)
            self.worst_shrunk = self.worst[:r]
        if plan.constraint and plan.closed:  # numpy_physics.integrate on buffers
            self.ndt = np.arange(1, n + 1, dtype=np.float64)[None, :, None] * plan.dt
            self.s1, self.s2, self.tmp = (np.zeros((rows, n, d)) for _ in range(3))
            self.s2_first, self.s2_rest, self.s1_head = self.s2[:, :1], self.s2[:, 1:], self.s1[:, :-1]
            self.pos, self.vel = plan.states[:, :n, :d], plan.states[:, :n, d:]
            self.p0, self.v0 = plan.start[:, None, :d], plan.start[:, None, d:]


class StopPlan:
    """The stop (``stepper.py``, "The end") of one motion (B = 1) on fixed buffers: ``stop_accel`` for all the
    shrink factors at once, the candidates' outputs (``outputs_for``), their states and the constraint's violation
    through bound sessions, then the pick. The same operations in the same order as ``StepperCore._stop``, so the
    same numbers; only where they are written differs (buffers made once, views once per length n)."""

    def __init__(self, gen: Any) -> None:
        m, contract = gen.onnx, gen.onnx.contract
        c, s, d = m.chunk, m.state_dim, m.accel_dim
        self.model, self.c, self.s, self.d, self.dt = m, c, s, d, m.dt
        self.velocity = np.asarray(gen._velocity, dtype=np.intp)
        self.constraint = bool(contract["constraint"])
        self.mapped = gen._outputs == "outputs_for"
        self.closed = m.closed_form == "double_integrator"
        scales = gen._shrink if self.constraint else (1.0,)
        self.ns = len(scales)
        self.rows = self.ns + 1 if self.constraint else 1  # the shrunk decelerations, then coasting
        self.tol, self.rest = gen._tol, gen._rest
        rate = np.asarray(scales, dtype=np.float64) / gen._tau  # (R,): stop_accel's scale / tau
        lim = gen._limit[None, :]
        self.lim_rate = lim / rate[:, None]  # (R, d)
        self.lim_dt = lim * self.dt  # (1, d)
        self.lim_dt3 = self.lim_dt[:, None, :]
        self.neg_rate3 = -rate[:, None, None]  # (R, 1, 1)
        self.base3 = 1.0 - rate[:, None, None] * self.dt
        self.lim3 = lim[:, None, :]
        self.index = np.arange(c, dtype=np.float64)[None, :, None]  # (1, C, 1)
        self.v0, self.speed, self.sign = np.zeros((1, d)), np.zeros((1, d)), np.zeros((1, d))
        self.neg_sign_lim3 = np.zeros((1, 1, d))
        self.steps, self.v_m = np.zeros((self.ns, d)), np.zeros((self.ns, d))  # clipped_steps, v_m
        self.steps3, self.v_m3 = self.steps[:, None, :], self.v_m[:, None, :]
        self.speed3, self.sign3 = self.speed[:, None, :], self.sign[:, None, :]
        # the candidates (rows, C, d): the planned accelerations, coasting's zeros, (mapped) the outputs that give
        # them; padded past n with zeros, as the runner pads a chunk
        self.accel = np.zeros((self.rows, c, d))
        self.outputs = np.zeros((self.rows, c, d)) if self.mapped else self.accel
        self.start = np.zeros((self.rows, s))
        self.states = np.zeros((self.rows, c, s))
        physics = {"physics": gen._physics} if m.physics_inputs else {}
        self.outputs_for = Bound(m, "outputs_for", m.outputs_for_session, {"x": self.start, "accel": self.accel,
                                                                            **physics}, {"outputs": self.outputs}) \
            if self.mapped else None
        self.dynamics = Bound(m, "dynamics", m.dynamics_session, {"x": self.start, "accel": self.outputs, **physics},
                               {"states": self.states}) if self.constraint and not self.closed else None
        self.views: dict[int, StopViews] = {}

    def plan(self, x: np.ndarray, n: int, out: np.ndarray) -> None:
        """Write the stop's n outputs from the state ``x`` ``(1, S)`` into ``out`` ``(n, d)``."""
        w = self.views.get(n)
        if w is None:
            w = self.views[n] = StopViews(self, n)
        # stop_accel(v0, n, scale, tau, limit, dt, rest) (core/stepper.py) for every shrink factor at once
        np.take(x, self.velocity, axis=1, out=self.v0)
        np.abs(self.v0, out=self.speed)
        np.sign(self.v0, out=self.sign)
        np.subtract(self.speed, self.lim_rate, out=self.steps)
        np.divide(self.steps, self.lim_dt, out=self.steps)
        np.ceil(self.steps, out=self.steps)
        np.maximum(self.steps, 0.0, out=self.steps)
        np.less(w.i, self.steps3, out=w.clipped)
        np.multiply(self.lim_dt3, w.i, out=w.v_lin)
        np.subtract(self.speed3, w.v_lin, out=w.v_lin)
        np.multiply(self.sign3, w.v_lin, out=w.v_lin)
        np.multiply(self.lim_dt, self.steps, out=self.v_m)
        np.subtract(self.speed, self.v_m, out=self.v_m)
        np.maximum(self.v_m, 0.0, out=self.v_m)
        np.multiply(self.sign, self.v_m, out=self.v_m)
        np.subtract(w.i, self.steps3, out=w.expo)
        np.maximum(w.expo, 0.0, out=w.expo)
        np.power(self.base3, w.expo, out=w.v)
        np.multiply(self.v_m3, w.v, out=w.v)
        np.copyto(w.v, w.v_lin, where=w.clipped)  # v = where(clipped, v_lin, v_geo)
        np.multiply(self.neg_rate3, w.v, out=w.a)
        np.negative(self.sign3, out=self.neg_sign_lim3)
        np.multiply(self.neg_sign_lim3, self.lim3, out=self.neg_sign_lim3)
        np.copyto(w.a, self.neg_sign_lim3, where=w.clipped)
        np.abs(w.v, out=w.expo)
        np.max(w.expo, axis=2, out=w.vmax)
        np.less_equal(w.vmax, self.rest, out=w.still)
        np.logical_or.accumulate(w.still, axis=1, out=w.still)
        np.copyto(w.a, 0.0, where=w.still3)
        np.copyto(w.accel, w.a)
        w.accel_pad.fill(0.0)
        w.coast.fill(0.0)  # coasting (constraint only: no row otherwise)
        np.copyto(self.start, x)
        if self.outputs_for is not None:
            self.outputs_for()
            w.outputs_pad.fill(0.0)  # their states are predicted from the outputs padded, as the runner pads
            refuse_nan(self.outputs_for.where, w.outputs_finite)
        if not self.constraint:
            np.copyto(out, w.rows[0])
            return
        if self.dynamics is None:  # numpy_physics.integrate, in the same order
            np.cumsum(w.outputs, axis=1, out=w.s1)
            w.s2_first.fill(0.0)
            np.cumsum(w.s1_head, axis=1, out=w.s2_rest)
            np.multiply(w.ndt, w.v0, out=w.tmp)
            np.add(w.p0, w.tmp, out=w.pos)
            np.multiply(w.s1, 0.5, out=w.tmp)
            np.add(w.s2, w.tmp, out=w.tmp)
            np.multiply(self.dt ** 2, w.tmp, out=w.tmp)
            np.add(w.pos, w.tmp, out=w.pos)
            np.multiply(self.dt, w.s1, out=w.tmp)
            np.add(w.v0, w.tmp, out=w.vel)
        else:
            self.dynamics()
            refuse_nan(self.dynamics.where, w.states_finite)
        np.copyto(w.v_first, self.start)
        np.copyto(w.v_rest, w.states)
        np.copyto(w.v_accel, w.outputs)
        w.violation()
        refuse_nan(w.violation.where, w.violation_finite)
        np.max(w.v_out, axis=1, out=w.worst)
        ns, tol = self.ns, self.tol
        coast = float(w.worst[ns])
        limit = max(coast, 0.0) + tol
        pick = -1
        for k in range(ns):
            if float(w.worst[k]) <= limit:  # the largest shrink no worse than not decelerating
                pick = k
                break
        if pick < 0:  # none: stop promptly where even coasting breaks the constraint, else the least violating
            pick = 0 if coast > tol else int(np.argmin(w.worst_shrunk))
        np.copyto(out, w.rows[pick])


class FastPath:
    """The stepper's steady state for one motion (B = 1) on fixed buffers: what ``StepperCore.step`` computes for a
    call of one measured state inside a chunk the decoder planned whole (the replanning correction), at a chunk
    boundary inside the motion, and past its end (the stop), with every array made once.

    * The decoder runs through bound sessions (:class:`Bound`): at a boundary at B = 1 from one of two state
      buffers into the other (they take turns); between boundaries on W_meas and W_pred from the boundary's state,
      in one run at B = 2. W_pred's run needs no measurement: :meth:`prepare` makes it at B = 1 (and the predicted
      states it reads) before the call, after the loop sent its command; the call then runs W_meas alone at B = 1.
    * The windows are slices of two histories of 2C states (float32): the chunk's window, then the states measured
      (resp. predicted) in the chunk, so W_meas at position j is ``measured_history[j:j+C]``.
    * The plan's predicted states are computed one per call, as the correction needs them (row j−1 at position j),
      instead of the whole chunk at its boundary: in closed form (the double integrator's running sums, the same
      operations as ``numpy_physics.integrate``), or one sample of the bundle's ``dynamics_sample`` graph. A bundle
      without that graph predicts the whole chunk at the boundary through the bound ``dynamics`` graph.
    * Anything else (the first call, a restart, a call of several states, the chunk where the motion ends, a batch)
      runs ``StepperCore.step`` on the same attributes: the rows not yet predicted are filled in first, and a chunk it
      planned whole is taken over afterwards.
    """

    def __init__(self, gen: Any) -> None:
        m = gen.onnx
        c, s, d, layers, hidden = m.chunk, m.state_dim, m.accel_dim, m.layers, m.hidden
        self.gen, self.c, self.s, self.d, self.dt = gen, c, s, d, m.dt
        key = m._decoder_key
        state = (layers, 1, hidden)
        self.ping = [(np.zeros(state, F32), np.zeros(state, F32)) for _ in range(2)]
        self.history_m = np.zeros((2 * c, s), F32)  # the chunk's window, then the states measured in it
        self.history_p = np.zeros((2 * c, s), F32)  # the chunk's window, then the states the plan predicts
        self.accel1 = np.zeros((1, c, d), F32)
        window = self.history_m[c:].reshape(1, c, s)  # the chunk just measured: the next boundary's window
        self.decode1 = [Bound(m, key, m.decoder, {"h": self.ping[i][0], "c": self.ping[i][1], "window": window},
                               {"h_out": self.ping[1 - i][0], "c_out": self.ping[1 - i][1], "accel": self.accel1})
                        for i in (0, 1)]
        # the replanning correction: the decoder's step from the chunk's boundary state on the measured window and
        # on the predicted one: both in one run at B = 2 (the weights read once), or, where prepare ran the
        # predicted one at B = 1 ahead of the call, the measured one at B = 1 (rows of a B = 2 run bit for bit)
        self.h2, self.c2 = np.zeros((layers, 2, hidden), F32), np.zeros((layers, 2, hidden), F32)
        self.window2 = np.zeros((2, c, s), F32)
        self.accel2 = np.zeros((2, c, d), F32)
        self.decode2 = Bound(m, key, m.decoder, {"h": self.h2, "c": self.c2, "window": self.window2},
                              {"h_out": np.zeros_like(self.h2), "c_out": np.zeros_like(self.c2),
                               "accel": self.accel2})
        self.h1, self.c1 = np.zeros(state, F32), np.zeros(state, F32)
        scratch = {"h_out": np.zeros(state, F32), "c_out": np.zeros(state, F32)}
        self.window_in_p = np.zeros((1, c, s), F32)
        self.accel_m, self.accel_p = np.zeros((1, c, d), F32), np.zeros((1, c, d), F32)
        # the measured window's run at position p reads history_m[p:p+C] where it lies (rows of a C-contiguous
        # array: contiguous), one binding per position, so the call copies no window
        self.decode_m = [Bound(m, key, m.decoder, {"h": self.h1, "c": self.c1,
                                                   "window": self.history_m[p:p + c].reshape(1, c, s)},
                               {**scratch, "accel": self.accel_m}) for p in range(c)]
        self.decode_p = Bound(m, key, m.decoder, {"h": self.h1, "c": self.c1, "window": self.window_in_p},
                              {**scratch, "accel": self.accel_p})
        self.prepared = -1  # the position whose predicted window's response is in accel_p64 (-1: none)
        self.plan = np.zeros((1, c, d))
        self.pred = np.zeros((1, c, s))
        self.start = np.zeros((1, s))  # the state at the chunk's boundary, where its prediction starts
        self.predicted = c  # rows of pred made so far
        self.closed = m.closed_form == "double_integrator"
        physics = {"physics": gen._physics} if m.physics_inputs else {}
        self.sample = None
        self.chunk_prediction = None
        if self.closed:
            self.s1, self.s2, self.tmp = np.zeros((1, d)), np.zeros((1, d)), np.zeros((1, d))
            self.p0, self.v0 = self.start[:, :d], self.start[:, d:]
            self.ndt = np.arange(1, c + 1, dtype=np.float64) * self.dt
        elif m.sample_session is not None:
            self.x_in, self.a_in, self.x_out = np.zeros((1, s)), np.zeros((1, 1, d)), np.zeros((1, 1, s))
            self.a_in0, self.x_out0 = self.a_in[0], self.x_out[0]
            self.sample = Bound(m, "dynamics_sample", m.sample_session,
                                 {"x": self.x_in, "accel": self.a_in, **physics}, {"states": self.x_out})
            self.x_out_finite = Finite(self.x_out)
        else:
            self.chunk_prediction = Bound(m, "dynamics", m.dynamics_session,
                                           {"x": self.start, "accel": self.plan, **physics}, {"states": self.pred})
            self.pred_finite = Finite(self.pred)
        self.out = np.zeros((c, d))
        self.stop = StopPlan(gen) if gen._velocity is not None else None
        # views made once: per position p in the chunk, per count k of rows
        self.meas_rows: list[np.ndarray] = []
        self.measured_of: np.ndarray | None = None
        self.window_m = [self.history_m[p:p + c] for p in range(c)]
        self.row_block_m = self.history_m[c:]
        self.window_p = [self.history_p[p:p + c] for p in range(c)]
        self.row_m = [self.history_m[c + p:c + p + 1] for p in range(c)]
        self.row_p = [self.history_p[c + p:c + p + 1] for p in range(c)]
        self.pred_row = [self.pred[0, p:p + 1] for p in range(c)]
        self.pos_row = [self.pred[0, p:p + 1, :d] for p in range(c)]
        self.vel_row = [self.pred[0, p:p + 1, d:] for p in range(c)]
        self.plan_row = [self.plan[0, p:p + 1] for p in range(c)]
        self.plan_tail = [self.plan[0, p:] for p in range(c)]
        self.accel2_64 = np.zeros((2, c, d))
        self.accel_m64, self.accel_p64 = self.accel2_64[0], self.accel2_64[1]
        self.accel_m_head = [self.accel_m64[:k] for k in range(c + 1)]
        self.accel_p_head = [self.accel_p64[:k] for k in range(c + 1)]
        self.plan0 = self.plan[0]
        self.accel1_finite = Finite(self.accel1)
        self.max_abs = np.array(MAX_ABS_STATE)
        self.window2_m, self.window2_p = self.window2[0], self.window2[1]
        self.window_in_p0 = self.window_in_p[0]
        self.accel_m0, self.accel_p0 = self.accel_m[0], self.accel_p[0]
        self.accel_m32_head = [self.accel_m0[:k] for k in range(c + 1)]
        self.heads: tuple[np.ndarray, list[np.ndarray]] = (self.out, [self.out[:k] for k in range(c + 1)])
        self.finite = np.zeros((c, d), dtype=bool)
        self.finite_head = [self.finite[:k] for k in range(c + 1)]
        self.check = np.zeros((1, s))
        self.check_ok = np.zeros((1, s), dtype=bool)
        self.history = np.zeros((0, 1, c, s))
        self.history_views: list[np.ndarray] = []
        self.active = False  # whether the chunk under way is this path's (planned here, or taken over)
        self.final = False  # whether it is the chunk in which the motion ends, planned here
        # the chunk in which the motion ends: states predicted for n outputs at once (the core's predict)
        self.row_block_p = self.history_p[c:]
        self.plan_head = [self.plan[0, :k] for k in range(c + 1)]
        self.batch_a = np.zeros((1, c, d))
        self.batch_x = np.zeros((1, s))
        self.batch_states = np.zeros((1, c, s))
        self.batch_head = [self.batch_a[0, :k] for k in range(c + 1)]
        self.batch_pad = [self.batch_a[:, k:] for k in range(c + 1)]
        self.batch_last = [self.batch_states[:, max(k - 1, 0)] for k in range(c + 1)]
        self.batch_views: dict[int, tuple] = {}
        self.batch_run = None if self.closed else Bound(
            m, "dynamics", m.dynamics_session, {"x": self.batch_x, "accel": self.batch_a, **physics},
            {"states": self.batch_states})
        self.batch_finite = Finite(self.batch_states)

    # --- the pieces -------------------------------------------------------------------------------------

    def heads_of(self, out: np.ndarray) -> list[np.ndarray]:
        """``out[:k]`` for each k, made once per output array."""
        if self.heads[0] is not out:
            self.heads = (out, [out[:k] for k in range(self.c + 1)])
        return self.heads[1]

    def measured_rows(self) -> list[np.ndarray]:
        """``gen._measured[0, p:p+1]`` per position (the core makes a new array at each reset)."""
        measured = self.gen._measured
        if self.measured_of is not measured:
            self.measured_of, self.meas_rows = measured, [measured[0, p:p + 1] for p in range(self.c)]
        return self.meas_rows

    def history_slot(self, k: int) -> np.ndarray:
        """Where the window of the motion's chunk k is kept (``gen._history``, for ``set_latent``'s replay)."""
        if k >= len(self.history_views):
            grown = np.zeros((max(2 * k, k + 8, math.ceil(self.gen._length / self.c) + 1), 1, self.c, self.s))
            grown[: len(self.history_views)] = self.history[: len(self.history_views)]
            self.history = grown
            self.history_views = [grown[i] for i in range(grown.shape[0])]
        return self.history_views[k]

    def predict(self, upto: int) -> None:
        """Make the plan's predicted states up to row ``upto`` (exclusive), one sample at a time."""
        p = self.predicted
        if p >= upto:
            return
        if self.chunk_prediction is not None:  # no one-sample graph: the whole chunk at once
            self.chunk_prediction()
            refuse_nan(self.chunk_prediction.where, self.pred_finite)
            for i in range(self.c):
                np.copyto(self.row_p[i], self.pred_row[i])
            self.predicted = self.c
            return
        while p < upto:
            if self.closed:  # numpy_physics.integrate, row by row: S2 += S1 (before), S1 += u; the same sums
                np.add(self.s2, self.s1, out=self.s2)
                np.add(self.s1, self.plan_row[p], out=self.s1)
                np.multiply(self.v0, self.ndt[p], out=self.tmp)
                np.add(self.p0, self.tmp, out=self.pos_row[p])
                np.multiply(self.s1, 0.5, out=self.tmp)
                np.add(self.s2, self.tmp, out=self.tmp)
                np.multiply(self.tmp, self.dt ** 2, out=self.tmp)
                np.add(self.pos_row[p], self.tmp, out=self.pos_row[p])
                np.multiply(self.s1, self.dt, out=self.tmp)
                np.add(self.v0, self.tmp, out=self.vel_row[p])
            else:
                np.copyto(self.x_in, self.start if p == 0 else self.pred_row[p - 1])
                np.copyto(self.a_in0, self.plan_row[p])
                self.sample()
                refuse_nan(self.sample.where, self.x_out_finite)
                np.copyto(self.pred_row[p], self.x_out0)
            np.copyto(self.row_p[p], self.pred_row[p])
            p += 1
        self.predicted = p

    def begin_prediction(self, start: np.ndarray) -> None:
        np.copyto(self.start, start)
        self.predicted = 0
        self.prepared = -1
        if self.closed:
            self.s1.fill(0.0)
            self.s2.fill(0.0)

    def predict_batch(self, x: np.ndarray, outputs: np.ndarray, n: int) -> None:
        """The states the n outputs ``outputs`` ``(n, d)`` give from ``x`` ``(1, S)`` into ``batch_states[:, :n]``:
        the runner's ``predict`` (the closed form's same operations; the graph on the outputs padded with zeros)."""
        np.copyto(self.batch_head[n], outputs)
        if self.batch_run is not None:
            np.copyto(self.batch_x, x)
            self.batch_pad[n].fill(0.0)
            self.batch_run()
            refuse_nan(self.batch_run.where, self.batch_finite)
            return
        views = self.batch_views.get(n)
        if views is None:
            d = self.d
            s1, s2, tmp = np.zeros((1, n, d)), np.zeros((1, n, d)), np.zeros((1, n, d))
            views = self.batch_views[n] = (
                self.batch_a[:, :n], s1, s2, tmp, s2[:, :1], s2[:, 1:], s1[:, :-1],
                np.arange(1, n + 1, dtype=np.float64)[None, :, None] * self.dt,
                self.batch_states[:, :n, :d], self.batch_states[:, :n, d:], self.batch_x[:, None, :d],
                self.batch_x[:, None, d:])
        u, s1, s2, tmp, s2_first, s2_rest, s1_head, ndt, pos, vel, p0, v0 = views
        np.copyto(self.batch_x, x)
        np.cumsum(u, axis=1, out=s1)  # numpy_physics.integrate, in the same order
        s2_first.fill(0.0)
        np.cumsum(s1_head, axis=1, out=s2_rest)
        np.multiply(ndt, v0, out=tmp)
        np.add(p0, tmp, out=pos)
        np.multiply(s1, 0.5, out=tmp)
        np.add(s2, tmp, out=tmp)
        np.multiply(self.dt ** 2, tmp, out=tmp)
        np.add(pos, tmp, out=pos)
        np.multiply(self.dt, s1, out=tmp)
        np.add(v0, tmp, out=vel)

    def emit_checked(self, heads: list[np.ndarray], k: int) -> None:
        np.isfinite(heads[k], out=self.finite_head[k])
        if np.count_nonzero(self.finite_head[k]) != k * self.d:  # never hand NaN to a robot (StepperCore._emit)
            raise ValueError("the measured states drove the decoder out of its numeric range (NaN outputs); "
                             "check the measurements, then reset() the generator")

    # --- the calls --------------------------------------------------------------------------------------

    def boundary(self, heads: list[np.ndarray]) -> None:
        """A chunk boundary inside the motion, with the next chunk the decoder's whole: plan it (one decoder run
        at B = 1); its states are predicted over the calls that follow (:meth:`predict`)."""
        self.plan_chunk()
        np.copyto(heads[self.c], self.plan0)
        self.emit_checked(heads, self.c)
        self.active = True

    def final_boundary(self, motion: int, heads: list[np.ndarray]) -> None:
        """The boundary of the chunk in which the motion ends after ``motion`` outputs: plan it, predict its states
        at once (the stop starts from the state its last output of the motion gives), then the stop."""
        c = self.c
        self.plan_chunk()
        self.predict_batch(self.gen._latest, self.plan0, c)
        np.copyto(self.pred, self.batch_states)
        np.copyto(self.row_block_p, self.pred[0])
        self.predicted = c
        head = heads[c]
        np.copyto(heads[motion], self.plan_head[motion])
        self.stop_into(self.pred_row[motion - 1], c - motion, head[motion:])
        self.emit_checked(heads, c)
        self.final = True

    def final_between(self, j: int, motion: int, heads: list[np.ndarray]) -> None:
        """Position j of the chunk in which the motion ends, ``motion`` of its outputs still the motion's: those
        (corrected as between boundaries), then the stop from the state they lead to."""
        total = self.c - j
        self.correct(j, motion, heads[motion])
        self.predict_batch(self.gen._latest, heads[motion], motion)
        self.stop_into(self.batch_last[motion], total - motion, heads[total][motion:])
        self.emit_checked(heads, total)

    def stop_into(self, x: np.ndarray, k: int, head: np.ndarray) -> None:
        if self.stop is None:
            head.fill(0.0)
        else:
            self.stop.plan(x, k, head)

    def correct(self, j: int, k: int, head: np.ndarray) -> None:
        """The plan's rows j..j+k corrected by the decoder's response to the measured window against the
        predicted one, into ``head`` ``(k, d)``; without replanning the plan's rows. Where a ``prepare`` made the
        predicted window's response for this position (:meth:`prepare_at`), one decoder run at B = 1 on the
        measured window; otherwise both windows in one run at B = 2."""
        if self.gen.replan:
            if self.prepared == j:
                self.decode_m[j]()
                # float32 - float64: NumPy casts the first exactly, as the core's float64 copy does
                np.subtract(self.accel_m32_head[k], self.accel_p_head[k], out=head)
            else:
                self.predict(j)
                np.copyto(self.window2_m, self.window_m[j])
                np.copyto(self.window2_p, self.window_p[j])
                self.decode2()
                np.copyto(self.accel2_64, self.accel2)
                np.subtract(self.accel_m_head[k], self.accel_p_head[k], out=head)
            self.prepared = -1
            np.add(self.plan_tail_k(j, k), head, out=head)
        else:
            np.copyto(head, self.plan_tail_k(j, k))

    def prepare_at(self, j: int) -> None:
        """What the correction at position j needs that no measurement changes: the plan's predicted states up to
        row j−1 and the decoder's response to the window they make."""
        self.predict(j)
        np.copyto(self.window_in_p0, self.window_p[j])
        self.decode_p()
        np.copyto(self.accel_p64, self.accel_p0)
        self.prepared = j

    def prepare(self) -> None:
        """Before the next call, if it is one measured state between boundaries of a chunk planned here (the
        control loop's ``prepare`` after its command went out): that call's :meth:`prepare_at`, so the call holds
        one decoder run. Anything else (a boundary next, the stop, no replanning) has nothing to prepare."""
        gen = self.gen
        if not (gen.replan and (self.active or self.final)):
            return
        c = self.c
        tau = gen._t - gen._origin + 1  # the next call's, one state measured
        j = tau % c
        if j == 0 or self.prepared == j or min(c, gen._length - 1 - (tau - j)) - j <= 0:
            return
        self.prepare_at(j)

    def plan_tail_k(self, j: int, k: int) -> np.ndarray:
        return self.plan_tail[j] if j + k == self.c else self.plan[0, j:j + k]

    def plan_chunk(self) -> None:
        """The decoder's step at a boundary from the state saved at the last one, on the chunk just measured."""
        gen = self.gen
        self.final = False
        source = gen._next_state
        if source is self.ping[1]:
            run, current, following = self.decode1[1], self.ping[1], self.ping[0]
        else:
            run, current, following = self.decode1[0], self.ping[0], self.ping[1]
            if source is not current:  # a state the core made (the first chunk, a latent swap): copied in once
                np.copyto(current[0], source[0])
                np.copyto(current[1], source[1])
        window = self.history_slot(len(gen._history))
        np.copyto(window, gen._measured)  # the chunk's window as the core keeps it (float64)
        if not self.active:  # the chunk was the core's: its measured rows were not written here
            np.copyto(self.row_block_m, gen._measured[0])
        run()  # the decoder reads history_m[C:], the chunk just measured
        refuse_nan(run.where, self.accel1_finite)
        np.copyto(self.plan, self.accel1)
        gen._state, gen._next_state = current, following
        np.copyto(self.h1, current[0])
        np.copyto(self.c1, current[1])
        np.copyto(self.h2, current[0])  # (L, 1, H) into both rows of (L, 2, H)
        np.copyto(self.c2, current[1])
        np.copyto(self.window_m[0], self.row_block_m)  # the chunk just measured is the next window
        np.copyto(self.window_p[0], self.row_block_m)
        gen._window = window
        gen._history.append(window)
        gen._plan, gen._pred = self.plan, self.pred
        self.begin_prediction(gen._latest)

    def between(self, j: int, heads: list[np.ndarray]) -> None:
        """Position j (1 ≤ j < C) of a chunk the decoder planned whole: the plan's rows j.., corrected by the
        decoder's response to the measured window against the predicted one (both in one run at B = 2)."""
        k = self.c - j
        self.correct(j, k, heads[k])
        self.emit_checked(heads, k)

    def stopping(self, k: int, heads: list[np.ndarray]) -> None:
        """Past the motion's end: the stop's k outputs from the latest measured state."""
        head = heads[k]
        if self.stop is None:
            head.fill(0.0)
        else:
            self.stop.plan(self.gen._latest, k, head)
        self.emit_checked(heads, k)

    def before_core(self) -> None:
        """Before ``StepperCore`` runs a call: the chunk's predicted states complete, as the core reads them."""
        if self.active:
            self.predict(self.c)

    def after_core(self) -> None:
        """After ``StepperCore`` ran a call (or a latent swap): take over the chunk under way, so that its next calls
        run here (its plan, predicted states, window and state copied in where the core made them)."""
        gen, c = self.gen, self.c
        self.active = self.final = False
        self.prepared = -1
        if gen._plan is None or gen._pred is None or gen._window is None:
            return
        tau = gen._t - gen._origin
        if gen._plan is not self.plan:  # a chunk the core planned (the first, after a restart): copied in once
            np.copyto(self.plan, gen._plan)
            np.copyto(self.pred, gen._pred)
            np.copyto(self.window_m[0], gen._window[0])
            np.copyto(self.window_p[0], gen._window[0])
            np.copyto(self.h1, gen._state[0])
            np.copyto(self.c1, gen._state[1])
            np.copyto(self.h2, gen._state[0])
            np.copyto(self.c2, gen._state[1])
            for i in range(c):
                np.copyto(self.row_p[i], self.pred_row[i])
            gen._plan, gen._pred = self.plan, self.pred
        np.copyto(self.row_block_m, gen._measured[0])
        self.predicted = c
        if gen._length - 1 - (tau - tau % c) < c:  # the chunk in which the motion ends
            self.final = True
        else:
            self.active = True


__all__ = ["Bound", "F32", "F64", "FastPath", "Finite", "StopPlan", "StopViews", "first_line", "refuse_nan"]
