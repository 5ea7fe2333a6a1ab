"""``python -m benchmarks.thesis``: every row of a table through its command line, the report's
structure, skipping finished seeds, continuing an unfinished one, and missing rows listed as such.
Smoke budgets: the numbers are not checked, the plumbing is."""

from __future__ import annotations

import dataclasses
import glob
import importlib
import json
import os

import pytest

import train.ddpg as train_ddpg
from benchmarks import thesis


def test_table_3_1_smoke_report_resume_and_missing_rows(tmp_path, monkeypatch, capsys):
    runs, out = str(tmp_path / "runs"), str(tmp_path / "out")
    table = thesis.select(["3.1"], None)
    assert [r.thesis for r in table] == [79, 78, 81, 87, 56, 9]
    # two of the table's rows run; the others' command lines build the trainer they name
    for r in table[2:]:
        _, _, cfg = train_ddpg.build(train_ddpg.parse(thesis.command(r, "cpu", 0, True)))
        flags = dict(zip(r.argv[:-1], r.argv[1:], strict=True))
        her, k = flags["--her"], int(flags.get("--her-k", 2))
        assert (cfg["ddpg"]["her"], cfg["ddpg"]["her_k"], cfg["ddpg"]["per"]) == (her, k, "--per" in r.argv), r.id
        assert cfg["args"]["reward"] == flags["--reward"] and cfg["ddpg"]["epochs"] == 1, r.id
    argv = ["--allow-dirty", "--tables", "3.1", "--rows", "sparse-final", "sparse-future2", "--seeds", "1", "--smoke",
            "--preset", "cpu", "--quiet", "--runs", runs, "--out", out]  # fmt: skip
    result = thesis.main(argv)
    rows = result["rows"]
    assert [r["row"]["name"] for r in rows] == ["sparse-final", "sparse-future2"]
    for r in rows:
        (seed,) = r["seeds"]
        assert "error" not in seed and seed["finished"] is True, seed
        assert r["figure"]["seeds_done"] == 1 and 0.0 <= r["figure"]["mean"][0] <= 100.0
        assert r["figure"]["met"] == [r["figure"]["mean"][0] >= 95.0]
        assert len(r["figure"]["precision"]) == 2 and 0.0 <= min(r["figure"]["precision"])  # at 2 and 1 cm
        assert seed["success_5cm"] == seed["success_rate"]  # the precision run agrees with the evaluation
    stem = result["stem"]
    md = open(stem + ".md").read()
    assert md.count("| DDPG, ") == 2 and "## Table 3.1" in md and "## Tables 7.1–7.3" in md
    assert "--her future --her-k 2 --preset cpu --seed 0" in md  # the exact command of a row
    assert os.path.exists(os.path.join(stem + "-figures", "table-3.1-curves.png"))
    assert json.load(open(stem + ".json"))["meta"]["smoke"] is True

    # a finished seed is skipped; one without eval.json (a killed run) continues in its own run directory
    dirs = {r["row"]["name"]: r["seeds"][0]["run_dir"] for r in rows}
    os.remove(os.path.join(dirs["sparse-final"], "eval.json"))
    before = os.path.getmtime(os.path.join(dirs["sparse-future2"], "eval.json"))
    again = thesis.main(argv)
    seeds = {r["row"]["name"]: r["seeds"][0] for r in again["rows"]}
    assert seeds["sparse-future2"].get("skipped") and not seeds["sparse-final"].get("skipped")
    # the skipped seed keeps the commit it ran at (its run directory's provenance.json), a row says which
    commit = result["meta"]["provenance"]["commit"]
    assert seeds["sparse-future2"]["provenance"]["commit"] == commit
    assert {r["row"]["name"]: r["provenance"]["missing"] for r in again["rows"]} == {"sparse-final": 0,
                                                                                  "sparse-future2": 0}
    assert seeds["sparse-final"]["run_dir"] == dirs["sparse-final"]
    assert os.path.exists(os.path.join(dirs["sparse-final"], "eval.json"))
    assert os.path.getmtime(os.path.join(dirs["sparse-future2"], "eval.json")) == before
    assert len(glob.glob(os.path.join(runs, "3.1", "sparse-final", "seed0", "*"))) == 1

    # --jobs: a seed run in a process of its own evaluates exactly as the same seed run in this process
    monkeypatch.setenv("JAX_PLATFORMS", "cpu")
    apart_runs = str(tmp_path / "apart")
    apart = thesis.main([*argv[:-4], "--runs", apart_runs, "--out", out, "--rows", "3.1/sparse-future2", "--jobs", "2"])
    (got,) = apart["rows"][0]["seeds"]
    assert os.path.exists(os.path.join(apart_runs, "3.1", "sparse-future2", "seed0.log")), got
    here = json.load(open(os.path.join(dirs["sparse-future2"], "eval.json")))
    numbers = [k for k in here if k.startswith(("success", "mean_", "closest_")) or k in ("env_steps", "episodes")]
    assert len(numbers) >= 8 and {k: got[k] for k in numbers} == {k: here[k] for k in numbers}

    # --together: a row's seeds as one run (the CPU loops one compiled program over them); its seed 0
    # evaluates exactly as seed 0 run alone, and a rerun skips both seeds
    together = [*argv[:-4], "--runs", str(tmp_path / "together"), "--out", out, "--rows", "3.1/sparse-future2",
                "--seeds", "2", "--together"]  # fmt: skip
    both = thesis.main(together)["rows"][0]["seeds"]
    assert [os.path.basename(s["run_dir"]) for s in both] == ["seed0", "seed1"] and [s["seed"] for s in both] == [0, 1]
    assert {k: both[0][k] for k in numbers} == {k: here[k] for k in numbers}
    assert both[0]["closest_distance_median"] != both[1]["closest_distance_median"]  # two seeds, not one twice
    assert all(s.get("skipped") for s in thesis.main(together)["rows"][0]["seeds"])

    # --parallel: two rows at once, each in a process of its own; a row evaluates as it does in this process,
    # and a rerun skips both
    par_runs = str(tmp_path / "parallel")
    par = [*argv[:-4], "--runs", par_runs, "--out", out, "--rows", "3.1/sparse-future2", "3.1/sparse-final",
           "--parallel", "2"]  # fmt: skip
    got = {r["row"]["name"]: r["seeds"][0] for r in thesis.main(par)["rows"]}
    assert {k: got["sparse-future2"][k] for k in numbers} == {k: here[k] for k in numbers}
    assert "error" not in got["sparse-final"] and got["sparse-final"]["finished"] is True
    assert os.path.exists(os.path.join(par_runs, "3.1", "sparse-final", "seeds0.log"))
    assert all(r["seeds"][0].get("skipped") for r in thesis.main(par)["rows"])
    with pytest.raises(SystemExit) as exit_info:  # argparse: usage, then the one error line
        thesis.main([*argv, "--parallel", "0"])
    assert exit_info.value.code == 2
    assert capsys.readouterr().err.strip().splitlines()[-1].endswith(
        "error: argument --parallel: 0 is out of range; allowed >= 1"
    )
    for bad, message in ((["--parallel", "2", "--jobs", "2"], "exclude each other"),
                         (["--gpus", "0"], "--gpus needs --parallel")):  # fmt: skip
        with pytest.raises(SystemExit, match=message):
            thesis.main([*argv, *bad])

    # a row whose algorithm does not exist is reported as missing, never run
    absent = thesis.Row("3.1", "absent", "an algorithm not built", None, (), 50, "arm", missing="not built")
    monkeypatch.setattr(thesis, "ROWS", (*thesis.ROWS, absent))
    missing = thesis.main(["--allow-dirty", "--rows", "3.1/absent", "--seeds", "1", "--runs", runs, "--out", out])
    md = open(missing["stem"] + ".md").read()
    assert md.count("**missing**") == 1 and "not built" in md
    assert not os.path.exists(os.path.join(runs, "3.1", "absent"))


