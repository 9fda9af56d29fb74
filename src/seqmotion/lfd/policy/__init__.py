"""The pushing policy room: the networks and their typed configs (:mod:`.networks`), the per-step
interface (:mod:`.interface`: :class:`Observation`, :class:`Controller`) and the policy itself
(:mod:`.policy`: :class:`PushingPolicy` with ``reset()`` / ``select_action(observation)``).

Nothing here steps a simulation; :mod:`seqmotion.lfd.rollout` does.
"""
