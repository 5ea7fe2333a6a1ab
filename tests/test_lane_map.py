"""Which lane map a run takes: one device or an env stepping no MJX physics ``shard_map``; MJX physics on several
devices ``vmap``; ``JAXRL_LANE_MAP`` over both. The envs say whether they step MJX physics, through wrappers."""

import json
import subprocess
import sys

import numpy as np
import pytest

import envs_mjx
from envs_mjx.base import steps_mjx_physics, wrap_for_training
from jaxrl_robot import parallel
from tests.subproc import cpu_env


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


EMPTY_CONSTANT_SCRIPT = r"""
import json, re
import jax, jax.numpy as jnp, numpy as np
from jaxrl_robot import parallel

mesh = parallel.lane_mesh(2)
empty = np.zeros((1, 0), np.float32)  # as MJX's models and data hold dozens


def fn(x):  # [lanes, 4] -> ([lanes, 4], [])
    e = jnp.asarray(empty)
    y = jnp.concatenate([x, jnp.broadcast_to(e, (x.shape[0], 0))], 1) * 2.0 + jnp.sum(e)
    return y, parallel.psum(jnp.sum(x))


specs = (parallel.P(parallel.LANES), (parallel.P(parallel.LANES), parallel.P()))
ours = jax.jit(parallel.shard_lanes(fn, mesh, *specs, impl="shard_map"))
plain = jax.jit(jax.shard_map(fn, mesh=mesh, in_specs=specs[0], out_specs=specs[1], check_vma=False))
x = jnp.arange(16.0).reshape(4, 4)


def empties(f):  # zero-size constants in the lowered program
    return len(re.findall(r"constant dense<> : tensor<[0-9x]*0[x0-9]*xf32>", f.lower(x).as_text()))


(y1, s1), (y2, s2) = ours(x), plain(x)
print(json.dumps({"ours": empties(ours), "plain": empties(plain), "y": y1.tolist(),
                  "same": bool(jnp.array_equal(y1, y2)), "sum": float(s1), "plain_sum": float(s2)}))
"""


def test_shard_map_over_several_devices_holds_no_zero_size_constant():
    """XLA:GPU dies compiling a shard_map program over several GPUs that holds a zero-size constant (2 x H200,
    benchmarks/results/gpu-nvidia_h200x2-multigpu_repro-empty.md): the lane map makes such arrays inside the program,
    with the same results as jax.shard_map of the function as it is (which keeps the constant)."""
    out = subprocess.run([sys.executable, "-c", EMPTY_CONSTANT_SCRIPT], env=cpu_env(2), capture_output=True,
                         text=True, timeout=300, check=True).stdout  # fmt: skip
    r = json.loads(out.strip().splitlines()[-1])
    assert r["plain"] == 1 and r["ours"] == 0
    assert r["same"] and r["sum"] == r["plain_sum"] == sum(range(16))
    assert r["y"][1] == [8.0, 10.0, 12.0, 14.0]  # 2 x the second lane's row
