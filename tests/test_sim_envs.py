"""The Gymnasium environments (issue 18): registration, timing, named observations, action spaces,
refused steps, and the closed loop with the pancake Deformer's online generator."""

from __future__ import annotations

import math
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import seqmotion as sm
from seqmotion.sim.envs import PANCAKE_FIELDS, SLIDING_FIELDS, PancakeArmEnv, ResetNeeded, SlidingArmEnv
from seqmotion.sim.registration import ENV_IDS, register_envs
from seqmotion.tasks.pancake.data import straight

ARM_ENV_IDS = sorted(env_id for env_id, entry in ENV_IDS.items() if entry.startswith("seqmotion.sim.envs:"))
"""The arm environments (their keywords: action, frame_skip, ...); seqmotion/Pushing-v0 has tests/test_lfd_gym.py."""
VARIANTS = [{}, {"action": "accel", "frame_skip": 1}, {"action": "pose"}, {"normalize_actions": True},
            {"action": "accel", "normalize_actions": True, "frame_skip": 3}]


def test_import_seqmotion_registers_the_ids_without_mujoco():
    """In a fresh interpreter: no gymnasium.make prefix needed, and registering imports no MuJoCo."""
    code = (
        "import sys, gymnasium as gym, seqmotion\n"
        "assert 'mujoco' not in sys.modules and 'seqmotion.sim.envs' not in sys.modules, 'registration is heavy'\n"
        "gym.register_envs(seqmotion)\n"
        "env = gym.make('seqmotion/PancakeArm-v0')\n"
        "assert type(env.unwrapped).__name__ == 'PancakeArmEnv'\n"
        "assert gym.spec('seqmotion/SlidingArm-v0').entry_point == 'seqmotion.sim.envs:SlidingArmEnv'\n"
        "print('ok')\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "ok"


def test_gymnasium_plugin_entry_point_registers_under_its_namespace():
    """What Gymnasium 0.26–0.29's ``load_plugin_envs`` does with the ``gymnasium.envs`` entry point."""
    from importlib.metadata import entry_points

    from gymnasium.envs.registration import namespace, registry

    (plugin,) = [ep for ep in entry_points(group="gymnasium.envs") if ep.name == "seqmotion"]
    assert plugin.value == "seqmotion.sim.registration:register_envs"
    saved = {env_id: registry.pop(env_id) for env_id in ENV_IDS}
    try:
        with namespace(plugin.name):
            plugin.load()()
        assert sorted(env_id for env_id in registry if env_id.startswith("seqmotion/")) == sorted(ENV_IDS)
        register_envs()  # idempotent
    finally:
        registry.update(saved)


@pytest.mark.parametrize("env_id", ARM_ENV_IDS)
@pytest.mark.parametrize("kwargs", VARIANTS, ids=lambda k: ",".join(f"{a}={b}" for a, b in k.items()) or "default")
def test_every_env_passes_the_checker(env_id, kwargs):
    env = gym.make(env_id, **kwargs)
    with warnings.catch_warnings():  # the checker's advice (unbounded observations) is not an error
        warnings.simplefilter("ignore", UserWarning)
        check_env(env.unwrapped, skip_render_check=True)
    base = env.unwrapped
    assert base.dt == pytest.approx(base.frame_skip * 1e-3)
    assert env.metadata["render_fps"] == pytest.approx(1.0 / base.dt)  # a video at render_fps plays in real time
    if kwargs.get("normalize_actions"):
        assert np.all(env.action_space.low == -1) and np.all(env.action_space.high == 1)
    env.close()


@pytest.mark.parametrize("env_id", ARM_ENV_IDS)
def test_an_unknown_keyword_is_refused_by_name_with_the_valid_ones(env_id):
    """Issue 32, item 12: ``action_mode="accel"`` (for ``action=``) got Python's bare TypeError."""
    with pytest.raises(ValueError, match=r"no keyword 'action_mode' \(did you mean action=\?\).*frame_skip, action,"):
        gym.make(env_id, action_mode="accel")


def test_observation_fields_are_named_contiguous_and_cover_the_vector():
    for fields, cls in ((PANCAKE_FIELDS, PancakeArmEnv), (SLIDING_FIELDS, SlidingArmEnv)):
        stops = [0] + [f.slice.stop for f in fields.values()]
        assert [f.slice.start for f in fields.values()] == stops[:-1]
        assert all(len(f.names) == len(f.units) == f.slice.stop - f.slice.start for f in fields.values())
        assert cls.model_layout.names == tuple(n for name in cls.model_fields for n in fields[name].names)
    assert PANCAKE_FIELDS["spatula"].slice == slice(22, 28) and SLIDING_FIELDS["object"].slice == slice(26, 30)
    env = PancakeArmEnv()
    assert env.observation_space.shape == (28,) and env.observation_layout.names[22] == "spatula.y"
    with pytest.raises(KeyError, match="spatula"):
        env.field(np.zeros(28), "velocity")


def test_model_state_reads_the_deformers_state_with_theta_unwrapped():
    env = PancakeArmEnv(frame_skip=20, jitter=0.0)
    obs, _ = env.reset(seed=0, options={"start": (0.02, -0.03, 3.0)})
    x = env.model_state(obs, sm.load_pretrained("pancake"))
    np.testing.assert_allclose(x[:3], [0.02, -0.03, 3.0], atol=2e-3)
    np.testing.assert_allclose(env.field(obs, "tool_pos")[1:], [0.02, -0.03 + 0.35], atol=2e-3)
    for _ in range(10):  # roll on past π: θ keeps counting (a wrapped -3.0 would drop the pancake)
        obs, *_ = env.step(np.array([0.02, -0.03, 3.3]))
    assert env.model_state(obs)[2] == pytest.approx(3.3, abs=0.01)
    assert env.model_state(np.stack([obs, obs])).shape == (2, 6)
    with pytest.raises(ValueError, match="pan and object state"):
        env.model_state(obs, sm.load_pretrained("sliding"))
    sliding = SlidingArmEnv()
    assert sliding.model_state(sliding.reset(seed=0)[0]).shape == (8,)


def test_normalised_actions_map_onto_the_physical_range():
    env = PancakeArmEnv(normalize_actions=True)
    phys = env.physical_action_space
    np.testing.assert_allclose(env.to_physical(np.ones(3)), phys.high)
    np.testing.assert_allclose(env.to_physical(-np.ones(3)), phys.low)
    p = np.array([0.1, -0.05, 1.0])
    np.testing.assert_allclose(env.to_physical(env.to_action(p)), p)
    assert env.action_layout.names == ("y", "z", "theta")
    assert PancakeArmEnv(action="accel").action_layout.names == ("a_y", "a_z", "a_theta")


def test_step_is_refused_before_reset_after_a_failed_reset_and_after_leaving_the_workspace():
    env = PancakeArmEnv(action="accel", frame_skip=10)
    with pytest.raises(ResetNeeded, match="reset"):
        env.step(np.zeros(3))
    with pytest.raises(ValueError, match="workspace"):
        env.reset(options={"start": (0.0, -0.6, 0.0)})
    with pytest.raises(RuntimeError, match="last reset"):  # ResetNeeded is a RuntimeError too
        env.step(np.zeros(3))
    with pytest.raises(ValueError, match="unknown reset option"):
        env.reset(options={"goal": (0, 0)})
    with pytest.raises(ValueError, match="finite"):
        env.reset(options={"start": (math.nan, 0, 0)})
    env.reset(seed=1)
    obs, reward, terminated, truncated, info = env.step(np.zeros(3))
    assert not terminated and reward == 1.0
    for _ in range(80):  # accelerate down (gently: the pancake stays on) out of reach
        _, _, terminated, _, info = env.step(np.array([0.0, -5.0, 0.0]))
        if terminated:
            break
    assert terminated and "shoulder" in info["out_of_workspace"]
    with pytest.raises(ResetNeeded, match="workspace"):
        env.step(np.zeros(3))


def test_episodes_are_truncated_by_simulated_time():
    env = PancakeArmEnv(frame_skip=10, time_limit=0.05)
    env.reset(seed=0)
    flags = [env.step(np.zeros(3))[3] for _ in range(5)]
    assert flags == [False] * 4 + [True]


def test_accel_actions_execute_like_run_pancake():
    """A motion's accelerations applied one per 1 ms step = run_pancake on its states (to µm)."""
    from seqmotion.physics.integrator import integrate_numpy
    from seqmotion.sim import run_pancake

    sketch = straight((0.03, 0.02, 0.5), 120)
    accel = np.diff(sketch[:, 3:], axis=0) / 1e-3
    states = integrate_numpy(sketch[0], accel)
    env = PancakeArmEnv(action="accel", frame_skip=1, jitter=0.0)
    env.reset(seed=0)
    executed = np.array([env.model_state(env.step(a)[0]) for a in accel])
    np.testing.assert_allclose(env.reference, states[-1], atol=1e-12)
    response = run_pancake(states, hold_time=0.0, decel_time=0.0).response[1:len(states)]
    np.testing.assert_allclose(executed[:, :3], response[:, :3], atol=1e-4)  # 0.1 mm, 0.1 mrad (settle: 20 vs 200 ms)


def test_render_fps_matches_the_frames(tmp_path):
    env = PancakeArmEnv(frame_skip=20, render_mode="rgb_array", width=64, height=48)
    env.reset(seed=0)
    try:
        frame = env.render()
    except RuntimeError as exc:  # no OpenGL on this machine (CI installs Mesa's EGL)
        pytest.skip(str(exc))
    finally:
        env.close()
    assert frame.shape == (48, 64, 3) and env.metadata["render_fps"] == 50


def test_closed_loop_keeps_the_pancake_on_with_measurement_noise(deformer, one_thread):
    from seqmotion.sim.closed_loop import PANCAKE_NOISE, draw_turning_episodes, run_episode

    sketches, counts = draw_turning_episodes(deformer, 2, seed=0)
    assert counts["drawn"] >= 2 and len(sketches) == 2
    env = gym.make("seqmotion/PancakeArm-v0", action="accel", frame_skip=1)
    for i, (sketch, replan) in enumerate(zip(sketches, ("sample", "chunk"), strict=True)):
        r = run_episode(env, deformer, sketch, noise=PANCAKE_NOISE, seed=i, replan_every=replan)
        assert r.kept_on and r.ended is None, r.summary()
        assert r.end_position_error < 0.02 and r.end_attitude_error < math.radians(5)
        assert r.replanning == replan or r.replanning.startswith("chunk (fallback")
        assert r.states.shape == (len(sketch) - 1, 6) and r.measured.shape == r.states.shape
    # fed its own reference, the loop is `deform` executed: the reference is the deformed motion
    r = run_episode(env, deformer, sketches[1], feedback="reference", replan_every="chunk")
    np.testing.assert_allclose(r.reference, r.plan[1:], atol=1e-9)
    with pytest.raises(ValueError, match="frame_skip=1"):
        run_episode(gym.make("seqmotion/PancakeArm-v0"), deformer, sketches[0])
    with pytest.raises(ValueError, match="noise"):
        run_episode(env, deformer, sketches[0], noise=(1e-3, 1e-3))


def test_the_closed_loop_example_runs(capsys, one_thread):
    import runpy
    from pathlib import Path

    example = Path(__file__).resolve().parents[1] / "examples" / "closed_loop_pancake.py"
    main = runpy.run_path(str(example))["main"]
    rows = main(["--episodes", "1", "--replan", "chunk"])
    assert len(rows) == 1 and rows[0]["kept_on"]
    assert "pancake kept on" in capsys.readouterr().out


@pytest.mark.parametrize("env_class", [PancakeArmEnv, SlidingArmEnv])
def test_the_built_in_arm_by_name_behaves_as_the_built_in_arm(env_class):
    """``robot="mh3f"`` resolves to the built-in arm (``env.robot`` is ``None``): the same scene, the same refused
    start, the same steps to the same observations, leaving the workspace at the same step for the same reason."""
    from seqmotion.sim.robot_models import BUILT_IN

    envs = [env_class(action="accel", frame_skip=10, robot=robot) for robot in (None, BUILT_IN)]
    assert [env.robot for env in envs] == [None, None] and envs[0].scene is envs[1].scene
    if env_class is PancakeArmEnv:  # a start out of the built-in arm's reach, above the table
        for env in envs:
            with pytest.raises(ValueError, match="wrist centre"):
                env.reset(options={"start": (0.45, 0.0, 0.0)})
    push = np.array([0.0, -5.0, 0.0]) if env_class is PancakeArmEnv else np.array([15.0, 0.0])
    runs = []
    for env in envs:
        obs, _ = env.reset(seed=3)
        steps = [(obs, 0.0, False, {})]
        for _ in range(80):  # accelerate out of reach: down (pancake) or forward (pan)
            obs, reward, terminated, _, info = env.step(push)
            steps.append((obs, reward, terminated, info))
            if terminated:
                break
        runs.append(steps)
    assert len(runs[0]) == len(runs[1]) and runs[0][-1][2], "the episode should leave the workspace"
    assert "shoulder" in runs[0][-1][3]["out_of_workspace"]
    for (obs_a, rew_a, term_a, info_a), (obs_b, rew_b, term_b, info_b) in zip(*runs, strict=True):
        np.testing.assert_array_equal(obs_a, obs_b)
        assert (rew_a, term_a) == (rew_b, term_b)
        assert {k: str(v) for k, v in info_a.items()} == {k: str(v) for k, v in info_b.items()}
