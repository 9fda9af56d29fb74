"""The online stepper (``model.generator``): partial chunks, replanning, the end of the motion, latent swaps,
reset and input checks, on the shipped models (contract: ``seqmotion.core.stepper``)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

import seqmotion as sm
from seqmotion.core.stepper import outputs_are_accelerations, stepper_contract, stop_accel, stop_spec


@pytest.fixture(scope="module", autouse=True)
def _one_thread(one_thread):
    """Every test here runs torch on one thread (see conftest)."""


@pytest.fixture(scope="module")
def pancake(deformer):
    return deformer


@pytest.fixture(scope="module")
def sliding(planner):
    return planner


def drive(gen, x0, sizes, *, disturb=None, until=None):
    """Close the loop through the generator's own dynamics, passing the measured states in pieces of ``sizes``
    (cycled); ``disturb(t, states)`` may alter what is measured. Returns the applied outputs and the states."""
    x, applied, states = np.asarray(x0, dtype=np.float64), [], [np.asarray(x0, dtype=np.float64)]
    u, i = gen.step(), 0
    until = until or gen.length + 2 * gen.chunk
    while len(applied) < until:
        n = min(sizes[i % len(sizes)], len(u))
        i += 1
        nxt = gen._predict(x[None], u[None, :n])[0]
        applied.append(u[:n])
        states.append(nxt)
        measured = nxt if disturb is None else disturb(gen.time, nxt.copy())
        x = measured[-1]
        u = gen.step(measured)
    return np.concatenate(applied), np.concatenate([states[0][None], *states[1:]])


@pytest.mark.parametrize("sizes", [[1], [7, 1, 30, 12], [50]])
def test_fed_its_own_states_in_any_pieces_it_reproduces_deform(pancake, sizes):
    k = 130 if sizes == [1] else 230
    sketch = sm.tasks.pancake.data.straight((0.1, 0.05, 0.6), k)
    r = pancake.deform(sketch)
    accel, states = drive(pancake.generator(sketch), sketch[0], sizes, until=k - 1)
    np.testing.assert_allclose(accel[: k - 1], r.accel, rtol=0, atol=1e-9)
    np.testing.assert_allclose(states[:k], r.states, rtol=0, atol=1e-12)


def test_sliding_sample_by_sample_reproduces_plan(sliding):
    command = sm.tasks.sliding.data.circle(0.05, 260)
    plan = sliding.plan(command)
    accel, states = drive(sliding.generator(command), np.r_[np.zeros(4), command[0]], [1, 13, 40], until=259)
    np.testing.assert_allclose(accel[:259], plan.pan_accel, rtol=0, atol=1e-9)
    np.testing.assert_allclose(states[:260, 4:], plan.rel_states, rtol=0, atol=1e-12)


def test_replanning_reacts_to_a_disturbance_between_boundaries(pancake):
    sketch = sm.tasks.pancake.data.straight((0.1, 0.05, 0.6), 230)
    outs = {}
    for replan in (True, False):
        gen = pancake.generator(sketch, replan=replan)
        gen.step()
        measured = gen._predict(sketch[:1], gen.step(np.repeat(sketch[:1], 50, axis=0))[None, :10])[0]
        plan = gen._plan[0, 10:].copy()
        measured[-1, 1] += 0.005  # the spatula is measured 5 mm higher than planned
        outs[replan] = (gen.step(measured), plan)
    corrected, plan = outs[True]
    unchanged, plan_again = outs[False]
    np.testing.assert_array_equal(unchanged, plan_again)  # without replanning: the plan
    assert corrected.shape == (40, 3) and np.abs(corrected - plan).max() > 1e-3  # with: the decoder reacts


def test_past_the_end_it_stops_within_the_cone_and_holds(pancake):
    sketch = sm.tasks.pancake.data.straight((0.0, 0.1, -0.3), 150)
    for sizes, after_end in (([1], 700), ([50], 1000), ([3, 20], 1000)):
        gen = pancake.generator(sketch)
        accel, states = drive(gen, sketch[0], sizes, until=149 + after_end)
        assert gen.done or gen.stopping  # past the end: at rest, or still (within 1e-4 m/s) decelerating
        after = slice(149, None)
        violation = pancake.violation_torch(torch.from_numpy(states[None]), torch.from_numpy(accel[None]))[0]
        assert float(violation[after].max()) <= 1e-6  # the pancake stays on while stopping
        assert np.abs(states[-1, 3:]).max() < (1e-4 if after_end == 700 else 1e-5)  # at rest (from 1.3 m/s)
        assert np.abs(states[-1, :3] - states[148, :3]).max() < 0.25  # no run-away (the issue: z = -3.4 m)


def test_done_means_at_rest_and_a_while_not_done_loop_ends_standing_still(pancake):
    """Issue 32 item 5: ``done`` turned True at K while the stop ramp still ran (a ``while not gen.done`` loop left
    the pancake at 2.9 m/s; the stop took 1,600 samples more). Now ``stopping`` covers the ramp, ``done`` rest."""
    sketch = sm.tasks.pancake.data.straight((0.3, 0.0, 3.0), 200)
    gen = pancake.generator(sketch)
    x, u, phases = sketch[0], gen.step(), []
    while not gen.done:
        assert gen.time < 20_000, "never came to rest"
        phases.append((gen.time, gen.stopping))
        states = gen._predict(x[None], u[None])[0]
        x = states[-1]
        u = gen.step(states)
    speeds = np.abs(x[3:])
    assert speeds.max() <= 1e-6 and np.all(gen.step(gen._predict(x[None], u[None])[0]) == 0.0)  # at rest, holds 0
    stopping = [t for t, flag in phases if flag]
    assert stopping and min(stopping) >= 199 and not any(flag for t, flag in phases if t < 199)
    assert gen.time - 199 > 50  # the ramp took time the old flag did not wait for


def test_the_sliding_pan_stops_and_the_object_comes_to_rest(sliding):
    command = sm.tasks.sliding.data.circle(0.05, 300)
    gen = sliding.generator(command)
    accel, states = drive(gen, np.r_[np.zeros(4), command[0]], [100], until=299 + 1500)
    assert np.abs(states[-1, 2:4]).max() < 1e-6 and np.abs(states[-1, 6:]).max() == 0.0
    assert np.abs(accel[-100:]).max() == 0.0  # holding: exactly zero


def test_the_stop_outputs_accelerations_where_the_outputs_are_accelerations(pancake, sliding):
    """Pancake and sliding (the pan) output accelerations of their velocity columns: the stop outputs the planned
    accelerations themselves, limited by the output scale; dynamics mapping accelerations to their outputs
    (``outputs_for``) must name their own limit, in the velocity columns' units per second."""
    for model in (pancake, sliding):
        stop = stepper_contract(model, model.dynamics())["stop"]
        assert stop["outputs"] == "accelerations" and stop["accel_limit"] == list(model.model.cfg.output_scale)
    assert outputs_are_accelerations(["m", "rad/s"], ["rad/s²"], [1]) and not outputs_are_accelerations(
        ["rad", "rad/s"], ["N·m"], [1])

    class Mapped:
        def outputs_for(self, x, accel):
            return accel

    layouts = (pancake.state_layout, pancake.accel_layout, [1.0, 1.0, 1.0], [3, 4, 5])
    with pytest.raises(ValueError, match=r"Mapped dynamics .* no stop_accel_limit of 3 finite numbers > 0"):
        stop_spec(Mapped(), *layouts)
    Mapped.stop_accel_limit = (1.0, 2.0, float("nan"))
    with pytest.raises(ValueError, match="stop_accel_limit"):
        stop_spec(Mapped(), *layouts)
    Mapped.stop_accel_limit = (1.0, 2.0, 3.0)
    assert stop_spec(Mapped(), *layouts) == ("outputs_for", [1.0, 2.0, 3.0])


