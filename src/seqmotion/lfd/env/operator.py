"""A scripted human operator who pushes the master's stylus like a person would.

The hand is modelled by the equilibrium-point hypothesis of human motor control: the
operator moves a *virtual* target point along minimum-jerk paths, and the hand applies to
the stylus tip the force of a spring-damper between that target and the tip::

    F = K_h (x_d − x) + D_h (ẋ_d − ẋ) + f_tremor,      |F| ≤ F_max

so the operator applies force, never position: the master moves because of this force and
the bilateral controller, and a block resisting on the slave side is felt as the master
resisting the hand. ``f_tremor`` is slow random force noise (an Ornstein–Uhlenbeck process).

Like a person watching the remote robot, the operator paces the push by what the slave
does: the stroke slows down when the slave's tip lags the target (along the push) by more
than ``lag_comfort`` and stops at ``lag_stop``. Without this a scripted target would keep moving
while the slave is held by the block's static friction, and the slave would lunge when the
block breaks free (the bilateral position coupling is soft: K_p = 120 /s² on a joint
inertia of ~1e-3 kg m²).

What the operator does (dissertation Fig. 5.4), with ``s = ±1`` the side of the block
(+1 on the robot's left, pushed towards −y):

1. ``wait``      — reaction time with the hand still.
2. ``approach``  — lift over and go behind the block: above its outer face, with a path that
   bulges a little differently every time.
3. ``descend``   — lower the pen beside the outer face, a few mm away from it.
4. ``push``      — sweep towards the other side until the block's centre should be
   ``overshoot`` past the centre line (some first pushes are deliberately hesitant and stop
   short). While pushing, the hand also leans into the stroke with a feed-forward force
   ``push_force`` (ramped in over ``push_ramp``), as people do when they know an object is
   heavy, and relaxes it once they see the block give way (it has moved 4 mm); the spring
   towards the paced target then carries the stroke. Pushing with one point is unstable —
   the block turns away from the pen — so, like a person, the operator steers: the pen
   slides along the face towards the side that turns the block back (``steer_gain`` metres
   per radian of block yaw, integrated with time constant ``steer_lag``).
5. ``check``     — pause and look. If the block has not clearly crossed the centre line (on the
   hard benchmark, if its centre does not look inside the goal band: the operator is told to put
   it on the goal line, :data:`seqmotion.lfd.env.pushing.GOAL_PAST`), push again (up to
   ``max_pushes`` pushes in all): if the pen is still behind the block's outer face,
   ``back_off`` a centimetre, ``realign`` with the face as it is now and push; if it slipped
   past or onto the block, ``back_off`` by lifting it clear, then approach and descend again.
   A push that stalls for ``STALL_TIME`` is abandoned and checked.
6. ``retract``   — lift the pen away, then ``hold``.

The operator sees the slave-side block (its true pose) with Gaussian perception noise each
time it looks (at planning moments), and never reads the simulator otherwise.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from . import pushing
from .pushing import BlockPosition
from .teleop import Operator

PHASES = ("wait", "approach", "descend", "push", "check", "back_off", "realign", "retract", "hold")
"""Phase names; a demonstration's ``phase`` array holds indices into this tuple."""
_P = {name: i for i, name in enumerate(PHASES)}
STALL_TIME = 0.6
"""A push whose stroke has not advanced for this long [s] is abandoned (then checked and redone)."""


