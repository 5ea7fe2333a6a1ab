"""``jaxrl_robot.plots``: the training curves a run draws, and pyplot imported off the main thread."""

import math
import os
import subprocess
import sys

from PIL import Image

from jaxrl_robot.plots import plot_training_curves

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def test_training_curves_draw_each_logged_metric_and_skip_missing_or_empty_ones(tmp_path):
    rows = [{"env_steps": 100 * i, "episode_return": float(i), "success": math.nan} for i in range(5)]
    written = plot_training_curves(rows, str(tmp_path))
    assert [os.path.basename(p) for p in written] == ["episode_reward.png"]  # success all NaN, no extra_distance
    with Image.open(written[0]) as im:
        assert im.size == (600, 350)  # figsize (6, 3.5) at 100 dpi
    assert plot_training_curves([], str(tmp_path)) == []


_PROBE = """
import importlib.util, sys
spec = importlib.util.spec_from_file_location("plots", sys.argv[1])
plots = importlib.util.module_from_spec(spec)
spec.loader.exec_module(plots)
assert "matplotlib.pyplot" not in sys.modules
thread = plots.import_in_background()
thread.join(60)
import matplotlib
print(thread.name, thread.daemon, "matplotlib.pyplot" in sys.modules, matplotlib.get_backend().lower())
"""


def test_import_in_background_imports_pyplot_on_agg_in_a_daemon_thread():
    path = os.path.join(ROOT, "jaxrl_robot", "plots.py")  # the module alone: no JAX in this process
    env = {k: v for k, v in os.environ.items() if k != "MPLBACKEND"}
    out = subprocess.run([sys.executable, "-c", _PROBE, path], env=env, capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == ["import-pyplot", "True", "True", "agg"]
