"""Runner results, input validation, the CLI, rendering and the Gymnasium environments."""

import argparse
import json
import math
import os
import warnings
from types import SimpleNamespace

import numpy as np
import pytest

os.environ.setdefault("MUJOCO_GL", "egl")  # before MuJoCo is first imported: offscreen rendering

from seqmotion.sim import run_pancake, run_sliding  # noqa: E402
from seqmotion.sim.motions import pan_circle, still  # noqa: E402
from seqmotion.tasks.pancake.data import straight  # noqa: E402


@pytest.fixture(scope="module")
def pancake_result():
    return run_pancake(straight((0.05, 0.03, 0.4), 150), hold_time=0.05)


def test_pancake_result_has_aligned_shapes_and_sane_metrics(pancake_result):
    r = pancake_result
    n = 150 + 100 + 50  # input + 0.1 s deceleration + 0.05 s hold
    assert r.n_motion == 150
    assert r.time.shape == (n,) and r.command.shape == (n, 6) and r.response.shape == (n, 6)
    assert r.slip.shape == r.gap.shape == r.tilt.shape == (n,)
    assert r.executed_violation.shape == (149,)
    assert r.torque_peak.shape == (6,)
    assert r.command[:150, :3] == pytest.approx(straight((0.05, 0.03, 0.4), 150)[:, :3])
    assert 0 < r.position_rmse < 3e-3 and 0 < r.attitude_rmse < 0.02
    assert not r.contact_lost and r.contact_lost_time is None and r.on_spatula and not r.turned_over
    assert r.realtime_factor > 0 and r.diverged is None
    summary = r.summary()
    json.dumps(summary)  # JSON-friendly
    assert summary["contact_lost"] is False
    assert "stayed on" in r.describe()


def test_contact_lost_time_is_when_the_slip_crosses_the_limit():
    r = run_pancake(still(math.radians(55), 0.5), hold_time=0.0, settle_time=0.0)
    assert r.contact_lost
    k = round(r.contact_lost_time / 1e-3)
    assert r.slip[k] > 5e-3 and r.slip[k - 1] <= 5e-3 and r.gap[k - 1] <= 2e-3


def test_sliding_result_and_rmse_against_the_command():
    pan = pan_circle(2.0, duration=0.5, ramp=0.3)
    command = np.zeros((len(pan), 4))
    command[:, 0] = np.linspace(0.0, 0.02, len(pan))  # ask the object to move 2 cm; it will stick
    plan = SimpleNamespace(pan_states=pan, rel_states=np.zeros((len(pan), 4)))
    r = run_sliding(plan, command, hold_time=0.0)
    n = len(pan) + 100
    assert r.object_path.shape == (n, 2) and r.pan_command.shape == (n, 2) and r.pan_accel.shape == (n, 2)
    assert r.command.shape == (len(pan), 2)
    assert r.rmse == pytest.approx(0.02 / math.sqrt(3), abs=5e-4)  # it stays at the centre
    assert r.rmse_plan < 5e-4  # ... exactly where the 2-D plan said it would be
    assert r.pan_excursion == pytest.approx(np.linalg.norm(r.pan_response - r.pan_response[0], axis=1).max())
    assert r.pan_range[0] > 0 and not r.fell_off and not r.tipped
    json.dumps(r.summary())
    assert "stayed on" in r.describe()


@pytest.mark.parametrize(
    ("states", "match"),
    [
        (np.zeros((10, 5)), "6 columns"),
        (np.zeros(6), "shape"),
        (np.zeros((1, 6)), "at least K = 2"),
        (np.full((10, 6), np.nan), "NaN"),
        (np.zeros((2, 10, 6)), "one trajectory"),
        ("abc", "numeric"),
    ],
)
def test_run_pancake_rejects_bad_states(states, match):
    with pytest.raises(ValueError, match=match):
        run_pancake(states)


def test_run_pancake_rejects_motions_outside_the_workspace_and_bad_options():
    far = straight((0.0, -0.5, 0.0), 100)  # down into the table
    with pytest.raises(ValueError, match="workspace"):
        run_pancake(far)
    with pytest.raises(ValueError, match="gains"):
        run_pancake(still(0.0, 0.1), gains="fast")
    with pytest.raises(ValueError, match="decel_time"):
        run_pancake(still(0.0, 0.1), decel_time=-1.0)


def test_run_sliding_rejects_bad_inputs():
    pan = np.zeros((50, 4))
    with pytest.raises(ValueError, match="4 columns"):
        run_sliding(np.zeros((50, 6)))
    with pytest.raises(ValueError, match="NaN"):
        run_sliding(np.full((50, 4), np.inf))
    with pytest.raises(ValueError, match="samples"):
        run_sliding(pan, np.zeros((40, 4)))
    with pytest.raises(ValueError, match="command"):
        run_sliding(pan, np.zeros((50, 3)))
    with pytest.raises(ValueError, match="differ in length"):
        run_sliding(SimpleNamespace(pan_states=pan, rel_states=np.zeros((49, 4))))
    with pytest.raises(ValueError, match="not on the pan"):
        run_sliding(pan, np.full((50, 4), 0.2))
    far = np.zeros((50, 4))
    far[:, 0] = 0.6  # 1.25 m from the base: out of reach
    with pytest.raises(ValueError, match="workspace"):
        run_sliding(far)