@dataclass(frozen=True)
class OperatorParams:
    """One operator's style for one episode (SI units). Sample with :meth:`sample`.

    Attributes:
        reaction_time: still time before moving [s].
        speed: multiplier of the nominal speeds [-].
        stiffness: hand stiffness K_h [N/m].
        damping: hand damping D_h [N s/m].
        force_limit: largest hand force F_max [N].
        tremor: standard deviation of the hand's force noise [N].
        perception_noise: standard deviation of the perceived block position [m].
        approach_height: tip height while passing over the block [m].
        bulge_height: extra lift in the middle of the approach [m].
        bulge_forward: forward (x) bulge of the approach path [m].
        push_height: tip height while pushing [m] (the block is 0.05 m high).
        aim_offset: where along the 10 cm face the operator aims, from its centre [m].
        standoff: gap left between pen and face before pushing [m].
        push_speed: mean speed of the push stroke [m/s] (before ``speed``).
        overshoot: how far past the centre line the block's centre is aimed [m].
        push_force: feed-forward force the hand leans into the stroke with [N].
        push_ramp: time to build up ``push_force`` [s].
        hesitant: whether the first push deliberately stops short (forcing a correction).
        shortfall: how far short of the centre line a hesitant push aims the block's centre [m].
        max_pushes: pushes allowed before giving up [-].
        steer_gain: lateral shift of the aim point per radian of block yaw while pushing [m/rad].
        steer_lag: time constant of the steering (aim point and pen height) corrections [s].
        lag_comfort: slave-tip lag behind the target at which the operator starts to slow down [m].
        lag_stop: lag at which the operator's target stops advancing [m].
    """

    reaction_time: float = 0.2
    speed: float = 1.0
    stiffness: float = 200.0
    damping: float = 5.0
    force_limit: float = 4.0
    tremor: float = 0.04
    perception_noise: float = 0.003
    approach_height: float = 0.08
    bulge_height: float = 0.01
    bulge_forward: float = 0.0
    push_height: float = 0.025
    aim_offset: float = 0.0
    standoff: float = 0.01
    push_speed: float = 0.13
    overshoot: float = 0.02
    push_force: float = 0.6
    push_ramp: float = 0.3
    hesitant: bool = False
    shortfall: float = 0.02
    max_pushes: int = 3
    steer_gain: float = 0.05
    steer_lag: float = 0.2
    lag_comfort: float = 0.01
    lag_stop: float = 0.02

    @classmethod
    def sample(cls, rng: np.random.Generator, hesitant_probability: float = 0.15) -> OperatorParams:
        """Human-like variability between demonstrations (ranges chosen by hand, see module doc)."""
        return cls(
            reaction_time=float(rng.uniform(0.12, 0.3)),
            speed=float(rng.uniform(0.85, 1.2)),
            stiffness=float(rng.uniform(150.0, 300.0)),
            damping=float(rng.uniform(4.0, 7.0)),
            force_limit=float(rng.uniform(3.0, 5.0)),
            tremor=float(rng.uniform(0.02, 0.06)),
            perception_noise=float(rng.uniform(0.002, 0.004)),
            approach_height=float(rng.uniform(0.075, 0.09)),
            bulge_height=float(rng.uniform(0.0, 0.02)),
            bulge_forward=float(rng.uniform(-0.015, 0.015)),
            push_height=float(rng.uniform(0.012, 0.024)),
            aim_offset=float(rng.normal(0.0, 0.005)),
            standoff=float(rng.uniform(0.004, 0.015)),
            push_speed=float(rng.uniform(0.10, 0.16)),
            overshoot=float(rng.uniform(0.01, 0.03)),
            push_force=float(rng.uniform(0.4, 0.8)),
            push_ramp=float(rng.uniform(0.2, 0.4)),
            hesitant=bool(rng.random() < hesitant_probability),
            shortfall=float(rng.uniform(0.012, 0.03)),
            steer_gain=float(rng.uniform(0.035, 0.07)),
            steer_lag=float(rng.uniform(0.15, 0.3)),
            lag_comfort=float(rng.uniform(0.008, 0.012)),
            lag_stop=float(rng.uniform(0.016, 0.024)),
        )

    def as_dict(self) -> dict[str, float]:
        """Plain ``{name: float}`` (booleans as 0/1) for storage."""
        return {k: float(v) for k, v in asdict(self).items()}


def _yaw(block_pose: np.ndarray) -> float:
    """The object's rotation about the vertical [rad] from its pose ``(7,)`` (it turns about z only)."""
    return 2.0 * math.atan2(block_pose[6], block_pose[3])


