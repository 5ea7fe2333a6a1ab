"""MuJoCo Playground's envs in the library: the adapter and the training wrappers against Playground's own
``reset`` / ``step`` (an oracle: the same keys and actions), PPO's ``make_train`` on a 2-D ``dm_control_suite``
task as ``registry.load`` gives it (``tests/cli/test_playground_cli.py``: ``train.ppo`` on the 1-D
``CartpoleBalance``), TD3 on a 1-D one, a dict observation, the one-line errors, and Playground's own
settings through the presets' and the benchmark's conversions.
"""

from __future__ import annotations

import math
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.base import State as BraxState
from mujoco_playground import State, registry

from envs_mjx import playground
from envs_mjx.base import ActionShapeError, AutoResetWrapper, EpisodeWrapper
from jaxrl_robot.agents import ddpg, ppo
from train.envs import make_env
from train.td3 import TD3_SETTINGS


class Compiled:
    """A Playground env whose ``reset`` and ``step`` are compiled once: the oracle's paths below call the same
    two programs, Playground's directly and ours through the adapter and the wrappers (run eagerly)."""

    def __init__(self, env):
        self.env, self._config, self.action_size = env, env._config, env.action_size
        self.reset, self.step = jax.jit(env.reset), jax.jit(env.step)


@pytest.fixture(scope="module")
def cartpole():
    return Compiled(registry.load("CartpoleBalance", config_overrides={"impl": "jax"}))


def test_adapter_steps_as_playground_s_own_env(cartpole):
    """Playground's reset and 5 steps of random actions (some outside [-1, 1], which go to the env as given)
    against the same keys and actions through :class:`PlaygroundEnv`: equal observations, rewards, dones and
    physics; brax states with Playground's info and metrics; the action's shape checked."""
    key = jax.random.PRNGKey(3)
    actions = jax.random.uniform(jax.random.PRNGKey(4), (5, 1), minval=-1.5, maxval=1.5)
    theirs = [cartpole.reset(key)]
    for a in actions:
        theirs.append(cartpole.step(theirs[-1], a))

    env = playground.PlaygroundEnv(cartpole, name="playground:CartpoleBalance")
    assert (env.observation_size, env.action_size, env.episode_length) == (5, 1, 1000)
    ours = [env.reset(key)]
    for a in actions:
        ours.append(env.step(ours[-1], a))
    for t, (s, o) in enumerate(zip(theirs, ours, strict=True)):
        assert isinstance(o, BraxState) and not env.dict_obs
        np.testing.assert_array_equal(o.obs, s.obs, err_msg=f"step {t}")
        np.testing.assert_array_equal(o.reward, s.reward, err_msg=f"step {t}")
        np.testing.assert_array_equal(o.done, s.done, err_msg=f"step {t}")
        np.testing.assert_array_equal(o.pipeline_state.qpos, s.data.qpos, err_msg=f"step {t}")
        assert set(o.info) == set(s.info) == {"rng", "time_out"} and set(o.metrics) == set(s.metrics)
    assert float(theirs[-1].reward) > 0.5  # upright: the comparison is of real rewards
    shape = r"playground:CartpoleBalance.step: action has shape \(2,\), expected \(1,\)"
    with pytest.raises(ActionShapeError, match=shape):
        env.step(ours[0], jnp.zeros(2))


@pytest.mark.parametrize("through_adapter", [True, False], ids=["adapter", "playground-state"])
def test_training_wrappers_reset_a_playground_episode_as_playground_does(cartpole, through_adapter):
    """A time limit of 3 steps and the auto-reset over the adapter, and over Playground's env as it is (its
    state's physics in ``data``, read and replaced through ``physics_of`` / ``with_physics``): the first 3
    steps are Playground's; the third ends the episode (truncation) keeping its last observation in
    ``final_obs``; the 4th starts from Playground's reset with the key the wrapper drew, then steps as it does."""
    env = playground.PlaygroundEnv(cartpole) if through_adapter else cartpole
    wrapped = AutoResetWrapper(EpisodeWrapper(env, 3))
    key = jax.random.PRNGKey(5)
    actions = jnp.array([[0.3], [-0.7], [1.0], [0.2], [-0.4]])
    state = wrapped.reset(key)
    _, first = jax.random.split(key)
    theirs = cartpole.reset(first)
    for t, a in enumerate(actions):
        reset_key = state.info["reset_key"]
        state = wrapped.step(state, a)
        theirs = cartpole.step(theirs, a)
        np.testing.assert_array_equal(state.reward, theirs.reward, err_msg=f"step {t}")
        if t == 2:  # the limit: done, truncated, the finished episode's observation kept
            assert float(state.done) == 1.0 and float(state.info["truncation"]) == 1.0
            np.testing.assert_array_equal(state.info["final_obs"], theirs.obs)
            theirs = cartpole.reset(jax.random.split(reset_key)[1])
        np.testing.assert_array_equal(state.obs, theirs.obs, err_msg=f"step {t}")
        physics = state.pipeline_state if through_adapter else state.data
        np.testing.assert_array_equal(physics.qvel, theirs.data.qvel, err_msg=f"step {t}")