def test_stop_profile_is_clipped_then_geometric():
    v0 = np.array([[2.0, -0.01, 0.0]])
    a = stop_accel(v0, 400, np.array([1.0]), 0.05, np.array([10.0, 10.0, 10.0]), 1e-3, 1e-6)[0]
    v = v0[0] + 1e-3 * np.cumsum(a, axis=0)
    assert np.abs(a).max() <= 10.0 + 1e-12 and a[0, 0] == -10.0 and a[0, 2] == 0.0
    np.testing.assert_allclose(a[200:210, 0], -v[199:209, 0] / 0.05, rtol=1e-9)  # geometric after the clip
    assert np.all(np.diff(np.abs(v[:, 0])) <= 0) and abs(v[-1, 0]) < 1e-2


def test_set_latent_replays_from_the_next_boundary(pancake):
    first = sm.tasks.pancake.data.straight((0.1, 0.05, 0.6), 300)
    other = pancake.deform(sm.tasks.pancake.data.straight((-0.1, 0.0, -0.5), 300)).latent
    chunk = pancake.deform(first).states[1:51]
    gen, ref = pancake.generator(first), pancake.generator(latent=other, x0=first[0], length=300)
    gen.step(), ref.step()
    rest = gen.step(chunk[:20])  # mid-chunk: the rest of this chunk still comes from the old latent
    plan = gen._plan[0, 20:].copy()
    gen.set_latent(other)
    np.testing.assert_array_equal(rest, plan)
    np.testing.assert_array_equal(gen.step(chunk[20:21]), plan[1:])
    # the next boundary's chunk is what the new latent gives from the start, fed the same measured chunk
    np.testing.assert_array_equal(gen.step(chunk[21:]), ref.step(chunk))
    np.testing.assert_array_equal(gen.latent, other)


