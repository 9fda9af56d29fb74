"""Turn a pancake with the decoder in the loop: the shipped Deformer's online generator drives the
simulated arm through the Gymnasium environment at 1 kHz, reading noisy measurements.

    python examples/closed_loop_pancake.py                      # 3 episodes, per-sample replanning
    python examples/closed_loop_pancake.py --episodes 10 --replan chunk --seed 1

Every millisecond: the generator's next acceleration ``[a_y, a_z, a_θ]`` is the action (the
environment integrates it into the arm controller's reference); the observation's ``spatula``
field (``env.model_state(obs)``: ``[y, z, θ, v_y, v_z, v_θ]``) plus Gaussian noise
σ = (1 mm, 1 mm, 10 mrad, 2 cm/s, 2 cm/s, 0.2 rad/s) is what the generator reads back. The core
loop is :func:`seqmotion.sim.closed_loop.run_episode`; the few lines below show it by hand too.
"""

from __future__ import annotations

import argparse

import gymnasium as gym
import numpy as np

import seqmotion as sm
from seqmotion.sim.closed_loop import PANCAKE_NOISE, draw_turning_episodes, run_episode


def by_hand(env: gym.Env, deformer, sketch: np.ndarray, seed: int) -> bool:
    """The loop written out: whole-chunk replanning, the stepper's current interface."""
    base = env.unwrapped
    rng = np.random.default_rng(seed)
    obs, _ = env.reset(seed=seed, options={"start": sketch[0, :3]})
    gen = deformer.generator(sketch)
    u, measured = gen.step(), []                   # the first C accelerations, from x0
    kept = True
    for k in range(len(sketch) - 1):
        obs, _, terminated, _, info = env.step(base.to_action(u[k % gen.chunk]))
        kept &= info["in_contact"]
        measured.append(base.model_state(obs) + np.asarray(PANCAKE_NOISE) * rng.standard_normal(6))
        if len(measured) == gen.chunk:             # C states measured since the last call
            u, measured = gen.step(np.array(measured)), []
        if terminated:
            return False
    return kept


def main(argv: list[str] | None = None) -> list[dict]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--episodes", type=int, default=3)
    parser.add_argument("--seed", type=int, default=0, help="of the sketches; episode i uses seed + i for noise")
    parser.add_argument("--replan", choices=["sample", "chunk"], default="sample",
                        help="replan after every sample (falls back to whole chunks where the stepper "
                             "takes only those) or every chunk")
    args = parser.parse_args(argv)

    deformer = sm.load_pretrained("pancake")
    sketches, counts = draw_turning_episodes(deformer, args.episodes, args.seed)
    print(f"{args.episodes} turning sketches ({counts['drawn']} drawn; set aside: "
          f"{counts['set_aside_infeasible']} infeasible after deformation, "
          f"{counts['set_aside_out_of_workspace']} out of the arm's workspace)")
    env = gym.make("seqmotion/PancakeArm-v0", action="accel", frame_skip=1)
    print(f"env: dt = {env.unwrapped.dt * 1e3:g} ms, render_fps = {env.metadata['render_fps']}, "
          f"actions {env.unwrapped.action_layout}")
    rows = []
    for i, sketch in enumerate(sketches):
        r = run_episode(env, deformer, sketch, noise=PANCAKE_NOISE, seed=args.seed + i, replan_every=args.replan)
        rows.append(r.summary())
        end = r.plan[-1]
        print(f"episode {i}: turn to θ = {end[2]:+.2f} rad in {len(sketch)} ms, replanning {r.replanning}: "
              f"{'pancake kept on' if r.kept_on else 'pancake LOST'} (max slip {r.max_slip * 1e3:.2f} mm); "
              f"end pose {r.end_position_error * 1e3:.1f} mm / {np.degrees(r.end_attitude_error):.2f}° "
              f"from the noise-free motion; tracking {r.tracking_rmse * 1e3:.2f} mm RMSE")
    if sketches:
        kept = by_hand(env, deformer, sketches[0], args.seed)
        print(f"by hand (whole chunks), episode 0: {'pancake kept on' if kept else 'pancake LOST'}")
    env.close()
    return rows


if __name__ == "__main__":
    main()
