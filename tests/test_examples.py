"""``examples/``: the scripts a user copies run and learn on a small budget."""

import importlib.util
import os

import jax
import numpy as np

from jaxrl_robot.agents.ppo import make_trainer
from jaxrl_robot.evaluation import run_test_episodes
from tests.subproc import ROOT


def _load(name: str):
    spec = importlib.util.spec_from_file_location(name, os.path.join(ROOT, "examples", f"{name}.py"))
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_ppo_on_a_user_written_brax_env_learns_with_seeds_vmapped():
    ex = _load("ppo_custom_env")
    env = ex.PointReach()
    trainer = make_trainer(ex.config(60_000), env)
    policy = trainer.policy(trainer.init(jax.random.PRNGKey(0)))
    untrained = run_test_episodes(jax.random.PRNGKey(1), env, policy, 100, episode_length=50)
    assert float(np.mean(untrained["success"])) < 0.3
    out = ex.main(["--seeds", "2", "--total-steps", "60000"])
    assert out["success"].shape == (2,) and np.all(out["success"] >= 0.8), out["success"]
    assert out["returns"].shape[0] == 2 and np.all(out["returns"][:, -1] > out["returns"][:, 0])
