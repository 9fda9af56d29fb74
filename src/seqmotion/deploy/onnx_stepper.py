"""Run an exported model with onnxruntime and NumPy only: the same stepper as ``model.generator``.

``seqmotion export-onnx MODEL OUT/`` writes the graphs, ``contract.json`` and this file (with ``hot_path.py``,
``bundle.py``, ``stepper.py`` and ``numpy_physics.py``) into OUT/. Loading checks the bundle first (``bundle.py``):
the contract's seal and schema, each graph's SHA-256, then what a re-sealed bundle could hide — each graph's ops and
constant shapes, and its inputs and outputs against the contract. The sessions run in a capped arena, and an
output of the wrong shape or with NaN or inf is refused, in every method. On a robot computer that has only NumPy
and onnxruntime::

    import sys; sys.path.insert(0, "OUT")
    from onnx_stepper import OnnxModel, OnnxStepper
    gen = OnnxStepper("OUT", motion)                 # or OnnxStepper("OUT", latent=z, x0=x0, length=K)
    u = gen.step()                                   # u[0..C-1]
    u = gen.step(measured)                           # 1..len(u) measured states → the next outputs

The task's dynamics run as the bundle's ``dynamics.onnx`` graph (traced from the PyTorch code the
model trained with), at the physics the contract records (``contract["dynamics"]["physics"]``) or
at other values of the fields that graph reads: ``OnnxStepper("OUT", motion, physics={"mu": 0.8})``, within the
ranges the contract records for them (``physics_ranges``: ``bundle.check_physics``, the same check inside seqmotion).
Dynamics the contract names a closed form of (``"closed_form": "double_integrator"``: the pancake's,
the tray's) are computed in NumPy instead (``numpy_physics.py``), the same numbers without a session run.
For a task whose outputs are not accelerations (joint torques), the stop's planned accelerations become
outputs through the bundle's ``outputs_for.onnx`` graph (``contract["stop"]["outputs"] == "outputs_for"``).

Inside seqmotion the same classes are ``sm.deploy.OnnxModel`` / ``sm.deploy.OnnxStepper``. The
semantics of ``step``, ``set_latent``, ``reset`` and the end of the motion are the module
docstring of ``stepper.py`` (:mod:`seqmotion.core.stepper`), shared by both backends.

**In a control loop** a call of one measured state runs on buffers the stepper made once (``hot_path.py``,
:mod:`seqmotion.deploy.hot_path`, shipped beside this file): the sessions bound to them (onnxruntime's I/O binding,
one thread), the decoder's windows slices of a history of states, the plan's states predicted one per call (closed
form, or the bundle's ``dynamics_sample.onnx``: a chunk boundary costs one decoder run, like any call), the stop on
buffers too. ``gen.step_into(measured, out)`` writes into the caller's array and makes no NumPy array and no Python
container; its outputs are the shared code's, bit for bit::

    out = np.zeros((gen.chunk, gen.accel_dim))
    n = gen.step_into(None, out)                     # out[:n]: the first chunk
    n = gen.step_into(measured, out)                 # measured: float64 (1, S), one state per call
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

try:  # inside the seqmotion package
    from ..core.stepper import StepperCore, check_vectors
    from .bundle import (
        MAX_RUN_BYTES,
        check_interface,
        check_physics,
        graph_interface,
        locate,
        read_contract,
        read_graphs,
    )
    from .hot_path import F64, FastPath, first_line
    from .numpy_physics import integrate
except ImportError:  # the standalone copy that export-onnx writes beside the graphs
    from bundle import (  # type: ignore[no-redef]
        MAX_RUN_BYTES,
        check_interface,
        check_physics,
        graph_interface,
        locate,
        read_contract,
        read_graphs,
    )
    from hot_path import F64, FastPath, first_line  # type: ignore[no-redef]
    from numpy_physics import integrate  # type: ignore[no-redef]
    from stepper import StepperCore, check_vectors  # type: ignore[no-redef]

_ARENA: dict[str, bool] = {}
"""Whether this process registered the capped arena (:func:`_capped_arena`; onnxruntime keeps one per process)."""


def _capped_arena(ort: Any) -> bool:
    """Register, once per process, a CPU arena capped at ``MAX_RUN_BYTES`` that sessions opting in
    (``session.use_env_allocators``) share: a graph asking for more than the cap fails in onnxruntime, before the
    memory is taken, where no static scan could see the size (a broadcast of two constants, a shape computed in the
    graph). False where this onnxruntime has no shared allocators (the scan of ``bundle.py`` still bounds the rest)."""
    if "registered" not in _ARENA:
        try:
            info = ort.OrtMemoryInfo("Cpu", ort.OrtAllocatorType.ORT_ARENA_ALLOCATOR, 0, ort.OrtMemType.DEFAULT)
            # extend strategy 1 (kSameAsRequested): the arena grows by what is asked, not to the next power of two,
            # so the cap counts what the graphs hold
            ort.create_and_register_allocator(info, ort.OrtArenaCfg(MAX_RUN_BYTES, 1, -1, -1))
            _ARENA["registered"] = True
        except Exception:  # any failure (an older onnxruntime, its own error types): run uncapped
            _ARENA["registered"] = False
    return _ARENA["registered"]


class OnnxModel:
    """An exported model: encoder, decoder step, dynamics and constraint in onnxruntime sessions.

    Args:
        directory: the folder ``export-onnx`` wrote (its contract and graphs are verified: see ``bundle.py``).
        int8: use the int8 decoder step (exported with ``--int8``).
        threads: onnxruntime intra-op threads per session (1: lowest latency for small models).

    Attributes:
        physics_inputs: the physics fields the dynamics graph reads, which ``physics=`` may override.
        physics_defaults: every physics field's value in the contract (what the graph runs at by default).
        sample_session: the session of ``dynamics_sample.onnx`` (one sample of the dynamics), None where the bundle
            has none (a closed form, or an export from before it).

    Raises:
        ValueError: no bundle there, or one whose contract is unsealed, edited, of another format or invalid,
            whose graphs are missing, do not match their hashes, are larger than any export, hold what the exporter
            never writes (``bundle.check_graph``), do not load in onnxruntime, or take or give other tensors than
            the contract says (the message names the field, or the file and the tensor).
    """

    def __init__(self, directory: str | Path, *, int8: bool = False, threads: int = 1) -> None:
        try:
            import onnxruntime as ort
        except ImportError:
            raise ValueError("running exported models needs onnxruntime: pip install 'seqmotion[deploy]'") from None
        # the contract is sealed and checked against its schema, and each graph against its hash, before
        # anything is loaded; onnxruntime then gets the very bytes that were checked (bundle.py)
        self.directory = locate(directory)
        self.contract: dict[str, Any] = read_contract(self.directory)
        graphs = read_graphs(self.directory, self.contract)
        files = self.contract["files"]
        options = ort.SessionOptions()
        options.intra_op_num_threads = options.inter_op_num_threads = int(threads)
        options.log_severity_level = 4  # an error reaches the caller as a ValueError naming the file: no log too
        if _capped_arena(ort):
            options.add_session_config_entry("session.use_env_allocators", "1")

        def session(key: str) -> Any:
            where = self.where(key)
            try:
                # no constant folding: onnxruntime folds constants while it loads a graph, up to 1 GB each and
                # outside the arena's cap; the exporter's graphs are folded already (torch.onnx's folding)
                made = ort.InferenceSession(graphs[key], options, providers=["CPUExecutionProvider"],
                                            disabled_optimizers=["ConstantFolding"])
            except Exception as exc:  # onnxruntime's own (InvalidProtobuf, InvalidGraph, Fail, ...)
                raise ValueError(f"{where}: onnxruntime cannot load it: {first_line(exc)}") from None
            check_interface(where, graph_interface(self.contract, key),
                            [(i.name, i.shape, i.type) for i in made.get_inputs()],
                            [(o.name, o.shape, o.type) for o in made.get_outputs()])
            return made

        if int8 and files.get("decoder_step_int8") is None:
            raise ValueError(f"{self.directory} has no int8 decoder_step graph (export with --int8)")
        self._decoder_key = "decoder_step_int8" if int8 else "decoder_step"
        self.encoder = session("encoder")
        self.decoder = session(self._decoder_key)
        self.dynamics_session = session("dynamics")
        self.violation_session = session("violation") if files.get("violation") else None
        self.outputs_for_session = session("outputs_for") if files.get("outputs_for") else None
        # one sample of the dynamics (bundles of dynamics without a closed form): the stepper predicts the plan's
        # states one per call with it instead of the whole chunk at its boundary
        self.sample_session = session("dynamics_sample") if files.get("dynamics_sample") else None
        self._outputs_for_inputs = [i.name for i in self.outputs_for_session.get_inputs()] \
            if self.outputs_for_session else []
        # a constraint that reads only the accelerations (tray) has no states input in its graph
        self._violation_inputs = [i.name for i in self.violation_session.get_inputs()] if self.violation_session else []
        c = self.contract
        self.chunk, self.layers, self.hidden = int(c["chunk"]), int(c["layers"]), int(c["hidden"])
        self.input_dim = len(c["input_layout"]["names"])
        self.state_dim = len(c["state_layout"]["names"])
        self.accel_dim = len(c["accel_layout"]["names"])
        self.dt = float(c["dt"])
        self.closed_form: str | None = c["dynamics"]["closed_form"]
        physics = c["dynamics"]["physics"]
        self.physics_inputs: tuple[str, ...] = tuple(physics["inputs"])
        self.physics_defaults: dict[str, float] = {k: float(v) for k, v in physics["values"].items()}
        feeds = ["x", "accel", *(["physics"] if self.physics_inputs else [])]
        names = [i.name for i in self.dynamics_session.get_inputs()]
        if names != feeds:  # a sealed bundle whose graph does not take what its contract says it reads
            raise ValueError(f"{self.directory}: the dynamics graph takes {names}, not {feeds} as its contract says "
                             f"(dynamics reading {list(self.physics_inputs) or 'no physics'}); re-export the model")
        self._default_vector = self.physics_vector(None)
        self._pads: dict[int, np.ndarray] = {}

    def where(self, key: str) -> str:
        """The graph ``key``'s file and key, as messages name it."""
        return f"{self.directory / self.contract['files'][key]} ({key})"

    def _run(self, key: str, session: Any, feeds: dict[str, np.ndarray], shapes: dict[str, tuple[int, ...]]
             ) -> list[np.ndarray]:
        """``session.run`` of the graph ``key``, its outputs checked: each of ``shapes`` (in the graph's order, the
        contract's), finite. A bundle anyone can re-seal may hold a graph that computes NaN; never hand it on."""
        try:
            outs = session.run(None, feeds)
        except Exception as exc:  # onnxruntime's own: a graph over the arena's cap, a shape it cannot run
            capped = f" (the sessions hold at most {MAX_RUN_BYTES} bytes: a smaller batch may run)" \
                if "Available memory" in str(exc) else ""
            raise ValueError(f"{self.where(key)}: onnxruntime failed running it{capped}: {first_line(exc)}") from None
        for (name, shape), out in zip(shapes.items(), outs, strict=True):
            if out.shape != shape:
                raise ValueError(f"{self.where(key)}: its output {name!r} has shape {out.shape}, not {shape}: "
                                 "refused (the graph is not this bundle's)")
            if not np.isfinite(out).all():
                raise ValueError(f"{self.where(key)}: its output {name!r} holds NaN or inf: refused (inputs far "
                                 "outside the model's range, or a graph that is not this model's)")
        return outs

    def __repr__(self) -> str:
        c = self.contract
        return f"OnnxModel({str(self.directory)!r}, task={c['task']!r}, {c['layers']}x{c['hidden']}, C={c['chunk']})"

    # --- physics -------------------------------------------------------------------------------------

    def physics_vector(self, physics: Mapping[str, float] | None) -> np.ndarray:
        """The dynamics graph's ``physics`` input ``(P,)`` float64: the contract's values with ``physics``
        (field name → value) put in; None: the contract's values.

        Raises:
            ValueError: not a dict, a name the graph does not read (the message lists those it reads), a
                value that is not a finite real number, or values the task's physics class refuses (e.g. sliding
                ``mu_dyn > mu``): ``bundle.check_physics``, the contract's ranges, here and in the standalone copy.
        """
        values = {name: self.physics_defaults[name] for name in self.physics_inputs}
        if physics is not None:
            if not isinstance(physics, Mapping):
                raise ValueError(f"physics must be a dict of field name → value (e.g. {{'mu': 0.8}}), got "
                                 f"{type(physics).__name__}")
            unknown = sorted(set(physics) - set(self.physics_inputs))
            if unknown:
                task = self.contract["task"]
                if not self.physics_inputs:
                    raise ValueError(f"the {task!r} model's exported dynamics take no physics (got {unknown}): "
                                     "they read no physics parameter")
                raise ValueError(f"the {task!r} model's exported dynamics take no physics {unknown}; they take "
                                 f"{list(self.physics_inputs)}")
            for name, value in physics.items():
                if isinstance(value, (bool, np.bool_)) or np.iscomplexobj(value):
                    raise ValueError(f"physics {name} must be a real number, got {value!r}")
                try:
                    number = float(value)
                except (TypeError, ValueError):
                    raise ValueError(f"physics {name} must be a number, got {value!r}") from None
                if not math.isfinite(number):
                    raise ValueError(f"physics {name} must be finite, got {number}")
                values[name] = number
            # a value equal to the contract's is no override: the bundle runs at its own physics whatever its ranges
            check_physics(self.contract, {name: values[name] for name in physics
                                          if values[name] != self.physics_defaults[name]},
                          str(self.directory / "contract.json"))
        return np.array([values[name] for name in self.physics_inputs], dtype=np.float64)

    # --- the graphs ----------------------------------------------------------------------------------

    def encode(self, inputs: object) -> tuple[np.ndarray, np.ndarray, bool]:
        """Motions ``(K, input_dim)``/``(B, K, input_dim)`` (any K ≥ 2) → latents ``(B, L·H)`` float32,
        start states ``(B, S)`` float64 and whether a single motion was given."""
        layout = self.contract["input_layout"]
        try:
            arr = np.asarray(inputs, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise ValueError(f"inputs must be a numeric array, got {type(inputs).__name__}: {exc}") from None
        if arr.ndim not in (2, 3) or arr.shape[-1] != self.input_dim:
            raise ValueError(f"inputs must have shape (K, {self.input_dim}) or (B, K, {self.input_dim}) of "
                             f"{layout['kind']} ({', '.join(layout['names'])}), got shape {arr.shape}")
        if arr.shape[-2] < 2:
            raise ValueError(f"inputs need at least K = 2 samples, got K = {arr.shape[-2]}")
        if not np.all(np.isfinite(arr)):
            raise ValueError("inputs contain NaN or inf")
        single = arr.ndim == 2
        x = arr[None] if single else arr
        b, k, _ = x.shape
        n = math.ceil(k / self.chunk)
        if n * self.chunk != k:
            x = np.concatenate([x, np.repeat(x[:, -1:], n * self.chunk - k, axis=1)], axis=1)
        z, x0 = self._run("encoder", self.encoder, {"chunks": np.ascontiguousarray(x.reshape(b, n, -1))},
                          {"z": (b, self.layers * self.hidden), "x0": (b, self.state_dim)})
        return z, x0.astype(np.float64), single

    def initial_state(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(h, c)`` ``(L, B, H)`` from latents ``(B, L·H)``: c = z (layer-major), h = 0."""
        b = z.shape[0]
        c = np.asarray(z, dtype=np.float32).reshape(b, self.layers, self.hidden).transpose(1, 0, 2)
        c = np.ascontiguousarray(c)
        return np.zeros_like(c), c

    def decode_step(self, state: tuple[np.ndarray, np.ndarray], window: np.ndarray) -> tuple[tuple, np.ndarray]:
        """One decoder step: ``window`` ``(B, C, S)`` → new ``(h, c)`` and the means ``(B, C, d)`` float64."""
        b = window.shape[0]
        hidden = (self.layers, b, self.hidden)
        h, c, mean = self._run(self._decoder_key, self.decoder,
                               {"h": state[0], "c": state[1], "window": np.ascontiguousarray(window, dtype=np.float32)},
                               {"h_out": hidden, "c_out": hidden, "accel": (b, self.chunk, self.accel_dim)})
        return (h, c), mean.astype(np.float64)

    def predict(self, x: np.ndarray, accel: np.ndarray, physics: np.ndarray | None = None) -> np.ndarray:
        """The states ``(B, n, S)`` float64 that outputs ``accel`` ``(B, n, d)`` produce from states ``x`` ``(B, S)``
        through the task's dynamics, at ``physics`` (the graph's input vector, :meth:`physics_vector`; None: the
        contract's): in closed form where the contract names one, else :meth:`predict_graph`."""
        if self.closed_form == "double_integrator":
            return integrate(np.asarray(x, dtype=np.float64), np.asarray(accel, dtype=np.float64), self.dt)
        return self.predict_graph(x, accel, physics)

    def predict_graph(self, x: np.ndarray, accel: np.ndarray, physics: np.ndarray | None = None) -> np.ndarray:
        """:meth:`predict` through the dynamics graph. It runs C outputs at a time: fewer are padded with zeros
        (the dynamics are causal, so the first n states do not depend on the padding), more run chunk after chunk."""
        vector = self._default_vector if physics is None else physics
        x, accel = np.asarray(x, dtype=np.float64), np.asarray(accel, dtype=np.float64)
        b, n = accel.shape[:2]
        c = self.chunk
        out = [np.empty((b, 0, self.state_dim))]
        for start in range(0, n, c):
            part = accel[:, start:start + c]
            m = part.shape[1]
            if m < c:
                pad = self._pads.get(b)
                if pad is None:
                    pad = self._pads[b] = np.zeros((b, c, self.accel_dim))
                pad[:, :m] = part
                pad[:, m:] = 0.0
                part = pad
            feeds = {"x": np.ascontiguousarray(x), "accel": np.ascontiguousarray(part, dtype=np.float64)}
            if self.physics_inputs:
                feeds["physics"] = vector
            (states,) = self._run("dynamics", self.dynamics_session, feeds, {"states": (b, c, self.state_dim)})
            states = states[:, :m].astype(np.float64, copy=False)
            out.append(states)
            x = states[:, -1]
        return out[-1] if len(out) <= 2 else np.concatenate(out, axis=1)

    def outputs_for(self, x: np.ndarray, accel: np.ndarray, physics: np.ndarray | None = None) -> np.ndarray:
        """The outputs ``(B, n, d)`` float64 that give the velocity columns the accelerations ``accel`` ``(B, n, d)``
        along the path from states ``x`` ``(B, S)`` (the bundle's ``outputs_for`` graph, at ``physics`` like
        :meth:`predict`). C at a time like :meth:`predict_graph`; past C the next chunk starts from the state the
        dynamics reach with the outputs so far.

        Raises:
            ValueError: the bundle has no ``outputs_for`` graph (its outputs are the accelerations themselves).
        """
        if self.outputs_for_session is None:
            raise ValueError(f"{self.directory} has no outputs_for graph: the {self.contract['task']!r} task's "
                             "outputs are the accelerations themselves")
        vector = self._default_vector if physics is None else physics
        x, accel = np.asarray(x, dtype=np.float64), np.asarray(accel, dtype=np.float64)
        b, n = accel.shape[:2]
        c = self.chunk
        out = []
        for start in range(0, n, c):
            part = accel[:, start:start + c]
            m = part.shape[1]
            if m < c:  # causal: the first m outputs do not depend on the padding
                part = np.concatenate([part, np.zeros((b, c - m, self.accel_dim))], axis=1)
            feeds = {"x": np.ascontiguousarray(x), "accel": np.ascontiguousarray(part), "physics": vector}
            (outputs,) = self._run("outputs_for", self.outputs_for_session,
                                   {k: feeds[k] for k in self._outputs_for_inputs}, {"outputs": (b, c, self.accel_dim)})
            out.append(outputs[:, :m].astype(np.float64, copy=False))
            if start + c < n:
                x = self.predict(x, out[-1], physics)[:, -1]
        return out[0] if len(out) == 1 else np.concatenate(out, axis=1)

    def violation(self, states: np.ndarray, accel: np.ndarray) -> np.ndarray | None:
        """The violation ``(B, N)`` of ``states`` ``(B, N+1, S)``, ``accel`` ``(B, N, d)`` (None: no constraint)."""
        if self.violation_session is None:
            return None
        given = {"states": states, "accel": accel}
        feeds = {name: np.ascontiguousarray(given[name], dtype=np.float32) for name in self._violation_inputs}
        (out,) = self._run("violation", self.violation_session, feeds, {"violation": np.shape(accel)[:2]})
        return out.astype(np.float64)

    # --- whole motions ---------------------------------------------------------------------------------

    def generate(self, inputs: object, physics: Mapping[str, float] | None = None) -> dict[str, np.ndarray | None]:
        """Encode and decode in closed loop through the dynamics graph, like PyTorch ``generate``, at the
        contract's physics with ``physics`` (field name → value) put in.

        Returns a dict: ``states`` ``(K, S)``, ``accel`` ``(K-1, d)``, ``violation`` ``(K-1,)`` or None,
        ``latent`` (a leading B axis for a batch).
        """
        vector = self.physics_vector(physics)
        z, x0, single = self.encode(inputs)
        k = np.shape(inputs)[-2]
        out = self._rollout(z, x0, k, vector)
        return {key: v if v is None else (v[0] if single else v) for key, v in out.items()}

    def decode(self, latent: object, x0: object, length: int, physics: Mapping[str, float] | None = None
               ) -> dict[str, np.ndarray | None]:
        """Decode latents ``(L·H,)``/``(B, L·H)`` from start states ``(S,)``/``(B, S)`` into ``length`` samples
        (at the contract's physics with ``physics`` put in)."""
        vector = self.physics_vector(physics)
        z, single = check_vectors(latent, int(self.contract["latent_dim"]), "latent", "L·H numbers")
        x, _ = check_vectors(x0, self.state_dim, "x0", self.contract["state_layout"]["kind"], z.shape[0])
        if int(length) < 2:
            raise ValueError(f"length must be at least 2, got {length}")
        out = self._rollout(z.astype(np.float32), x, int(length), vector)
        return {key: v if v is None else (v[0] if single else v) for key, v in out.items()}

    def _rollout(self, z: np.ndarray, x0: np.ndarray, length: int, physics: np.ndarray) -> dict[str, Any]:
        steps = max(1, math.ceil((length - 1) / self.chunk))
        state = self.initial_state(z)
        window = np.repeat(x0[:, None], self.chunk, axis=1)
        x, states, accels = x0, [x0[:, None]], []
        for _ in range(steps):
            state, mean = self.decode_step(state, window)
            window = self.predict(x, mean, physics)
            x = window[:, -1]
            states.append(window)
            accels.append(mean)
        all_states = np.concatenate(states, axis=1)[:, :length]
        accel = np.concatenate(accels, axis=1)[:, : length - 1]
        return {"states": all_states, "accel": accel, "violation": self.violation(all_states, accel), "latent": z}

    def generator(self, inputs: object | None = None, **kwargs: Any) -> OnnxStepper:
        """An :class:`OnnxStepper` on this model (arguments as ``OnnxStepper``'s after ``model``)."""
        return OnnxStepper(self, inputs, **kwargs)


class OnnxStepper(StepperCore):
    """The online motion generator on onnxruntime: ``step``, ``set_latent``, ``reset``, ``contract``
    exactly as PyTorch ``model.generator(...)`` (semantics: ``stepper.py``'s docstring).

    Args:
        model: an :class:`OnnxModel` or the folder ``export-onnx`` wrote.
        inputs: a motion to encode (x0 = the task's start state for it, K = its length); or
        latent, x0: a latent ``(L·H,)``/``(B, L·H)`` and start state(s) of the state layout,
        length: K (default: the input's length, else the longest motion the model trained on).
        replan: correct the plan between chunk boundaries from the latest measured states.
        int8: with a folder, use its int8 decoder step.
        physics: values of the physics fields the dynamics graph reads (``OnnxModel.physics_inputs``; sliding:
            ``{"mu": 0.8, "mu_dyn": 0.4}``); the others, and any not given, are the contract's.

    **The control loop's calls** (one motion, one measured state per call, float64 ``(1, S)``) run on buffers
    made when the stepper is: the sessions' inputs and outputs bound to them (onnxruntime's I/O binding, one
    thread), the windows slices of a history of states, the plan's states predicted one per call (so a chunk
    boundary costs one decoder run, like a call between boundaries), the stop planned on buffers too. Such a call
    makes no array; :meth:`step_into` writes its outputs into the caller's array, so it makes none at all.
    Other calls (the first, several states at once, a restart, the chunk where the motion ends, a batch) run
    the shared ``StepperCore`` code on the same state. Both give the same outputs.
    """

    def __init__(self, model: OnnxModel | str | Path, inputs: object | None = None, *, latent: object | None = None,
                 x0: object | None = None, length: int | None = None, replan: bool = True, int8: bool = False,
                 physics: Mapping[str, float] | None = None) -> None:
        self.onnx = model if isinstance(model, OnnxModel) else OnnxModel(model, int8=int8)
        contract = self.onnx.contract
        self._physics = self.onnx.physics_vector(physics)
        if inputs is not None:
            if latent is not None or x0 is not None:
                raise ValueError("give either the input motion, or latent and x0 — not both")
            z, start, single = self.onnx.encode(inputs)
            length = np.shape(inputs)[-2] if length is None else length
        elif latent is not None and x0 is not None:
            z, single = check_vectors(latent, int(contract["latent_dim"]), "latent", "L·H numbers")
            start = x0
        else:
            raise ValueError("give either the input motion, or both latent and x0")
        self._fast: FastPath | None = None
        self._out_checked: np.ndarray | None = None
        super().__init__(contract, z, start, single, length, replan)
        if self._single:
            self._fast = FastPath(self)

    # --- the control loop's calls -------------------------------------------------------------------------

    def step(self, measured: object | None = None) -> np.ndarray:
        """The next outputs (``StepperCore.step``; the module docstring of ``stepper.py``): ``(m, d)``, or
        ``(B, m, d)`` for a batch, 1 ≤ m ≤ C. A new array each call (:meth:`step_into` writes into yours)."""
        fast = self._fast
        if fast is not None:
            n = self._fast_call(measured, fast.out)
            if n >= 0:
                return fast.out[:n].copy()
        return self._core_step(measured)

    def step_into(self, measured: object | None, out: np.ndarray) -> int:
        """:meth:`step` writing the outputs into ``out`` (rows ``0..m-1``) and returning m: for a control loop
        that makes no Python object per call. ``out``: float64, C-contiguous, ``(C, d)`` (a batch: ``(B, C, d)``).

        Raises:
            ValueError: ``out`` of another type, dtype or shape, or read-only; what :meth:`step` raises.
        """
        if out is not self._out_checked:
            c, d = self.chunk, self.accel_dim
            want = (c, d) if self._single else (self._batch, c, d)
            if not (isinstance(out, np.ndarray) and out.dtype == F64 and out.shape == want
                    and out.flags.c_contiguous and out.flags.writeable):
                shown = f"{type(out).__name__} {getattr(out, 'dtype', '')} {getattr(out, 'shape', '')}".strip()
                raise ValueError(f"out must be a writable C-contiguous float64 array of shape {want} (C outputs of "
                                 f"the accel layout), got {shown}")
            self._out_checked = out
        fast = self._fast
        if fast is not None:
            n = self._fast_call(measured, out)
            if n >= 0:
                return n
        u = self._core_step(measured)
        n = u.shape[-2]
        out[..., :n, :] = u
        return n

    def prepare(self) -> None:
        """Between calls (after the control loop sent its command): the next call's predicted window and its
        decoder run, so that call holds one decoder run (``stepper.py``, "prepare()"); same outputs either way."""
        if self._fast is not None and self._started:
            self._fast.prepare()

    def _fast_call(self, measured: object, out: np.ndarray) -> int:
        """One call on the buffers (class docstring) writing into ``out``; -1 where the call is the core's (nothing
        changed then)."""
        fast = self._fast
        if (not self._started or type(measured) is not np.ndarray or measured.dtype is not F64
                or measured.ndim != 2 or len(measured) != 1 or measured.size != fast.s):
            return -1
        c = fast.c
        tau = self._t - self._origin + 1
        j = tau % c
        last = self._length - 1
        motion = min(c, last - (tau - j)) - j  # how many of this call's outputs are the motion's (> 0)
        if j == 0 and self._pending is not None:
            return -1  # a restart: the core's
        if j != 0 and motion > 0 and not (fast.active or fast.final):
            return -1  # outputs of the motion in a chunk the core planned
        np.abs(measured, out=fast.check)
        np.less_equal(fast.check, fast.max_abs, out=fast.check_ok)  # NaN and inf fail it too
        if np.count_nonzero(fast.check_ok) != fast.s:
            return -1  # the core names the problem
        position = (j or c) - 1
        np.copyto(fast.measured_rows()[position], measured)
        np.copyto(fast.row_m[position], measured)
        np.copyto(self._latest, measured)
        self._t += 1
        heads = fast.heads_of(out)
        n = c - j
        if j == 0:
            fast.active = False
            if motion >= c:
                fast.boundary(heads)
            elif motion > 0:
                fast.final_boundary(motion, heads)
            else:  # past the end: no plan, the stop
                self._plan = self._pred = self._window = None
                fast.final = False
                fast.stopping(c, heads)
        elif motion <= 0:
            fast.stopping(n, heads)
        elif fast.active:
            fast.between(j, heads)
        else:
            fast.final_between(j, motion, heads)
        self._available = n
        return n

    def _core_step(self, measured: object) -> np.ndarray:
        fast = self._fast
        if fast is not None:
            fast.before_core()
        out = super().step(measured)
        if fast is not None:
            fast.after_core()
        return out

    def set_latent(self, latent: object, *, restart: bool = False, length: int | None = None) -> None:
        """``StepperCore.set_latent`` (a new length may end the motion inside the chunk under way)."""
        fast = self._fast
        if fast is not None:
            fast.before_core()
        super().set_latent(latent, restart=restart, length=length)
        if fast is not None:
            fast.after_core()

    def reset(self, x0: object | None = None) -> None:
        """``StepperCore.reset``."""
        super().reset(x0)
        if getattr(self, "_fast", None) is not None:
            self._fast.active = self._fast.final = False

    @property
    def physics(self) -> dict[str, float]:
        """The physics the stepper runs at: every field's value (the contract's, with the overrides given)."""
        return {**self.onnx.physics_defaults, **dict(zip(self.onnx.physics_inputs, self._physics.tolist(),
                                                         strict=True))}

    def contract(self) -> dict[str, Any]:
        """The stepper's contract (``stepper.py``) with this generator's length and mode, and the physics it
        runs at in ``dynamics.physics.values``."""
        out = super().contract()
        dynamics = out["dynamics"]
        out["dynamics"] = {**dynamics, "physics": {**dynamics["physics"], "values": self.physics}}
        return out

    def _initial_state(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self.onnx.initial_state(z)

    def _decode(self, state: Any, windows: np.ndarray, repeat: int = 1) -> tuple[Any, np.ndarray]:
        if repeat > 1:
            state = (np.concatenate((state[0],) * repeat, axis=1), np.concatenate((state[1],) * repeat, axis=1))
        return self.onnx.decode_step(state, windows)

    def _predict(self, x: np.ndarray, accel: np.ndarray) -> np.ndarray:
        return self.onnx.predict(x, accel, self._physics)

    def _violation(self, states: np.ndarray, accel: np.ndarray) -> np.ndarray:
        return self.onnx.violation(states, accel)

    def _outputs_for(self, x: np.ndarray, accel: np.ndarray) -> np.ndarray:
        return self.onnx.outputs_for(x, accel, self._physics)

    def _stop(self, x: np.ndarray, n: int) -> np.ndarray:
        fast = self._fast
        if fast is None or fast.stop is None or x.shape[0] != 1:
            return super()._stop(x, n)
        out = np.empty((1, n, self.accel_dim))
        fast.stop.plan(x, n, out[0])
        return out


__all__ = ["OnnxModel", "OnnxStepper"]
