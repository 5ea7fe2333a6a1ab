"""Which lane map a run takes: one device or an env stepping no MJX physics ``shard_map``; MJX physics on several
devices ``vmap``; ``JAXRL_LANE_MAP`` over both. The envs say whether they step MJX physics, through wrappers."""

import numpy as np
import pytest

import envs_mjx
from envs_mjx.base import steps_mjx_physics, wrap_for_training
from jaxrl_robot import parallel


class TwoDevices:
    """A stand-in for a mesh of two devices (``lane_map_impl`` reads only the device count)."""

    devices = np.empty(2, dtype=object)


def test_the_lane_map_follows_the_mesh_the_env_and_the_override(monkeypatch):
    monkeypatch.delenv(parallel.IMPL_ENV, raising=False)
    one = parallel.lane_mesh(1)
    assert parallel.lane_map_impl(one) == "shard_map" and parallel.lane_map_impl(one, mjx_physics=False) == "shard_map"
    assert parallel.lane_map_impl(TwoDevices()) == "vmap"
    assert parallel.lane_map_impl(TwoDevices(), mjx_physics=False) == "shard_map"
    assert parallel.lane_map_impl(TwoDevices(), "vmap", mjx_physics=False) == "vmap"
    monkeypatch.setenv(parallel.IMPL_ENV, "vmap")
    assert parallel.lane_map_impl(TwoDevices(), mjx_physics=False) == "vmap"
    monkeypatch.setenv(parallel.IMPL_ENV, "pmap")
    with pytest.raises(ValueError, match="JAXRL_LANE_MAP='pmap' is not a lane-map implementation; valid: shard_map"):
        parallel.lane_map_impl(one)


@pytest.mark.parametrize(
    "name, config, physics",
    [("arm7", {"mode": "pd"}, True), ("arm7", {"mode": "kinematic"}, False), ("unicycle", {"mode": "dynamic"}, True),
     ("unicycle", {"mode": "kinematic"}, False), ("scara", {}, True), ("racecar", {}, False)],
)  # fmt: skip
def test_envs_say_whether_they_step_mjx_physics_through_the_training_wrappers(name, config, physics):
    env = envs_mjx.make(name, **config)
    assert env.steps_mjx_physics is physics
    assert steps_mjx_physics(wrap_for_training(env, episode_length=5)) is physics


def test_an_env_that_does_not_say_is_taken_to_step_mjx_physics():
    assert steps_mjx_physics(object()) is True
