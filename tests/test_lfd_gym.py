"""The pushing task as a Gymnasium environment (``seqmotion/Pushing-v0``): it passes Gymnasium's checker and an
external policy evaluated through it meets exactly the episodes the library's rollout runs."""

from __future__ import annotations

import numpy as np
import pytest

gym = pytest.importorskip("gymnasium")
pytest.importorskip("seqmotion.lfd.env.pushing")

from gymnasium.utils.env_checker import check_env  # noqa: E402

from seqmotion.lfd.env import gym_env, pushing  # noqa: E402
from seqmotion.lfd.env.state import ArmState  # noqa: E402
from seqmotion.lfd.rollout import run_autonomous  # noqa: E402


@pytest.fixture
def registered():
    """The id registered for the test (as ``import seqmotion`` does), and the registry left as it was."""
    from gymnasium.envs.registration import registry

    added = gym_env.ENV_ID not in registry
    gym_env.register()
    yield gym_env.ENV_ID
    if added:
        registry.pop(gym_env.ENV_ID)


@pytest.mark.parametrize("hard", [False, True])
def test_the_env_passes_gymnasiums_checker(hard, registered):
    env = gym.make(gym_env.ENV_ID, hard=hard, duration=0.1).unwrapped
    try:
        check_env(env, skip_render_check=True)
        assert env.benchmark == ("hard" if hard else "chapter")
        assert env.metadata["render_fps"] == 50  # one step per 20 ms decision
    finally:
        env.close()


def test_registered_by_id_and_seeded(registered):
    env = gym.make(registered, duration=0.06)
    try:
        first, info = env.reset(seed=4)
        again, info_again = env.reset(seed=4)
        np.testing.assert_array_equal(first["image"], again["image"])
        assert info["position"] == info_again["position"] and first["image"].shape == (64, 64, 3)
        steps, truncated = 0, False
        while not truncated:
            _, reward, terminated, truncated, info = env.step(first["state"])  # hold where it started
            steps += 1
            assert not terminated
        assert steps == 3 and reward in (0.0, 1.0) and info["t"] == pytest.approx(0.06)
        with pytest.raises(gym.error.ResetNeeded):
            env.step(first["state"])
        with pytest.raises(ValueError, match="9 finite"):
            env.reset(seed=0)
            env.step(np.full(9, np.nan))
    finally:
        env.close()


def test_an_external_policy_through_the_env_meets_the_rollouts_episode():
    """The env steps as the rollout does: one sense per 1 ms period, the command held 20 ms."""
    position, variation = pushing.POSITIONS[2], pushing.SceneVariation.sample(np.random.default_rng(7))
    target = pushing.inverse_kinematics(np.array([0.16, 0.0, 0.03]))

    def policy(t: float, state: ArmState) -> ArmState:  # steer the tip toward a point near the block
        return ArmState(state.theta + 0.05 * (target - state.theta), np.zeros(3), np.zeros(3))

    env = gym_env.PushingEnv(duration=0.2)
    scene = pushing.PushingScene()
    try:
        obs, _ = env.reset(options={"position": position, "variation": variation})
        states, t, truncated = [], 0.0, False
        while not truncated:
            state = ArmState(obs["state"][:3], obs["state"][3:6], obs["state"][6:])
            states.append(obs["state"])
            command = policy(t, state)
            obs, _, _, truncated, _ = env.step(np.concatenate([command.theta, command.dtheta, command.tau]))
            t += 0.02
        run = run_autonomous(scene, policy, position, 0.2, variation)
        np.testing.assert_array_equal(np.array(states), np.hstack([run.slave_theta, run.slave_dtheta,
                                                                   run.slave_tau])[::20])
        np.testing.assert_array_equal(env.scene.block_pose, scene.block_pose)
    finally:
        env.close()
        scene.close()
