"""jaxrl-robot: JAX-accelerated, vectorised deep reinforcement learning for robot control.

Pure-functional agents (``make_train(config, env) -> train(key)``), returns and losses,
replay buffers and evaluation helpers, designed to be imported into other JAX code.
"""

__version__ = "0.1.0"

import envs_mjx  # noqa: E402, F401  (first: it imports MJX quietly, before brax does)
from jaxrl_robot import networks, noise, recurrent, replay  # noqa: E402
from jaxrl_robot.agents import a2c, ddpg, ppo, sac, td3  # noqa: E402
from jaxrl_robot.agents.a2c import A2CConfig, A3CConfig  # noqa: E402
from jaxrl_robot.agents.ddpg import DDPGConfig  # noqa: E402
from jaxrl_robot.agents.ppo import PPOConfig  # noqa: E402
from jaxrl_robot.agents.sac import SACConfig  # noqa: E402
from jaxrl_robot.evaluation import run_test_episodes, summarize_episodes, tracking_error_sums  # noqa: E402
from jaxrl_robot.networks import *  # noqa: E402, F403  (networks.__all__, listed once there)
from jaxrl_robot.noise import make_gaussian_noise, make_ou_noise  # noqa: E402
from jaxrl_robot.replay import make_her, make_prioritized_replay, make_uniform_replay  # noqa: E402
from jaxrl_robot.returns import gae, lambda_returns, n_step_returns, td_errors  # noqa: E402
from jaxrl_robot.runs import load_policy  # noqa: E402
from jaxrl_robot.types import RecurrentPolicy, RunningStats, Trainer, Transition  # noqa: E402

__all__ = [
    "__version__",
    # returns (Eq. 4.3, 5.12, 5.14)
    "gae",
    "lambda_returns",
    "n_step_returns",
    "td_errors",
    # networks: the actor, critic, Gaussian-policy and observation-normaliser helpers (networks.__all__)
    *networks.__all__,
    # shared types: a Trainer is what train/run.py drives
    "RecurrentPolicy",
    "RunningStats",
    "Trainer",
    "Transition",
    # a trained policy and its env from a run directory of python -m train.<algo>
    "load_policy",
    # evaluation
    "run_test_episodes",
    "summarize_episodes",
    "tracking_error_sums",
    # PPO (thesis ch. 5): jaxrl_robot.ppo.make_train(PPOConfig(), env)
    "ppo",
    "PPOConfig",
    # A2C / A3C (thesis §4.1): jaxrl_robot.a2c.make_train(A2CConfig() or A3CConfig(), env)
    "a2c",
    "A2CConfig",
    "A3CConfig",
    # DDPG (thesis ch. 3): jaxrl_robot.ddpg.make_train(DDPGConfig(her="future"), env)
    "ddpg",
    "DDPGConfig",
    # TD3 (thesis §6.2): jaxrl_robot.td3.make_train(jaxrl_robot.td3.td3_config(), env)
    "td3",
    # SAC: jaxrl_robot.sac.make_train(SACConfig(schedule="steps"), env)
    "sac",
    "SACConfig",
    # replay memories (§3.1-3.3) and exploration noise (Eq. 3.8); more in jaxrl_robot.replay / .noise
    "replay",
    "make_uniform_replay",
    "make_prioritized_replay",
    "make_her",
    "noise",
    "make_ou_noise",
    "make_gaussian_noise",
    # recurrent networks, sequence unrolls and the start-state table (§5.7)
    "recurrent",
]
