"""A plug-in task with its own nonlinear physics: ``examples/cup_arm`` (a two-link arm carrying an open cup).

The example package is installed the way a user would (``pip install`` into a folder on ``sys.path``),
its physics is checked against what a two-link arm must do (held by its gravity torques it stays
put, left alone it falls with its energy kept, its mass matrix is symmetric positive definite, the
cup upright at rest spills nothing and a fast swing spills), then it is trained with ``seqmotion
train cup_arm`` and used from Python (generate, the online generator fed measured states, latent
optimisation on a residual objective, another payload) and from the command line, and exported to ONNX.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import install_example
from conftest import seqmotion_cli as seqmotion

import seqmotion as sm
from seqmotion import tasks

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "cup_arm"


@pytest.fixture(scope="module")
def installed(tmp_path_factory):
    """The example package installed into a fresh folder and put on the path (in-process and for subprocesses)."""
    yield from install_example("cup_arm", tmp_path_factory)


@pytest.fixture(scope="module")
def arm(installed):
    import seqmotion_cup_arm.arm as module

    return module


@pytest.fixture(scope="module")
def run(installed, tmp_path_factory):
    _, env = installed
    out = tmp_path_factory.mktemp("cup_arm") / "run"
    done = seqmotion(env, "train", "cup_arm", "--config", "tiny", "--epochs", "8", "--batches-per-epoch", "3",
                     "--out", str(out), "--quiet", cwd=out.parent)
    assert done.returncode == 0, done.stderr
    return out


@pytest.fixture(scope="module")
def bundle(run, tmp_path_factory):
    pytest.importorskip("onnxruntime")
    from seqmotion.deploy import export_onnx

    out = tmp_path_factory.mktemp("cup_arm_onnx") / "onnx"
    export_onnx(sm.load(run), out)
    return out


def rest(q: list[list[float]]) -> torch.Tensor:
    """States ``(B, 4)`` at rest at joint angles ``q`` ``(B, 2)``."""
    q_t = torch.tensor(q, dtype=torch.float64)
    return torch.cat([q_t, torch.zeros_like(q_t)], -1)


def roll(dynamics, x0: torch.Tensor, tau: torch.Tensor) -> torch.Tensor:
    """States ``(B, N + 1, 4)`` that torques ``(B, N, 2)`` give from ``x0``."""
    _, out = dynamics.step(dynamics.start(x0), tau, None)
    return torch.cat([x0[:, None], out["states"]], 1)


def drive(gens: list, dynamics, x0: np.ndarray, until: int, sizes=(3, 7, 10, 1)) -> tuple[np.ndarray, list]:
    """Steppers fed the states the first one's torques give the arm (``sizes`` states a call, in turn) until
    t = ``until``: the states ``(until + 1, 4)`` and each stepper's torques ``(until, 2)``."""
    outputs = [[g.step()] for g in gens]
    states, x, call = [x0], torch.from_numpy(x0[None]), 0
    while gens[0].time < until:
        n = min(sizes[call % len(sizes)], len(outputs[0][-1]), until - gens[0].time)
        call += 1
        applied = torch.from_numpy(outputs[0][-1][None, :n])
        measured = dynamics.step(dynamics.start(x), applied, None)[1]["states"]
        x = measured[:, -1]
        states.extend(measured[0].numpy())
        for g, out in zip(gens, outputs, strict=True):
            out[-1] = out[-1][:n]  # what was applied
            out.append(g.step(measured[0].numpy()))
    return np.array(states), [np.concatenate(out[:-1]) for out in outputs]


# --- physics ---------------------------------------------------------------------------------------------


def test_held_by_its_gravity_torques_the_arm_stays_at_rest(arm):
    physics = arm.CupArmPhysics()
    x0 = rest([[0.6, -0.6], [1.2, 0.3], [-0.3, 1.0]])
    hold = arm.bias_torques(x0[:, :2], x0[:, 2:], physics)
    assert torch.all(hold[:, 0] > 0)  # gravity pulls the raised links down: the shoulder pushes up
    states = roll(arm.CupArmDynamics.at(physics), x0, hold[:, None].expand(-1, 1000, -1))
    assert (states - x0[:, None]).abs().max() < 1e-12
    # a payload 1 kg heavier needs more torque at both joints, the elbow's by m g l2 cos(q1 + q2)
    heavier = arm.bias_torques(x0[:, :2], x0[:, 2:], physics.replace(payload_mass=1.3)) - hold
    expected = arm.GRAVITY * arm.LINK_LENGTHS[1] * torch.cos(x0[:, 0] + x0[:, 1])
    torch.testing.assert_close(heavier[:, 1], expected)