@dataclass
class _Segment:
    """A minimum-jerk move of the hand's target from ``start`` to ``end`` over ``duration`` [s]."""

    start: np.ndarray
    end: np.ndarray
    t0: float
    duration: float
    bulge: np.ndarray

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray, bool]:
        """Target position, velocity, and whether the move is over, at time ``t``."""
        tau = (t - self.t0) / self.duration
        if tau >= 1.0:
            return self.end, np.zeros(3), True
        tau = max(tau, 0.0)
        s = tau**3 * (10 - 15 * tau + 6 * tau**2)
        ds = 30 * tau**2 * (1 - tau) ** 2 / self.duration
        # The bulge follows sin(pi s): zero with zero slope at both ends of the path.
        pos = self.start + (self.end - self.start) * s + self.bulge * math.sin(math.pi * s)
        vel = ((self.end - self.start) + self.bulge * math.pi * math.cos(math.pi * s)) * ds
        return pos, vel, False


class ScriptedOperator(Operator):
    """A person teleoperating the master (see the module docstring).

    Args:
        params: the operator's style (sampled per episode by the collector).
        rng: randomness of perception and tremor, seeded by the collector.

    Attributes (read by the teleoperation loop and for inspection):
        phase: index of the current phase in :data:`PHASES`.
        n_pushes: pushes started so far.
        target: the hand's current virtual target ``(3,)`` [m].
        pace: rate of the operator's clock (1 = as planned, 0 = waiting for the slave).
    """

    def __init__(self, params: OperatorParams, rng: np.random.Generator) -> None:
        self.params, self.rng = params, rng
        self.phase = _P["wait"]
        self.n_pushes = 0

    # -- teleoperation-loop interface --------------------------------------------------------------
    def reset(self, tip: np.ndarray, block_pose: np.ndarray, position: BlockPosition) -> None:
        """Start of the episode: the hand holds the stylus still at ``tip``."""
        self.side = position.sign
        # The operator sees which object it is and, on the hard benchmark, how it is turned; the
        # chapter's operators treat the block as square to the push (its ±3° fit in the standoff),
        # which keeps the chapter's recorded demonstrations as they were.
        self.shape, self._turn_aware = position.shape, position.index < 0
        # on the hard benchmark a push is redone while the centre looks short of the goal band's near
        # edge, with 5 mm to spare (the operator's look is noisy)
        self._done_past = pushing.GOAL_PAST - pushing.GOAL_TOLERANCE + 0.005
        self._seen_yaw = 0.0
        self.n_pushes = 0
        self.phase = _P["wait"]
        p = self.params
        self._tremor = np.zeros(3)
        self._clock = 0.0  # the operator's own pace [s]: slows down when the slave lags
        self._time = 0.0  # real time since the reset [s]
        self._relax = math.exp(-pushing.DT / 0.1)  # the lean fades with a 0.1 s time constant
        self._steer = np.zeros(3)  # current steering offset of the aim point [m]
        self._stalled = 0.0  # how long the push stroke has not advanced [s]
        self._push_start, self._push_block_y, self._yielded, self._lean = 0.0, 0.0, False, 0.0
        self._quick = False  # whether the current re-push skips lifting the pen
        self._slave_tip = tip.copy()
        self.target, self.pace = tip.copy(), 1.0
        self._segment = _Segment(tip.copy(), tip.copy(), 0.0, self.params.reaction_time, np.zeros(3))
        self._tremor_decay = math.exp(-pushing.DT / 0.1)  # 0.1 s correlation time
        self._tremor_kick = p.tremor * math.sqrt(1 - self._tremor_decay**2)

    def describe(self) -> dict[str, float]:
        return self.params.as_dict()

    def hand_force(
        self, tip: np.ndarray, tip_velocity: np.ndarray, slave_tip: np.ndarray, block_pose: np.ndarray
    ) -> np.ndarray:
        """Force [N] ``(3,)`` the hand applies to the master's tip during the next period.

        Args:
            tip, tip_velocity: the master's tip position [m] and velocity [m/s] (felt by the hand).
            slave_tip: the slave's tip position [m] (seen).
            block_pose: the block's pose ``(7,)`` (seen, with perception noise at planning moments).
        """
        p = self.params
        self._slave_tip = slave_tip
        planned, target_velocity, done = self._segment.at(self._clock)
        if done:
            self._next(self._clock, planned, block_pose)
            planned, target_velocity, _ = self._segment.at(self._clock)
        target, pace = planned, 1.0
        if self.phase == _P["push"]:
            target = planned + self._steering(block_pose, slave_tip)
            lag = self.side * (slave_tip[1] - target[1])  # how far the slave trails along the stroke
            pace = min(1.0, max(0.0, (p.lag_stop - lag) / (p.lag_stop - p.lag_comfort)))
            self._stalled = self._stalled + pushing.DT if pace < 0.1 else 0.0
            if self._stalled > STALL_TIME:  # the stroke is stuck (pen caught on the block): stop and look
                self._next(self._clock, planned, block_pose)
                target, target_velocity, _ = self._segment.at(self._clock)
        self._clock += pace * pushing.DT
        self._time += pushing.DT
        target_velocity = pace * target_velocity
        self.target, self.pace = target, pace
        self._tremor = self._tremor_decay * self._tremor + self._tremor_kick * self.rng.standard_normal(3)
        force = p.stiffness * (target - tip) + p.damping * (target_velocity - tip_velocity) + self._tremor
        if self.phase == _P["push"]:
            if not self._yielded and self.side * (self._push_block_y - block_pose[1]) > 0.004:
                self._yielded = True
            ramp = min(1.0, (self._time - self._push_start) / p.push_ramp)
            self._lean = p.push_force * ramp if not self._yielded else self._lean * self._relax
            force[1] -= self.side * self._lean
        norm = float(np.linalg.norm(force))
        return force * (p.force_limit / norm) if norm > p.force_limit else force

    # -- decisions ---------------------------------------------------------------------------------
    def _steering(self, block_pose: np.ndarray, slave_tip: np.ndarray) -> np.ndarray:
        """Shift ``(3,)`` [m] of the aim point (along x) that keeps the block from turning away.

        The operator watches where the *slave's* pen touches the face and integrates the
        error to the point it wants: the block's centre, moved by ``side * steer_gain * yaw``
        so that a turning block is turned back. (The slave's pen sits off the master's aim by
        the soft bilateral coupling, so a proportional correction alone would leave it off
        centre and the block would keep turning.)
        """
        p = self.params
        # Pushing towards -side*y at an offset dx from the centre turns the block by -side*dx*F;
        # putting the pen at +side*k*yaw therefore turns it back (a cylinder's turning does not matter).
        yaw = _yaw(block_pose) if self.shape == "box" else 0.0
        turn_back = min(max(self.side * p.steer_gain * yaw, -0.015), 0.015)
        error = np.array([block_pose[0] + p.aim_offset + turn_back - slave_tip[0], 0.0, 0.0])
        self._steer = np.clip(self._steer + pushing.DT / p.steer_lag * error, -0.02, 0.02)
        return self._steer

    def _look(self, block_pose: np.ndarray) -> np.ndarray:
        """Perceived block centre ``(x, y)`` [m] (and its yaw, remembered for :meth:`_behind`)."""
        self._seen_yaw = _yaw(block_pose) if self._turn_aware else 0.0
        return block_pose[:2] + self.rng.normal(0.0, self.params.perception_noise, size=2)

    def _behind(self, block_xy: np.ndarray, height: float) -> np.ndarray:
        """A tip point beside the block's outer face (the side away from the centre line)."""
        p, s = self.params, self.side
        # clear the whole object (a turned box's corners too) before the pen goes down
        face_y = block_xy[1] + s * pushing.lateral_extent(self.shape, self._seen_yaw)
        return np.array([block_xy[0] + p.aim_offset, face_y + s * (pushing.ARM.pen_radius + p.standoff), height])

    def _move(self, phase: str, t: float, start: np.ndarray, end: np.ndarray, duration: float,
              bulge: np.ndarray | None = None) -> None:
        self.phase = _P[phase]
        self._segment = _Segment(start, end, t, max(duration, 0.05), np.zeros(3) if bulge is None else bulge)

    def _next(self, t: float, here: np.ndarray, block_pose: np.ndarray) -> None:
        """The current move is over: choose the next one."""
        p, s = self.params, self.side
        phase = PHASES[self.phase]
        if phase == "wait":
            above = self._behind(self._look(block_pose), p.approach_height)
            distance = float(np.linalg.norm(above - here))
            bulge = np.array([p.bulge_forward, 0.0, p.bulge_height])
            self._move("approach", t, here, above, (0.35 + distance / 0.22) / p.speed, bulge)
        elif phase == "approach":
            ready = here.copy()
            ready[2] = p.push_height
            self._move("descend", t, here, ready, 0.3 / p.speed)
        elif phase in ("descend", "realign"):
            self.n_pushes += 1
            # Aim the block's centre past the line; a hesitant first push stops short of it.
            goal_centre = -s * (p.overshoot + 0.01 * (self.n_pushes - 1))
            if p.hesitant and self.n_pushes == 1:
                goal_centre = s * p.shortfall
            end = here.copy()
            face = pushing.face_offset(self.shape, _yaw(block_pose) if self._turn_aware else 0.0)
            end[1] = goal_centre + s * (face + pushing.ARM.pen_radius)
            stroke = abs(end[1] - here[1])
            self._move("push", t, here, end, (0.15 + stroke / p.push_speed) / p.speed)
            self._steer, self._push_start, self._stalled = np.zeros(3), self._time, 0.0
            self._push_block_y, self._yielded, self._lean = float(block_pose[1]), False, 0.0
        elif phase == "push":
            here = here + self._steer  # keep the steered aim point
            self._move("check", t, here, here, 0.15 / p.speed)
        elif phase == "check":
            block = self._look(block_pose)
            # What "done" looks like: in the chapter, the block clearly across the centre line; on the
            # hard benchmark (told to put it at the goal line), its centre inside the goal band.
            done = -self._done_past if self._turn_aware else -0.004
            if s * block[1] < done or self.n_pushes >= p.max_pushes:
                lifted = here + np.array([-0.015, s * 0.01, 0.0])
                lifted[2] = p.approach_height
                self._move("retract", t, here, lifted, 0.4 / p.speed)
            else:
                yaw = _yaw(block_pose)
                face_y = block[1] + s * pushing.face_offset(self.shape, yaw if self._turn_aware else 0.0)
                pen = self._slave_tip
                turned = abs(yaw) if self.shape == "box" else 0.0
                self._quick = s * (pen[1] - face_y) > 0.0 and turned < math.radians(20) and pen[2] < 0.045
                if self._quick:  # still behind the face: step back and push again
                    away = here + np.array([0.0, s * 0.012, 0.0])
                    self._move("back_off", t, here, away, 0.15 / p.speed)
                else:  # slipped past or onto the block: lift the pen clear, then go round
                    up = here.copy()
                    up[2] = p.approach_height
                    self._move("back_off", t, here, up, 0.25 / p.speed)
        elif phase == "back_off":
            if self._quick:
                ready = self._behind(self._look(block_pose), p.push_height)
                self._move("realign", t, here, ready, 0.25 / p.speed)
            else:
                above = self._behind(self._look(block_pose), p.approach_height)
                distance = float(np.linalg.norm(above - here))
                self._move("approach", t, here, above, (0.2 + distance / 0.22) / p.speed)
        else:  # retract or hold: keep the hand where it is
            self._move("hold", t, here, here, 10.0)