def test_ppo_make_train_trains_a_playground_env_as_registry_loads_it():
    """``make_train`` of a default :class:`PPOConfig` (its budget set, and a fresh reset per finished lane:
    the reset pool's program compiles 4 copies of the physics, this one 3) on ``PointMass`` (2-D actions) as
    ``registry.load`` returns it. 4 lanes of 64 steps with Playground's time limit set to 16 steps end 16
    episodes; the losses stay finite and every iteration moves the policy (KL > 0)."""
    env = registry.load("PointMass", config_overrides={"impl": "jax", "episode_length": 16})
    assert (env.action_size, env.observation_size) == (2, 4)
    config = ppo.PPOConfig(total_steps=256, reset_refresh=1.0)  # 4 lanes x 8 steps per iteration: 8 iterations
    _, metrics = jax.jit(ppo.make_train(config, env))(jax.random.PRNGKey(0))
    assert metrics["episodes"].shape == (config.total_iterations,) and float(jnp.sum(metrics["episodes"])) == 16
    for k in ("actor_loss", "critic_loss", "episode_return"):
        values = np.asarray(metrics[k])
        assert np.all(np.isfinite(values[~np.isnan(values)])) and np.any(np.isfinite(values)), k
    assert np.all(np.asarray(metrics["kl"]) > 0)


def test_td3_trains_a_playground_env():
    """TD3 (DDPG with ``train.td3.TD3_SETTINGS``) on ``PendulumSwingup`` loaded by ``envs_mjx.playground.load``:
    4 lanes x 64 steps of 16-step episodes end 16 episodes, learning from step 32 on; the losses are finite."""
    env = playground.load("PendulumSwingup", episode_length=16)
    config = ddpg.DDPGConfig(
        schedule="steps", total_steps=256, num_envs=4, unroll_length=4, updates_per_iteration=2, learning_starts=32,
        batch_size=16, buffer_size=256, actor_hidden=(32,), critic_hidden=(32,), **TD3_SETTINGS,
    )  # fmt: skip
    _, metrics = jax.jit(ddpg.make_train(config, env))(jax.random.PRNGKey(1))
    assert float(jnp.sum(metrics["episodes"])) == 16
    for k in ("critic_loss", "actor_loss"):
        assert np.all(np.isfinite(np.asarray(metrics[k]))), k


class DictObservationEnv:
    """A Playground-style env (not a brax ``Env``) with a dict observation.

    Its state is Playground's ``State``, the physics in ``data`` (a point's position ``[2]``). A point in
    ``[-1, 1]^2`` is moved by ``0.2 · clip(action, -1, 1)`` toward a goal; observation ``"state"``: position and
    goal ``[4]`` (the policy's), ``"privileged_state"``: those and the distance ``[5]``, from which ``step``
    reads the goal back (as some of Playground's envs read ``state.obs`` in ``step``). Reward: the decrease of
    the distance; done within 0.1. ``step`` returns a new ``info`` of its own keys only.
    """

    action_size = 2

    @staticmethod
    def _obs(pos: jax.Array, goal: jax.Array) -> dict[str, jax.Array]:
        state = jnp.concatenate([pos, goal])
        return {"state": state, "privileged_state": jnp.append(state, jnp.linalg.norm(goal - pos))}

    def reset(self, rng: jax.Array) -> State:
        pos, goal = jax.random.uniform(rng, (2, 2), minval=-1.0, maxval=1.0)
        zero = jnp.zeros(())
        return State(data=pos, obs=self._obs(pos, goal), reward=zero, done=zero, metrics={"success": zero},
                     info={"moves": jnp.zeros((), jnp.int32)})  # fmt: skip

    def step(self, state: State, action: jax.Array) -> State:
        goal, before = state.obs["privileged_state"][2:4], state.obs["privileged_state"][4]
        pos = jnp.clip(state.data + 0.2 * jnp.clip(action, -1.0, 1.0), -1.0, 1.0)
        obs = self._obs(pos, goal)
        success = (obs["privileged_state"][4] < 0.1).astype(jnp.float32)
        return State(data=pos, obs=obs, reward=before - obs["privileged_state"][4], done=success,
                     metrics={"success": success}, info={"moves": state.info["moves"] + 1})  # fmt: skip