def test_left_alone_it_falls_and_keeps_its_energy(arm):
    still = arm.CupArmPhysics(joint_damping=0.0)
    x0 = rest([[0.6, -0.6], [1.2, 0.3]])
    drifts = []
    for dt in (1e-3, 5e-4):  # 1 s each
        states = roll(arm.CupArmDynamics(still.payload_mass, 0.0, dt), x0,
                      torch.zeros(2, round(1 / dt), 2, dtype=torch.float64))
        assert torch.all(states[:, :, 0].min(1).values < x0[:, 0] - 0.5)  # it fell
        q, dq = states[..., :2], states[..., 2:]
        e = arm.energy(q, dq, still.payload_mass)
        kinetic = e - arm.energy(q, torch.zeros_like(dq), still.payload_mass)
        drifts.append((e - e[:, :1]).abs().max(1).values)
        assert torch.all(drifts[-1] < 0.1 * kinetic.max(1).values)  # a swing of ~10 J keeps it within 1 J
    # the drift is the step's first-order error (half the step, half the drift), not a missing force
    ratio = drifts[0] / drifts[1]
    assert torch.all((ratio > 1.7) & (ratio < 2.3)), ratio
    # damping takes energy out
    damped = roll(arm.CupArmDynamics.at(arm.CupArmPhysics(joint_damping=0.5)), x0,
                  torch.zeros(2, 1000, 2, dtype=torch.float64))
    assert torch.all(arm.energy(damped[:, -1, :2], damped[:, -1, 2:], 0.3) < e[:, 0] - 0.5)


def test_mass_matrix_and_inverse_dynamics(arm):
    physics = arm.CupArmPhysics(payload_mass=0.5)
    q = torch.from_numpy(np.random.default_rng(0).uniform(-3, 3, size=(200, 2)))
    m = arm.mass_matrix(q, physics.payload_mass)
    torch.testing.assert_close(m, m.transpose(-1, -2))
    assert torch.linalg.eigvalsh(m).min() > 0
    # the step applies q̈ = M⁻¹ (τ − C q̇ − g − b q̇): inverse dynamics of its velocity change gives τ back
    x0 = torch.cat([q[:8], torch.randn(8, 2, dtype=torch.float64)], -1)
    tau = 3 * torch.randn(8, 20, 2, dtype=torch.float64)
    states = roll(arm.CupArmDynamics.at(physics), x0, tau)
    ddq = (states[:, 1:, 2:] - states[:, :-1, 2:]) / 1e-3
    torch.testing.assert_close(arm.inverse_dynamics(states[:, :-1, :2], states[:, :-1, 2:], ddq, physics), tau)


def test_the_cup_spills_when_swung_not_when_still(arm):
    limit = np.radians(20)
    upright = rest([[0.6, -0.6]])[:, None].expand(-1, 5, -1)
    assert arm.spill_violation(upright, limit).abs().max() == 0
    tilted = rest([[0.6, -0.6 + 0.5]])[:, None].expand(-1, 5, -1)  # 0.5 rad tilt at rest: 0.5 − limit past it
    torch.testing.assert_close(arm.spill_violation(tilted, limit), torch.full((1, 4), 0.5 - limit, dtype=torch.float64))
    # the cup's acceleration from the arm's kinematics matches the second difference of its position
    t = torch.linspace(0, 0.3, 301, dtype=torch.float64)
    q = torch.stack([0.6 + 0.5 * torch.sin(6 * t), -0.6 - 0.3 * torch.sin(9 * t)], -1)
    dq = torch.stack([3 * torch.cos(6 * t), -2.7 * torch.cos(9 * t)], -1)
    ddq = torch.stack([-18 * torch.sin(6 * t), 24.3 * torch.sin(9 * t)], -1)
    p = arm.cup_position(q)
    accel = (p[2:] - 2 * p[1:-1] + p[:-2]) / 1e-6
    specific = torch.stack([accel[:, 0], accel[:, 1] + arm.GRAVITY], -1)
    axis = torch.stack([-torch.sin(q[1:-1].sum(-1)), torch.cos(q[1:-1].sum(-1))], -1)
    angle = torch.atan2(axis[:, 0] * specific[:, 1] - axis[:, 1] * specific[:, 0], (axis * specific).sum(-1))
    torch.testing.assert_close(arm.cup_tilt(q[1:-1], dq[1:-1], ddq[1:-1]), angle, atol=1e-4, rtol=0)
    # a fast swing of the shoulder (1 rad in 0.2 s from rest) spills
    dynamics = arm.CupArmDynamics()
    x0 = rest([[0.6, -0.6]])
    hold = arm.bias_torques(x0[:, :2], x0[:, 2:], arm.CupArmPhysics())
    swing = hold[:, None] + torch.tensor([8.0, 0.0], dtype=torch.float64).expand(1, 100, 2)
    assert arm.spill_violation(roll(dynamics, x0, swing), limit).max() > 0.2