def test_an_interrupted_row_stops_the_runner_with_one_line(monkeypatch):
    """A row's run that SIGTERM stopped (exit 143, checkpointed) ends the runner instead of moving on."""
    row = thesis.ROWS[0]
    monkeypatch.setattr(importlib.import_module(f"train.{row.algo}"), "main", lambda argv: 143)
    with pytest.raises(SystemExit, match=f"interrupted: {row.id} stopped with a checkpoint; the same command"):
        thesis.run_in_process(row, [], quiet=True)
    monkeypatch.setattr(importlib.import_module(f"train.{row.algo}"), "main", lambda argv: 1)
    assert thesis.run_in_process(row, [], quiet=True)[0] == 1  # a failed row is recorded, the runner goes on


def test_racing_rows_by_hand(tmp_path):
    """Tables 6.2-6.3: successes per road over seeds, met only with ≥ 95 % of the laps and ≤ 5 % collisions
    on every seed, one table line per road with the thesis's figures beside."""
    (row,) = [r for r in thesis.ROWS if r.table == "6.2-6.3" and r.name == "td3"]
    assert row.algo == "td3" and row.argv[:2] == ("--env", "racecar") and len(row.thesis) == 4

    def seed(success, collision):
        ev = {"laps_per_road": 20, "wall_s": 10.0, "run_dir": str(tmp_path)}
        for road, ok, hit in zip(thesis.ROADS, success, collision, strict=True):
            ev.update({f"{road}/success": ok, f"{road}/collision": hit, f"{road}/overtakes": 3.0,
                       f"{road}/speed_kmh": 100.0})  # fmt: skip
        return ev

    seeds = [seed((20, 19, 18, 20), (0, 1, 2, 2)), seed((19, 20, 20, 20), (1, 0, 0, 0))]
    fig = thesis.row_figure(row, seeds)
    assert fig["mean"] == [19.5, 19.5, 19.0, 20.0] and fig["std"] == [0.5, 0.5, 1.0, 0.0]
    assert fig["met"] == [True, True, False, False]  # test2: 18 < 19 on one seed; test3: 2 collisions on one
    assert fig["collisions"] == [0.5, 0.5, 1.0, 1.0] and fig["laps"] == 20
    result = {"row": dataclasses.asdict(row), "command": ["--env", "racecar"], "seeds": seeds, "figure": fig}
    lines = thesis.table_markdown("6.2-6.3", [result], str(tmp_path), "figs")
    body = [line for line in lines if line.startswith("| ") and "---" not in line][1:]
    assert [line.split(" | ")[1] for line in body] == list(thesis.ROADS)
    assert "18 / 2 / 0 / 2.6" in body[0] and "**19.5 ± 0.5** of 20" in body[0] and "19.0 ± 1.0 of 20" in body[2]


