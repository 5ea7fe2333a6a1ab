"""Replay memories as bundles of pure functions (thesis §3.1–3.3).

* :func:`make_uniform_replay` — ring buffer with uniform sampling.
* :mod:`sum_tree` — array-backed sum-tree (batched set, stratified sampling, Fig. 3.2).
* :mod:`block_tree` — two-level sum-tree, one fused kernel per sample and per update on a GPU.
* :func:`make_prioritized_replay` — prioritised replay (Eq. 3.9–3.10); NaN / inf TD errors and
  out-of-range indices cannot poison it (:func:`count_nonfinite` counts the replaced errors).
* :func:`make_her` — hindsight relabelling with ``final`` / ``future`` / ``random`` goals.

State is a ``flax.struct.dataclass`` with static sizes outside the pytree; nothing is jitted
here — jit the caller and donate the buffer state.
"""

from jaxrl_robot.replay import block_tree, sum_tree
from jaxrl_robot.replay.her import STRATEGIES, GoalEnv, GoalEpisode, Her, flatten_copies, make_her, num_copies
from jaxrl_robot.replay.prioritized import (
    PrioritizedReplay,
    PrioritizedReplayState,
    PrioritizedSample,
    count_nonfinite,
    importance_weights,
    make_prioritized_replay,
)
from jaxrl_robot.replay.uniform import UniformReplay, UniformReplayState, UniformSample, make_uniform_replay
from jaxrl_robot.types import Transition

__all__ = [
    "STRATEGIES",
    "GoalEnv",
    "GoalEpisode",
    "Her",
    "PrioritizedReplay",
    "PrioritizedReplayState",
    "PrioritizedSample",
    "Transition",
    "UniformReplay",
    "UniformReplayState",
    "UniformSample",
    "block_tree",
    "count_nonfinite",
    "flatten_copies",
    "importance_weights",
    "make_her",
    "make_prioritized_replay",
    "make_uniform_replay",
    "num_copies",
    "sum_tree",
]