def test_gradients_and_covariances_through_a_rollout(arm):
    dynamics = arm.CupArmDynamics()
    x0 = rest([[0.6, -0.6], [0.9, -1.0]])
    tau = (4 * torch.ones(2, 30, 2, dtype=torch.float64)).requires_grad_()
    cov = torch.diag_embed(torch.full((2, 30, 2), 0.04, dtype=torch.float64))
    carry, covs, states = dynamics.start(x0), [], []
    for k in range(3):  # three chunks of 10
        carry, out = dynamics.step(carry, tau[:, 10 * k:10 * (k + 1)], cov[:, 10 * k:10 * (k + 1)])
        covs.append(out["pos_cov"])
        states.append(out["states"])
    chunked, states = torch.cat(covs, 1), torch.cat([x0[:, None], *states], 1)
    (states[:, -1, :2].sum() + arm.spill_violation(states, 0.1).sum()).backward()
    assert torch.isfinite(tau.grad).all() and tau.grad.abs().sum() > 0
    # the chunk-by-chunk covariance is the whole motion's (what a generated result's uncertainty comes from)
    whole = tasks.get("cup_arm").position_cov(cov, states.detach(), tau.detach(), {}, dynamics)
    torch.testing.assert_close(chunked.detach(), whole)
    assert torch.all(torch.linalg.eigvalsh(whole[:, 1:]) > 0)
    torch.autograd.gradcheck(lambda t: dynamics.step(dynamics.start(x0), t, cov[:, :4])[1]["pos_cov"].sum(),
                             (tau.detach()[:, :4].clone().requires_grad_(),))


def test_registered_by_hand_without_the_entry_point(tmp_path):
    script = ("import seqmotion.tasks as t; from seqmotion_cup_arm.task import CupArmTask; "
              "task = t.register(CupArmTask()); assert t.get('cup_arm') is task; "
              "print(task.physics(task.options(None)))")
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(EXAMPLE / "src"), os.environ.get("PYTHONPATH", "")])}
    done = subprocess.run([sys.executable, "-c", script], env=env, cwd=tmp_path, capture_output=True, text=True)
    assert done.returncode == 0, done.stderr
    assert "CupArmPhysics(payload_mass=0.3, joint_damping=0.02)" in done.stdout


# --- a trained model --------------------------------------------------------------------------------------


def test_options_and_physics_are_typed_and_checked(installed):
    _, env = installed
    assert "cup_arm" in tasks.names()
    task = tasks.get("cup_arm")
    assert task.physics(task.options({"payload_mass": 0.8})).payload_mass == 0.8
    done = seqmotion(env, "train", "cup_arm", "--config", "tiny", "--set", "payload_mass=-1", cwd=Path.cwd())
    assert done.returncode == 2 and "payload_mass" in done.stderr, done.stderr
    for bad in ({"spill_limit_deg": 95}, {"rest_tilt": 0.5}, {"length": [300]}, {"mu": 0.5}):
        with pytest.raises(ValueError, match=next(iter(bad))):
            task.options(bad)
    inputs = task.example_inputs(3, seed=1)
    assert inputs.shape == (3, 400, 4) and np.allclose(inputs[:, [0, -1], 2:], 0)  # whole moves, rest to rest


def test_generate_and_the_online_generator_fed_its_own_states(run):
    model = sm.load(run)
    assert model.task_def.name == "cup_arm" and model.accel_layout.names == ("tau_1", "tau_2")
    sketch = model.task_def.sketch((0.75, -0.7), 80)
    motion = model.generate(sketch)
    assert motion.states.shape == (80, 4) and motion.accel.shape == (79, 2) and motion.violation.shape == (79,)
    assert motion.physics == model.physics and np.all(motion.violation >= 0)
    assert set(motion.errors) == {"shape_rmse_rad", "end_error_rad", "end_speed_rad_s", "max_violation"}
    assert motion.uncertainty.shape == (80, 2) and np.all(np.diff(motion.uncertainty[:, 0]) >= 0)
    # the torques drive the task's own physics
    replay = model.integrate_torch(torch.from_numpy(sketch[:1, :]), torch.from_numpy(motion.accel[None]))[0]
    np.testing.assert_allclose(motion.states, replay.numpy(), atol=1e-9)
    # the online stepper fed the states its torques produce reproduces generate
    gen, dynamics = model.generator(sketch), model.dynamics()
    c = gen.chunk
    u, x = [gen.step()], torch.from_numpy(sketch[:1])
    for _ in range(3):
        states = dynamics.step(dynamics.start(x), torch.from_numpy(u[-1][None]), None)[1]["states"]
        x = states[:, -1]
        u.append(gen.step(states[0].numpy()))
    np.testing.assert_allclose(np.concatenate(u)[: 4 * c], motion.accel[: 4 * c], atol=1e-6)
    # another payload: the same torques lift a heavier cup less high
    heavy = model.generate(sketch, physics=model.physics.replace(payload_mass=1.0))
    assert heavy.physics.payload_mass == 1.0 and not np.allclose(heavy.states, motion.states)
    with pytest.raises(ValueError, match="payload_mass"):
        model.physics.replace(payload_mass=-0.1)


