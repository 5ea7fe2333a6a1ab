"""What a ``python -m train.<algo>`` process spends outside its run: MuJoCo Warp is imported only when the
command asks for it (``train/__init__.py``, ``envs_mjx.xla.WARP_ENV``), and the process leaves as soon as its
files are written (``train.cli.exit_process``)."""

import json
import subprocess
import sys

import train
from tests.subproc import ROOT, cpu_env


def test_a_command_asks_for_warp_by_impl_playground_or_the_run_it_resumes(tmp_path):
    asks = train._asks_for_warp
    assert not asks(["--env", "arm7", "--total-steps", "64"])
    assert asks(["--env", "arm7", "--env-config", "mode=pd", "impl=warp"])
    assert asks(["--env", "playground:CartpoleBalance"])
    for env_config, wanted in ((["impl=warp"], True), (["mode=pd"], False)):
        run = tmp_path / f"run-{wanted}"
        run.mkdir()
        (run / "config.json").write_text(json.dumps({"args": {"env": "arm7", "env_config": env_config}}))
        assert asks(["--resume", str(run)]) is wanted
    assert asks(["--resume", str(tmp_path / "missing")])  # unreadable: Warp stays available


_PROBE = """
import os, sys
import envs_mjx
from envs_mjx.config import ConfigError
print("warp imported:", "mujoco.mjx.third_party.mujoco_warp" in sys.modules)
try:
    envs_mjx.make("arm7", mode="pd", impl="warp")
except ConfigError as e:
    print("error:", e)
sys.stdout.flush()
from train.cli import exit_process
exit_process(3)
"""


def test_without_warp_the_import_leaves_it_out_and_impl_warp_says_why():
    out = subprocess.run([sys.executable, "-c", _PROBE], cwd=ROOT, env=cpu_env(JAXRL_ROBOT_WARP="off"),
                         capture_output=True, text=True, timeout=300)  # fmt: skip
    assert out.returncode == 3, out.stderr[-2000:]  # exit_process keeps the code
    lines = out.stdout.strip().splitlines()
    assert lines[0] == "warp imported: False"
    assert lines[1] == "error: impl='warp' needs MuJoCo Warp, which this process left out (JAXRL_ROBOT_WARP=off)"
    assert "Failed to import" not in out.stdout + out.stderr