def test_a_dict_observation_gives_the_policy_its_state_entry_and_the_env_its_whole_dict():
    """``adapt`` takes the env as it is: the policy's observation is the ``"state"`` entry ``[4]``, the env's
    ``step`` gets the whole dict back (it reads the goal from ``"privileged_state"``), rewards as the env's own
    step gives them; ``obs_key`` picks another entry, an unknown key is a one-line error listing the valid
    ones; PPO's default config trains on it through the training wrappers (whose info keys the env drops)."""
    raw = DictObservationEnv()
    env = playground.adapt(raw)
    assert isinstance(env, playground.PlaygroundEnv) and env.dict_obs and env.observation_size == 4
    assert playground.adapt(env) is env and env.episode_length is None
    key, action = jax.random.PRNGKey(2), jnp.array([0.5, -1.0])
    theirs, ours = raw.step(raw.reset(key), action), env.step(env.reset(key), action)
    np.testing.assert_array_equal(ours.obs, theirs.obs["state"])
    whole = ours.info[playground.FULL_OBS_KEY]
    np.testing.assert_array_equal(whole["privileged_state"], theirs.obs["privileged_state"])
    np.testing.assert_array_equal(ours.reward, theirs.reward)
    assert float(ours.reward) != 0.0 and int(ours.info["moves"]) == 1
    assert playground.PlaygroundEnv(raw, obs_key="privileged_state").observation_size == 5
    with pytest.raises(ValueError, match=r"^DictObservationEnv: obs_key='pixels' is not a key of its observation; "
                                         r"valid: privileged_state, state$"):  # fmt: skip
        playground.PlaygroundEnv(raw, obs_key="pixels")

    config = ppo.PPOConfig(total_steps=320, episode_length=10)
    _, metrics = jax.jit(ppo.make_train(config, raw))(jax.random.PRNGKey(0))
    assert float(jnp.sum(metrics["episodes"])) >= 32  # 4 lanes of 80 steps: at least 8 episodes each
    assert np.all(np.isfinite(np.asarray(metrics["critic_loss"])))


def test_unknown_names_settings_and_a_missing_package_are_one_line_errors(monkeypatch):
    with pytest.raises(ValueError) as e:
        playground.load("CartpoleBalancee")
    message = str(e.value)
    assert message.startswith("unknown MuJoCo Playground environment 'CartpoleBalancee'; valid names")
    assert "\n" not in message and all(n in message for n in registry.dm_control_suite.ALL_ENVS)
    with pytest.raises(ValueError, match=r"^playground:CartpoleBalance: 'epsiode_length' is not a setting of its "
                                         r"config; valid: action_repeat, ctrl_dt, episode_length, impl, "):  # fmt: skip
        playground.load("CartpoleBalance", epsiode_length=50)
    with pytest.raises(ValueError, match=r"^playground:CartpoleBalance with \{'impl': 'jax', 'episode_length': "
                                         r"'long'\}: Could not override field 'episode_length'"):  # fmt: skip
        make_env("playground:CartpoleBalance", {"episode_length": "long"})

    monkeypatch.setitem(sys.modules, "mujoco_playground", None)  # as if it were not installed
    with pytest.raises(playground.PlaygroundMissingError) as e:
        make_env("playground:CartpoleBalance", {})
    assert str(e.value) == '--env playground:CartpoleBalance needs MuJoCo Playground: pip install -e ".[playground]"'
    assert isinstance(e.value, ImportError) and isinstance(e.value, ValueError)


def test_every_registered_dm_control_name_is_valid_and_the_default_impl_is_jax():
    """The names ``--env playground:`` takes are the registry's; ``load`` asks for MJX's JAX backend unless told."""
    assert set(registry.dm_control_suite.ALL_ENVS) <= set(playground.names())
    assert playground.suite_of("CheetahRun") == "dm_control_suite" and playground.suite_of("Nope") is None
    env = playground.load("playground:PendulumSwingup")
    assert env.env.mjx_model.impl.value == "jax" and env.name == "playground:PendulumSwingup"
    assert math.isclose(env.dt, 0.02) and env.episode_length == 1000  # the wrapped env's attributes