def test_past_the_end_the_generator_stops_the_arm_and_holds_it_against_gravity(run, arm):
    """The stop plans joint accelerations and outputs the torques that give them (the arm's inverse dynamics):
    the arm decelerates within the stop's limit, comes to rest, and is then held against gravity, not let fall."""
    model = sm.load(run)
    sketch = model.task_def.sketch((0.75, -0.7), 80)
    gen = model.generator(sketch)
    stop = gen.contract()["stop"]
    assert stop["outputs"] == "outputs_for" and stop["accel_limit"] == list(arm.STOP_ACCEL)  # rad/s², not N·m
    states, (tau,) = drive([gen], model.dynamics(), sketch[0], until=79 + 1200)
    after, limit, still = slice(79, None), stop["rest_velocity"], stop["rest_velocity"] * (1 + 1e-9)
    assert np.abs(states[79, 2:]).max() > 0.1 and gen.done  # it was moving at the end of the motion; now at rest
    ddq = np.diff(states[after, 2:], axis=0) / 1e-3  # what the arm got: the planned accelerations
    assert np.all(np.abs(ddq) <= np.array(arm.STOP_ACCEL) + 1e-6)
    resting = np.all(np.abs(states[:, 2:]) <= still, axis=1)
    first = 79 + int(np.argmax(resting[after]))
    assert resting[after].any() and first < 79 + 1000 and resting[first:].all()  # at rest, and it stays there
    held = len(states) - 1 - first
    assert held > 200 and np.abs(states[-1, :2] - states[first, :2]).max() <= limit * held * 1e-3 + 1e-12  # no sag
    gravity = arm.bias_torques(torch.from_numpy(states[first:-1, :2]), torch.zeros(held, 2, dtype=torch.float64),
                               model.physics).numpy()
    np.testing.assert_allclose(tau[first:], gravity, rtol=0, atol=1e-6)  # the hold is gravity compensation
    violation = model.violation_torch(torch.from_numpy(states[None]), torch.from_numpy(tau[None]))[0].numpy()
    assert violation[after].max() <= 1e-6  # the stop keeps the liquid in


def test_dynamics_without_outputs_for_get_no_stepper(run, arm, monkeypatch):
    """Torques are not accelerations: without the map between them the generator could not stop the arm."""
    monkeypatch.delattr(arm.CupArmDynamics, "outputs_for")
    model = sm.load(run)
    with pytest.raises(ValueError, match=r"outputs \(N·m, N·m\) are not accelerations.*outputs_for"):
        model.generator(model.task_def.sketch((0.75, -0.7), 80))


def test_lm_moves_the_end_toward_a_joint_space_target(run):
    model = sm.load(run)
    sketch = model.task_def.sketch((0.75, -0.7), 80)
    target = torch.tensor(model.generate(sketch).states[-1, :2] + [0.01, -0.01])
    reach = sm.objectives.Function(residuals=lambda states, accel: states[:, -1, :2] - target)
    res = sm.optimize_latent(model, sketch, reach, steps=15, optimizer="lm")
    # the tiny model's 16 latent numbers get it within half the way (a small preset's 128 reach it to 1e-8)
    assert np.linalg.norm(res.states[-1, :2] - target.numpy()) < 0.5 * np.linalg.norm([0.01, 0.01])
    assert np.all(np.diff(res.history) <= 1e-12) and res.violation.max() <= 0.01


