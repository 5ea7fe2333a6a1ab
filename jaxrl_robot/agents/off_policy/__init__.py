"""The off-policy actor-critic family (thesis ch. 3-4, §6.2): DDPG, TD3 and SAC share it by import.

* :class:`OffPolicyConfig` (:mod:`.config`) — schedules, lanes, replay, PER, HER, exploration noise,
  targets, imitation and distributed workers; a member's config adds only its own fields.
* :mod:`.acting` — lanes exploring (``μ(s) + ω`` or a stochastic policy's draw) in whole episodes or
  continuous steps, HER relabelling, the rows gathered for the replay.
* :mod:`.learner` — the update loop around a member's gradient steps (:class:`Update`): sampling, PER,
  policy delay, the imitation stage, a named :class:`LearnerState`; synchronous workers (:func:`worker_shards`).
* :mod:`.member` — what a member supplies (:class:`Member`); :mod:`.trainer` — :class:`OffPolicyState`,
  :func:`setup`, :func:`make_trainer` (single learner);
  :mod:`.distributed` — synchronous and collecting workers (thesis §4.2); :mod:`.imitation` — the
  expert's pre-training stage (§6.1.2).
* :mod:`.losses` (TD target, critic and actor losses, clipped double Q, soft updates) and :mod:`.networks`
  (the critic ``Q(s, a)``, one or twin).

A member (``jaxrl_robot.agents.ddpg``, ``jaxrl_robot.agents.sac``) supplies a :class:`Member`: its policy,
its initial networks and its :class:`Update`.
"""

from jaxrl_robot.agents.off_policy.config import ANCHORS, NOISES, PRETRAINS, SCHEDULES, OffPolicyConfig
from jaxrl_robot.agents.off_policy.distributed import Collectors, DistributedState
from jaxrl_robot.agents.off_policy.learner import SINGLE, Learner, LearnerState, Update, Workers, worker_shards
from jaxrl_robot.agents.off_policy.member import Member
from jaxrl_robot.agents.off_policy.trainer import GOAL_API, OffPolicyState, make_trainer

__all__ = [
    "ANCHORS",
    "GOAL_API",
    "NOISES",
    "PRETRAINS",
    "SCHEDULES",
    "SINGLE",
    "Collectors",
    "DistributedState",
    "Learner",
    "LearnerState",
    "Member",
    "OffPolicyConfig",
    "OffPolicyState",
    "Update",
    "Workers",
    "make_trainer",
    "worker_shards",
]
