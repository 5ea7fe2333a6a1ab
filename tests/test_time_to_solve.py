"""``python -m benchmarks.time_to_solve``: its figures are those of the runs' ``evals.csv`` and ``eval.json``, one
process per device count (fake CPU devices); the criteria and the summary by hand."""

import glob
import json
import os

import pytest

from benchmarks import time_to_solve as tts
from benchmarks.time_to_solve_report import spread
from benchmarks.tracking_report import GOAL

TINY = ["--episode-length", "16", "--num-envs", "4", "--unroll-length", "8", "--minibatch-size", "16",
        "--actor-hidden", "8", "--critic-hidden", "8", "--actor-updates", "2", "--critic-updates", "2",
        "--chunks", "1"]  # fmt: skip


def test_figures_come_from_each_process_s_evals_csv(tmp_path, monkeypatch, capsys):
    """A tiny task (PPO on brax's ``fast`` env, one chunk, mean episode length ≥ 0 as its criterion, so that the
    first evaluation meets it) on 1 and 2 fake CPU devices, one seed each, in fresh processes."""
    monkeypatch.setenv("JAX_PLATFORMS", "cpu")  # fake CPU devices on any host
    monkeypatch.setitem(tts.TASKS, "tiny", tts.Task("tiny", "ppo", "brax:fast", (), "mean_length", "mean length"))
    argv = ["--tasks", "tiny", "--devices", "1", "2", "--seeds", "1", "--first-seed", "7", "--evals", "1",
            "--eval-episodes", "2", "--total-steps", "64", "--target", "0", "--preset", "cpu",
            "--compile-cache", os.environ["JAX_COMPILATION_CACHE_DIR"], "--runs", str(tmp_path / "runs"),
            "--out", str(tmp_path / "results"), "--allow-dirty", "--", *TINY]  # fmt: skip
    result = tts.main(argv)
    (task,) = result["tasks"]
    assert [(r["devices"], r["seed"]) for r in task["runs"]] == [(1, 7), (2, 7)]
    for record, summary in zip(task["runs"], task["summary"], strict=True):
        n = record["devices"]
        assert "error" not in record, record.get("error")
        (run_dir,) = glob.glob(str(tmp_path / "runs" / f"tiny-d{n}-s7" / "ppo-brax_fast-*"))
        with open(os.path.join(run_dir, "config.json")) as f:
            assert json.load(f)["devices"] == n  # the process saw n devices
        with open(os.path.join(run_dir, "eval.json")) as f:
            final = json.load(f)
        rows = tts.read_rows(run_dir)
        met = next(r for r in rows if float(r["mean_length"]) >= 0.0)
        assert record["train_to_target_s"] == float(met["train_wall_s"]) > 0
        assert record["total_to_target_s"] == float(met["process_s"]) > record["train_to_target_s"]
        assert record["startup_s"] == pytest.approx(final["startup_s"], abs=1e-3)
        assert record["first_chunk_s"] == pytest.approx(final["compile_s"], abs=1e-3)
        assert record["final"] == final["mean_length"] == 16.0
        assert record["finished"] and not record["stopped_at_target"]
        assert record["process_wall_s"] > record["total_to_target_s"]
        assert summary["devices"] == n and summary["reached"] == summary["seeds"] == 1
        assert summary["train_to_target_s"]["values"] == [record["train_to_target_s"]]
    stem = str(tmp_path / "results" / f"cpu-{os.cpu_count()}core-time_to_solve")
    with open(stem + ".json") as f:
        saved = json.load(f)
    assert saved["tasks"][0]["runs"][1]["train_to_target_s"] == task["runs"][1]["train_to_target_s"]
    assert saved["provenance"]["seeds"]["ids"] == [7] and saved["device"]["fake_devices"]
    assert os.path.isfile(stem + "-figures/tiny.png")
    text = open(stem + ".md").read()
    assert f"| 1 | 1 / 1 | {task['runs'][0]['process_wall_s']:.1f} |" in text and "## Provenance" in text
    capsys.readouterr()


def test_criteria_and_spread_by_hand():
    sine = tts.TASKS["unicycle_sine"]
    assert sine.goal == GOAL["sine"]
    row = {"x": "0.65", "y": "0.43", "theta": "0.94"}  # half the goal on x and y, twice it on θ
    assert sine.value(row) == pytest.approx(2.0) and not sine.met(sine.value(row), 0.95)
    assert sine.met(sine.value({"x": "1.3", "y": "0.1", "theta": "0.2"}), 0.95)
    arm = tts.TASKS["arm7"]
    assert arm.value({"success_5cm": "0.96", "success_rate": "0.5"}) == 0.96
    assert arm.value({"success_5cm": "", "success_rate": "0.5"}) == 0.5  # --no-precision: arm7's own 5 cm
    assert arm.met(0.95, 0.95) and not arm.met(0.94, 0.95)
    with pytest.raises(ValueError, match="no 'success_2cm' column"):
        tts.TASKS["arm7_precise"].value({"success_rate": "1.0"})
    rows = [{"success_5cm": v} for v in ("0.5", "0.97", "0.99")]
    assert tts.first_met(arm, rows, 0.95) is rows[1] and tts.first_met(arm, rows, 1.0) is None
    assert spread([1.0, None, 2.0, 3.0]) == {"n": 3, "mean": 2.0, "std": 1.0, "values": [1.0, 2.0, 3.0]}
    assert spread([None])["mean"] is None and spread([4.0])["std"] == 0.0


def test_bad_arguments_are_one_line_errors(capsys):
    for argv, message in ((["--target", "1.5"], "argument --target: 1.5 is out of range; allowed [0, 1]"),
                          (["--devices", "0"], "argument --devices: 0 is out of range; allowed >= 1"),
                          (["--tasks", "nope"], "argument --tasks: invalid choice: 'nope'")):  # fmt: skip
        with pytest.raises(SystemExit) as e:
            tts.main(argv)
        assert e.value.code == 2 and message in capsys.readouterr().err