def test_cli_deform_and_optimize(installed, run, tmp_path):
    _, env = installed
    sketch = sm.load(run).task_def.sketch((0.75, -0.7), 80)
    np.savetxt(tmp_path / "sketch.csv", sketch, delimiter=",")
    done = seqmotion(env, "deform", "--model", str(run), "--input", "sketch.csv", "--output", "out.csv", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert (tmp_path / "out.csv").read_text().splitlines()[0].startswith("q1,q2,dq1,dq2,tau_1,tau_2")
    done = seqmotion(env, "optimize", "--model", str(run), "--target", "0.75", "-0.7", "--length", "80", "--steps",
                     "3", "--output", "opt.npz", cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert np.load(tmp_path / "opt.npz")["states"].shape == (80, 4)


def test_export_onnx_runs_the_arms_own_dynamics(run, bundle):
    from seqmotion.deploy import OnnxModel, OnnxStepper

    model = sm.load(run)
    assert (bundle / "dynamics.onnx").is_file()
    sketch = model.task_def.sketch((0.75, -0.7), 80)
    onnx = OnnxModel(bundle)
    for physics in (None, {"payload_mass": 0.8, "joint_damping": 0.1}):  # the payload is an input of the graph
        ref = model.generate(sketch, physics=None if physics is None else model.physics.replace(**physics))
        mine = onnx.generate(sketch, physics=physics)
        assert np.abs(mine["states"] - ref.states).max() <= 1e-5 * np.abs(ref.states).max()
    ref = model.generate(sketch)
    stepper, dynamics = OnnxStepper(bundle, sketch), model.dynamics()
    outputs, x = [stepper.step()], torch.from_numpy(sketch[:1])
    for _ in range(3):
        states = dynamics.step(dynamics.start(x), torch.from_numpy(outputs[-1][None]), None)[1]["states"]
        x = states[:, -1]
        outputs.append(stepper.step(states[0].numpy()))
    c = stepper.chunk
    np.testing.assert_allclose(np.concatenate(outputs)[: 4 * c], ref.accel[: 4 * c], rtol=0, atol=1e-4)


def test_the_onnx_stepper_stops_the_arm_like_pytorch(run, bundle, tmp_path):
    """The bundle carries the arm's outputs_for as a graph: the ONNX stepper's stop is PyTorch's, at the
    contract's payload and at another; a cup-arm bundle from before the graph is refused with advice."""
    import json
    import shutil

    from seqmotion.deploy import OnnxModel, OnnxStepper
    from seqmotion.deploy.bundle import SEAL, contract_digest

    model = sm.load(run)
    sketch = model.task_def.sketch((0.75, -0.7), 80)
    onnx = OnnxModel(bundle)
    assert onnx.contract["stop"]["outputs"] == "outputs_for" and onnx.contract["files"]["outputs_for"]
    for physics in (None, {"payload_mass": 0.8}):
        at = None if physics is None else model.physics.replace(**physics)
        gens = [model.generator(sketch, physics=at), OnnxStepper(onnx, sketch, physics=physics)]
        states, (mine, theirs) = drive(gens, model.dynamics(at), sketch[0], until=79 + 400)
        assert np.abs(states[-1, 2:]).max() < 0.1 * np.abs(states[79, 2:]).max()  # well into the stop
        np.testing.assert_allclose(theirs[79:], mine[79:], rtol=0, atol=1e-5)  # N·m
    old = Path(shutil.copytree(bundle, tmp_path / "old"))
    contract = json.loads((old / "contract.json").read_text())
    del contract["stop"]["outputs"], contract["files"]["outputs_for"], contract["sha256"]["outputs_for"]
    contract[SEAL] = contract_digest(contract)
    (old / "contract.json").write_text(json.dumps(contract))
    with pytest.raises(ValueError, match=r"'stop\.outputs' is missing and the outputs \(N·m, N·m\) are not "
                                         r"accelerations.*re-export"):
        OnnxModel(old)


def test_the_onnx_steppers_control_loop_calls_are_its_shared_codes(run, bundle):
    """One measured state per call runs on the stepper's buffers (the arm's dynamics one sample per call through
    the bundle's one-sample graph, the stop's outputs_for, dynamics and constraint through bound sessions, issue
    49) and gives what the shared stepper code gives, bit for bit, through the motion and the stop."""
    from seqmotion.deploy import OnnxStepper

    model = sm.load(run)
    sketch = model.task_def.sketch((0.75, -0.7), 80)
    fast, core = OnnxStepper(bundle, sketch), OnnxStepper(bundle, sketch)
    core._fast = None
    assert fast._fast.sample is not None and fast._fast.stop.outputs_for is not None
    states, (mine, theirs) = drive([fast, core], model.dynamics(), sketch[0], until=79 + 300, sizes=(1,))
    assert np.abs(states[79, 2:]).max() > 0.1 and fast.stopping == core.stopping
    assert np.array_equal(mine, theirs)