def test_cli_runs_both_scenes_from_npz_and_csv(tmp_path, capsys):
    from seqmotion.sim import cli

    parser = argparse.ArgumentParser()
    cli.add_parser(parser.add_subparsers(dest="command"))
    states = straight((0.03, 0.0, 0.2), 120)
    np.savetxt(tmp_path / "t.csv", states, delimiter=",", header="y,z,theta,vy,vz,vtheta", comments="")
    args = parser.parse_args(["simulate", "pancake", "--trajectory", str(tmp_path / "t.csv"),
                              "--json", str(tmp_path / "m.json")])
    assert args.func(args) == 0
    metrics = json.loads((tmp_path / "m.json").read_text())
    assert metrics["metrics"]["contact_lost"] is False and len(metrics["response"]) == 120 + 100 + 500
    np.savez(tmp_path / "p.npz", pan_states=np.zeros((100, 4)), command=np.zeros((100, 4)))
    args = parser.parse_args(["simulate", "sliding", "--trajectory", str(tmp_path / "p.npz")])
    assert cli.run(args) == 0
    assert "object RMSE" in capsys.readouterr().out
    args = parser.parse_args(["simulate", "sliding", "--trajectory", str(tmp_path / "t.csv")])
    with pytest.raises(ValueError, match="4 columns"):
        cli.run(args)
    args = parser.parse_args(["simulate", "pancake", "--trajectory", str(tmp_path / "missing.npz")])
    with pytest.raises(ValueError, match="does not exist"):
        cli.run(args)


def test_video_and_snapshots_are_written(tmp_path):
    from seqmotion.sim.arm import get_scene
    from seqmotion.sim.render import FrameRecorder

    try:
        FrameRecorder(get_scene("pancake").model, "oblique", 64, 48).close()
    except RuntimeError as exc:  # no OpenGL on this machine (CI installs Mesa's EGL)
        pytest.skip(str(exc))
    r = run_pancake(straight((0.02, 0.0, 0.2), 100), video=tmp_path / "v.mp4", snapshots=tmp_path / "s.png",
                    n_snapshots=3, hold_time=0.0, slow_motion=1.0, fps=25)
    assert r.diverged is None
    import imageio.v2 as imageio

    assert (tmp_path / "v.mp4").stat().st_size > 1000
    frames = imageio.mimread(tmp_path / "v.mp4")
    assert len(frames) == pytest.approx(200 / 40, abs=1)  # 0.2 s at 25 fps, real time
    strip = imageio.imread(tmp_path / "s.png")
    assert strip.shape[1] > 3 * 600  # three 640-px frames side by side


@pytest.mark.parametrize("env_id", ["seqmotion/PancakeArm-v0", "seqmotion/SlidingArm-v0"])
def test_gymnasium_environments_pass_the_checker(env_id):
    import gymnasium as gym
    from gymnasium.utils.env_checker import check_env

    import seqmotion.sim.envs  # noqa: F401  (registers the ids)

    env = gym.make(env_id)
    with warnings.catch_warnings():  # the checker's advice (normalised, bounded spaces) is not an error
        warnings.simplefilter("ignore", UserWarning)
        check_env(env.unwrapped, skip_render_check=True)
    obs, _ = env.reset(seed=7)
    assert obs.shape == env.observation_space.shape
    hold = np.zeros(env.action_space.shape)
    total = 0.0
    for _ in range(20):  # holding the start pose keeps the object where it is
        obs, reward, terminated, truncated, info = env.step(hold)
        total += reward
        assert not terminated
    if env_id.startswith("seqmotion/Pancake"):
        assert total == 20.0 and info["in_contact"]
    else:
        assert info["distance"] == pytest.approx(np.linalg.norm(info["goal"]), abs=1e-3)
    with pytest.raises(ValueError, match="action"):
        env.unwrapped.step(np.full(env.action_space.shape, np.nan))
    env.close()


def test_pancake_env_drops_the_pancake_when_tilted_too_far():
    from seqmotion.sim.envs import PancakeArmEnv

    env = PancakeArmEnv(frame_skip=20)
    env.reset(seed=0)
    terminated, steps = False, 0
    while not terminated and steps < 100:  # tilt to 60° and hold
        _, reward, terminated, _, _ = env.step(np.array([0.0, 0.0, math.radians(60)]))
        steps += 1
    assert terminated and reward == 0.0


def test_figures_are_written(tmp_path, pancake_result):
    from seqmotion.sim import plot_pancake_psi, plot_pancake_tracking, plot_sliding

    states = straight((0.05, 0.03, 0.4), 150)
    assert plot_pancake_tracking(states, pancake_result, tmp_path / "a.png", original=states).stat().st_size > 0
    deformed = SimpleNamespace(states=states, accel=np.diff(states[:, 3:], axis=0) / 1e-3)
    assert plot_pancake_psi(deformed, pancake_result, tmp_path / "b.png").stat().st_size > 0
    sliding = run_sliding(np.zeros((50, 4)), np.zeros((50, 4)), hold_time=0.0, decel_time=0.0)
    assert plot_sliding(sliding, tmp_path / "c.png", label="still").stat().st_size > 0