def test_presets_and_the_benchmark_convert_playground_s_own_rows_by_hand():
    """Playground's ``brax_ppo_config("CartpoleBalance")`` (2048 envs, batch 1024, 32 mini-batches, unrolls of 30,
    16 passes, 10 resets per evaluation) through the code that converts brax's rows: per lane 1024 · 32 / 2048
    = 16 unrolls of 30 = 480 steps, brax's update on mini-batches of 1024 unrolls (30 720 steps), 16 · 32 = 512
    steps each; the env's own time limit. brax trains ``num_resets_per_eval`` rounds per evaluation: 60 M over 9
    epochs of 10 rounds of 983 040 steps is 0.68 -> 1, so 9 · 10 · 983 040 env steps, which ours then makes too.
    The SAC row under TD3's own settings: 128 lanes, one update of 256 per lane step, the row's memory."""
    from benchmarks import brax_tasks
    from train import presets
    from train.presets import on_policy as presets_on_policy

    row = presets.playground_row("playground:CartpoleBalance")
    c = presets.playground_ppo_config("playground:CartpoleBalance", 1)
    assert c == presets.ppo_config_of_row(row, 1, True)
    assert (c.num_envs, c.unroll_length, c.minibatch_size, c.actor_updates) == (2048, 480, 30720, 512)
    assert (c.advantage_segment, c.total_steps, c.gamma, c.reward_scale) == (30, 60_000_000, 0.995, 10)
    assert (c.actor_lr, c.entropy_coef, c.episode_length, c.tanh_actions) == (1e-3, 1e-2, 1000, True)
    assert presets_on_policy._ppo_base_preset("auto", "playground:CartpoleBalance", 250, 1).episode_length == 250
    assert brax_tasks.brax_ppo_steps(row, 60_000_000) == 9 * 10 * 983_040
    small = brax_tasks.brax_row("playground:CartpoleBalance", 16)  # the CPU check's 16 envs: batch 8
    assert brax_tasks.brax_ppo_steps(small, 20_000, 2) == 10 * 8 * 32 * 30
    ours = brax_tasks.our_config("ppo", "playground:CartpoleBalance", 1, small, 76_800)
    assert (ours.num_envs, ours.unroll_length, ours.advantage_segment) == (16, 480, 30)

    td3 = presets.ddpg_preset("playground", "playground:CheetahRun", 500, None).replace(**TD3_SETTINGS)
    assert (td3.num_envs, td3.updates_per_iteration, td3.batch_size, td3.actor_lr) == (128, 128, 256, 3e-4)
    assert (td3.buffer_size, td3.learning_starts, td3.total_steps, td3.episode_length) == (4_194_304, 8192, 10**7, 500)
    for algo, preset in (("ppo", "playground"), ("ddpg", "playground"), ("td3", "playground"), ("a2c", "cpu")):
        assert presets.resolve_preset("auto", "playground:WalkerWalk", algo) in (preset, "fast"), algo
    assert presets.resolve_preset("cpu", "playground:WalkerWalk") == "cpu"


def test_a_default_ppo_config_trains_a_brax_env_that_sets_no_time_limit():
    """brax's envs have no ``episode_length``: the wrappers then take brax's own default of 1000 steps
    (``envs_mjx.base.DEFAULT_EPISODE_LENGTH``), so ``make_train`` needs nothing beyond the budget."""
    from brax import envs as brax_envs

    from envs_mjx.base import DEFAULT_EPISODE_LENGTH, default_episode_length, wrap_for_training

    env = brax_envs.get_environment("fast")
    assert not hasattr(env, "episode_length") and default_episode_length(env) == DEFAULT_EPISODE_LENGTH == 1000
    assert wrap_for_training(env).env.env.episode_length == 1000  # VmapWrapper(AutoResetWrapper(EpisodeWrapper))
    _, metrics = jax.jit(ppo.make_train(ppo.PPOConfig(total_steps=64), env))(jax.random.PRNGKey(0))
    assert np.all(np.isfinite(np.asarray(metrics["critic_loss"]))) and float(jnp.sum(metrics["episodes"])) == 0