def test_precise_variant_rows_by_hand(tmp_path):
    """``--variant precise``: the arm rows run on ``arm7_precise`` (arm7 at a 1 cm goal, nothing else changed);
    a row is met at ≥ 95 % within 2 cm and ≥ 90 % within 1 cm (mean over seeds), tracking rows unchanged."""
    import envs_mjx

    precise, plain = envs_mjx.make("arm7_precise"), envs_mjx.make("arm7")
    assert precise.config == dataclasses.replace(plain.config, goal_threshold=0.01)
    rows = thesis.select(["5.1", "4.4"], None, "precise")
    arm = [r for r in rows if r.kind == "arm"]
    assert [r.argv[:2] for r in arm] == [("--env", "arm7_precise")] * 2 and all(thesis.is_precise(r) for r in arm)
    assert [r for r in rows if r.kind != "arm"] == [r for r in thesis.ROWS if r.table == "4.4"]
    assert thesis.command(arm[1], "cpu", 2, False)[-4:] == ["--preset", "cpu", "--seed", "2"]

    def seed(at5, at2, at1):
        return {"success_rate": at1, "success_5cm": at5, "success_2cm": at2, "success_1cm": at1, "wall_s": 5.0,
                "run_dir": str(tmp_path)}  # fmt: skip

    seeds = [seed(1.0, 0.97, 0.92), seed(0.99, 0.95, 0.86)]
    fig = thesis.row_figure(arm[1], seeds)
    assert fig["values"] == [[97.0, 92.0], [95.0, 86.0]] and fig["mean"] == [96.0, 89.0]
    assert fig["met"] == [True, False] and fig["precision"] == [99.5]  # 1 cm misses 90 on the mean
    result = {"row": dataclasses.asdict(arm[1]), "command": list(arm[1].argv), "seeds": seeds, "figure": fig}
    lines = thesis.table_markdown("5.1", [result], str(tmp_path), "figs")
    (line,) = [x for x in lines if x.startswith("| Distributed PPO")]
    cells = line.split(" | ")
    assert cells[2:6] == ["**96.0 ± 1.0**", "89.0 ± 3.0", "97 / 92; 95 / 86 (2/2)", "no"] and cells[6] == "99.5"


