"""The chapter-5 pushing policy's closed loop on a Franka Panda (robosuite's model) in place of the Touch arm.

Runs the evaluation protocol of ``seqmotion lfd evaluate`` (5 trials at each of the 6 block positions, seed 0,
the same block placements and lighting) on the Touch arm and on the Panda (:mod:`seqmotion.lfd.env.robot`;
``--mode command`` or ``twin``, see :func:`seqmotion.lfd.rollout.run_trial`), the latter with the CNN on the Panda
world's images, with the CNN on the Touch world's images of the same trials, and (given ``--data``, a
``seqmotion lfd collect`` directory) with the demonstrations' medoid latents per position (no CNN). Prints one
JSON object (rates, per position, limits, tracking, timing, machine).

    MUJOCO_GL=egl python benchmarks/bench_pushing_robot.py [--trials 5] [--data DIR] [--mode twin] [--skip-touch]
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time

import numpy as np

import seqmotion as sm
from seqmotion.lfd.evaluation import evaluate, position_latents, run_on_robot


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--trials", type=int, default=5, help="trials per position (default 5: 30 in all)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--robot", default="panda")
    parser.add_argument("--data", default=None, help="a 'seqmotion lfd collect' directory (for oracle latents)")
    parser.add_argument("--skip-touch", action="store_true", help="do not run the Touch arm's own evaluation")
    parser.add_argument("--mode", default="command", choices=("command", "twin"),
                        help="how the decoder's commands reach the robot (seqmotion.lfd.rollout.run_trial)")
    args = parser.parse_args()
    policy = sm.load_pretrained("pushing")
    out: dict = {"policy": "pushing (shipped)", "robot": args.robot, "mode": args.mode,
                 "trials_per_position": args.trials, "seed": args.seed}

    def brief(result) -> dict:
        d = result.as_dict()
        d.pop("outcomes")
        d["failed"] = [f"{o.position}#{o.trial}" for o in result.outcomes if not o.success]
        return d

    if not args.skip_touch:
        start = time.perf_counter()
        touch = evaluate(policy, trials=args.trials, seed=args.seed)
        out["touch"] = {"success_rate": touch.success_rate, "per_position": touch.per_position,
                        "seconds": time.perf_counter() - start}
    runs = {"cnn": None, "cnn_on_touch_images": "touch"}
    if args.data:
        runs["oracle_medoid"] = position_latents(policy, os.path.join(args.data, "motions.h5"), medoid=True)
    for name, latents in runs.items():
        result = run_on_robot(policy, args.robot, trials=args.trials, seed=args.seed, latents=latents, mode=args.mode)
        out[name] = brief(result)
        out[name]["seconds_per_trial"] = result.seconds / result.n_trials
    out["machine"] = {"platform": platform.platform(), "processor": platform.processor(), "cpus": os.cpu_count(),
                      "load_average": [round(x, 2) for x in os.getloadavg()]}
    print(json.dumps(out, indent=1, default=lambda o: o.tolist() if isinstance(o, np.ndarray) else str(o)))


if __name__ == "__main__":
    main()