def test_set_latent_restart_starts_a_new_motion_here(pancake):
    sketch = sm.tasks.pancake.data.straight((0.1, 0.05, 0.6), 120)
    other = pancake.deform(sm.tasks.pancake.data.straight((-0.1, 0.0, -0.5), 200)).latent
    gen = pancake.generator(sketch)
    accel, states = drive(gen, sketch[0], [50], until=150)  # past the first motion's end
    assert gen.done or gen.stopping  # past the end
    with pytest.raises(ValueError, match="ended"):
        gen.set_latent(other)
    gen.set_latent(other, restart=True, length=200)
    here = states[-1]
    u = gen.step(gen._predict(here[None], np.zeros((1, 50, 3)))[0])  # the boundary: the new motion starts
    fresh = pancake.generator(latent=other, x0=gen._latest[0], length=200).step()
    np.testing.assert_array_equal(u, fresh)
    assert not gen.done and not gen.stopping and gen.length == 200


def test_reset_starts_over_and_takes_a_new_start_state(pancake):
    sketch = sm.tasks.pancake.data.straight((0.1, 0.05, 0.6), 200)
    gen = pancake.generator(sketch)
    first = gen.step()
    gen.step(np.repeat(sketch[:1], 10, axis=0))
    gen.reset()
    np.testing.assert_array_equal(gen.step(), first)
    start = sketch[0] + [0.01, 0.0, 0.05, 0, 0, 0]
    gen.reset(x0=start)
    z = pancake.deform(sketch).latent
    np.testing.assert_array_equal(gen.step(), pancake.generator(latent=z, x0=start, length=200).step())


def test_a_batch_steps_like_its_members(pancake):
    sketches = np.stack([sm.tasks.pancake.data.straight(end, 120) for end in ((0.1, 0.0, 0.5), (0.0, 0.1, -0.4))])
    gen = pancake.generator(sketches)
    u = gen.step()
    measured = gen._predict(sketches[:, 0], u[:, :5])
    both = gen.step(measured)
    assert u.shape == (2, 50, 3) and both.shape == (2, 45, 3)
    for i in range(2):
        one = pancake.generator(sketches[i])
        np.testing.assert_allclose(one.step(), u[i], rtol=1e-5, atol=1e-5)
        np.testing.assert_allclose(one.step(measured[i]), both[i], rtol=1e-5, atol=1e-5)


def test_the_contract_is_data(pancake, sliding):
    c = pancake.generator(sm.tasks.pancake.data.straight((0.1, 0.0, 0.5), 100)).contract()
    assert c["chunk"] == 50 and c["state_layout"]["names"][3] == "v_y" and c["state_layout"]["units"][2] == "rad"
    assert c["velocity_columns"] == [3, 4, 5] and c["constraint"] and c["length"] == 100
    assert "c_l = z" in c["decoder_init"]
    assert c["dynamics"] == {"graph": "dynamics.onnx", "dt": 0.001, "chunk": 50, "closed_form": "double_integrator",
                             "physics": {"class": "seqmotion.physics.pancake.PancakePhysics", "names": ["mu"],
                                         "inputs": [], "values": {"mu": 1.0}}}
    json.dumps(c)
    s = sliding.generator(latent=np.zeros(256), x0=np.zeros(8), physics=sliding.physics.replace(mu=0.6)).contract()
    assert s["dynamics"]["physics"] == {"class": "seqmotion.physics.sliding.SlidingPhysics", "names": ["mu", "mu_dyn"],
                                        "inputs": ["mu", "mu_dyn"], "values": {"mu": 0.6, "mu_dyn": 0.5}}
    assert s["dynamics"]["chunk"] == 100 and s["dynamics"]["closed_form"] is None and not s["constraint"]
    assert s["length"] == 1500 and s["velocity_columns"] == [2, 3]  # the longest training motion, the pan


def test_named_errors(pancake):
    sketch = sm.tasks.pancake.data.straight((0.1, 0.0, 0.5), 120)
    gen = pancake.generator(sketch)
    with pytest.raises(ValueError, match="first step"):
        gen.step(sketch[:5])
    u = gen.step()
    with pytest.raises(ValueError, match="measured"):
        gen.step()
    with pytest.raises(ValueError, match=r"6 columns.*pancake state.*v_theta \[rad/s\]"):
        gen.step(np.zeros((3, 4)))
    with pytest.raises(ValueError, match="NaN"):
        gen.step(np.full((3, 6), np.nan))
    with pytest.raises(ValueError, match=r"only 50 outputs"):
        gen.step(np.zeros((51, 6)))
    gen.step(np.zeros((len(u) - 5, 6)))
    with pytest.raises(ValueError, match=r"only 5 outputs"):
        gen.step(np.zeros((6, 6)))
    with pytest.raises(ValueError, match="latent"):
        gen.set_latent(np.zeros(5))
    with pytest.raises(ValueError, match="finite"):
        gen.set_latent(np.full(128, np.inf))
    with pytest.raises(ValueError, match="x0"):
        gen.reset(x0=[np.nan] * 6)
    with pytest.raises(ValueError, match="finite|NaN"):
        pancake.generator(latent=np.zeros(128), x0=[0, 0, np.nan, 0, 0, 0])
    with pytest.raises(ValueError, match="length"):
        pancake.generator(latent=np.zeros(128), x0=np.zeros(6), length=1)
    with pytest.raises(ValueError, match="not both"):
        pancake.generator(sketch, latent=np.zeros(128), x0=np.zeros(6))