def test_runs_wall_counts_a_run_of_several_seeds_once():
    """Seeds run apart add their walls; the seeds of one ``--seeds`` run (``<run>/seed<k>/``, each
    ``eval.json`` with the whole run's wall) count that wall once; a failed seed without a folder counts
    its process time."""
    apart = [{"run_dir": f"/r/3.1/x/seed{k}/ddpg-arm7-1", "wall_s": w} for k, w in enumerate((10.0, 12.0))]
    together = [{"run_dir": f"/r/3.1/y/seeds0-1-2/ddpg-arm7-2/seed{k}", "wall_s": 30.0} for k in range(3)]
    failed = [{"error": "exit code 1", "run_dir": None, "wall_s": 4.0}, {"error": "exit code 1", "wall_s": 5.0}]
    assert thesis.runs_wall(apart) == 22.0
    assert thesis.runs_wall(together) == 30.0
    assert thesis.runs_wall(together + apart + failed) == 61.0


def test_row_processes_share_gpus_round_robin():
    """--parallel 5 over --gpus 0 1: slots 0, 2, 4 on GPU 0 (a third of its memory each), 1 and 3 on GPU 1
    (half each); without --gpus every slot sees every device with 1/5 of the memory."""
    import argparse

    args = argparse.Namespace(parallel=5, gpus=[0, 1])
    envs = [thesis.row_process_env(slot, args) for slot in range(5)]
    assert [e["CUDA_VISIBLE_DEVICES"] for e in envs] == ["0", "1", "0", "1", "0"]
    assert [e["XLA_PYTHON_CLIENT_MEM_FRACTION"] for e in envs] == ["0.300", "0.450", "0.300", "0.450", "0.300"]
    plain = thesis.row_process_env(3, argparse.Namespace(parallel=5, gpus=None))
    assert plain["XLA_PYTHON_CLIENT_MEM_FRACTION"] == "0.180"
    assert plain.get("CUDA_VISIBLE_DEVICES") == os.environ.get("CUDA_VISIBLE_DEVICES")


def test_every_arm_row_of_a_table_has_the_same_columns(tmp_path):
    """The 5 cm arm table: every row (not only the first) gives the faithful column (here not run), mean ± std,
    the seeds, met, and success at 2 cm / 1 cm, in the header's nine columns."""
    rows = thesis.select(["5.1"], None)

    def seed(at5, at2, at1, k):
        return {"success_rate": at5, "success_5cm": at5, "success_2cm": at2, "success_1cm": at1, "wall_s": 5.0,
                "run_dir": str(tmp_path / f"seed{k}")}  # fmt: skip

    results = []
    for row, (at5, at2, at1) in zip(rows, ((0.98, 0.25, 0.02), (0.99, 0.54, 0.10)), strict=True):
        seeds = [seed(at5, at2, at1, k) for k in range(2)]
        results.append({"row": dataclasses.asdict(row), "command": list(row.argv), "seeds": seeds,
                        "figure": thesis.row_figure(row, seeds)})  # fmt: skip
    lines = [x for x in thesis.table_markdown("5.1", results, str(tmp_path), "figs") if x.startswith("| Distributed")]
    assert [x.split(" | ")[2:7] for x in lines] == [["not run", "**98.0 ± 0.0**", "98; 98 (2/2)", "yes", "25.0 / 2.0"],
                                                    ["not run", "**99.0 ± 0.0**", "99; 99 (2/2)", "yes", "54.0 / 10.0"]]
    header = next(x for x in thesis.table_markdown("5.1", results, str(tmp_path), "figs") if x.startswith("| row"))
    assert all(x.count(" | ") == header.count(" | ") for x in lines)
