"""``benchmarks.provenance``: the record of a benchmark run (command as run, commit, whether the tree
was clean, device, seeds, wall time) and a results writer that puts it into the ``.md`` and the ``.json``.
No training: the writer runs with a stand-in case."""

from __future__ import annotations

import argparse
import json
import os
import subprocess

import jax

from benchmarks import provenance, tracking_report


def _git(repo, *args):
    cmd = ["git", "-c", "user.name=t", "-c", "user.email=t@t", "-c", "commit.gpgsign=false", *args]
    return subprocess.run(cmd, cwd=repo, check=True, capture_output=True, text=True).stdout.strip()


def _repo(tmp_path):
    repo = tmp_path / "repo"
    repo.mkdir()
    _git(repo, "init", "-q")
    (repo / "a.py").write_text("x = 1\n")
    _git(repo, "add", "a.py")
    _git(repo, "commit", "-q", "-m", "one")
    return str(repo), _git(repo, "rev-parse", "HEAD")


def test_record_names_command_commit_dirty_flag_and_device(tmp_path):
    rec = provenance.record("benchmarks.x", ["--seeds", "3", "--note", "a b"], seeds=[0, 1, 2])
    assert rec["command"] == "python -m benchmarks.x --seeds 3 --note 'a b'"
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=provenance.REPO, capture_output=True, text=True)
    assert rec["commit"] == head.stdout.strip() and len(rec["commit"]) == 40
    status = subprocess.run(["git", "status", "--porcelain"], cwd=provenance.REPO, capture_output=True, text=True)
    assert rec["dirty"] is bool(status.stdout.strip())
    assert rec["device"]["name"] == jax.devices()[0].device_kind and rec["device"]["count"] == jax.device_count()
    assert rec["seeds"] == [0, 1, 2] and rec["wall_s"] == 0.0

    repo, head = _repo(tmp_path)
    clean = provenance.git_state(repo)
    assert (clean["commit"], clean["dirty"], clean["dirty_files"]) == (head, False, [])
    assert provenance.tree_words(clean) == "clean tree"
    open(os.path.join(repo, "a.py"), "a").write("y = 2\n")
    dirty = provenance.git_state(repo)
    assert dirty["commit"] == head and dirty["dirty"] is True and dirty["dirty_files"] == [" M a.py"]
    assert "DIRTY" in provenance.tree_words(dirty) and "a.py" in provenance.tree_words(dirty)
    # --commit that is not this checkout's HEAD (a copy of the tree on another machine): the tree is unknown
    given = provenance.git_state(repo, commit="abc1234")
    assert (given["commit"], given["dirty"]) == ("abc1234", None)
    assert provenance.git_state(str(tmp_path))["commit"] == "unknown"  # no checkout, no --commit


def _case(reference, method, args):
    sums = [[1.0, 2.0, 3.0], [3.0, 2.0, 1.0], [2.0, 2.0, 8.0]]
    return {"reference": reference, "method": method, "label": "", "sums": sums, "mean": [2.0, 2.0, 4.0],
            "std": [0.8, 0.0, 3.0], "median": [2.0, 2.0, 3.0], "goal": (1.0, 1.0, 1.0), "thesis": None,
            "env_steps": 1000, "train_s": 1.0, "compile_s": 0.5}  # fmt: skip


def test_writer_puts_the_record_into_md_and_json(tmp_path, monkeypatch):
    repo, head = _repo(tmp_path)
    open(os.path.join(repo, "a.py"), "a").write("y = 2\n")  # a run from a dirty tree is recorded as such
    monkeypatch.setattr(provenance, "REPO", repo)
    args = argparse.Namespace(preset="fast", seed=0, seeds=3, commit="", label="", out=str(tmp_path / "out"))
    md_of = lambda r: tracking_report.to_markdown(r, "Stand-in", "No training.")  # noqa: E731
    result = tracking_report.run_cases("ppo_tracking", args, ["--seeds", "3"], [("sine", "mlp")], _case, md_of)
    (stem,) = {os.path.splitext(p)[0] for p in os.listdir(args.out)}
    md = open(os.path.join(args.out, stem + ".md")).read()
    saved = json.load(open(os.path.join(args.out, stem + ".json")))
    prov = saved["provenance"]
    assert prov == json.loads(json.dumps(result["provenance"]))
    assert prov["command"] == "python -m benchmarks.ppo_tracking --seeds 3"
    assert (prov["commit"], prov["dirty"], prov["dirty_files"]) == (head, True, [" M a.py"])
    assert prov["device"]["name"] == jax.devices()[0].device_kind and prov["wall_s"] >= 0.0
    assert prov["seeds"] == "3 keys split from PRNGKey(0)"
    assert "## Provenance" in md and f"`{prov['command']}`" in md and f"Commit: {head}" in md
    assert "DIRTY tree: uncommitted edits" in md and "a.py" in md
    assert jax.devices()[0].device_kind in md and "Wall time:" in md and "PRNGKey(0)" in md


def test_keep_run_copies_eval_and_config_only(tmp_path):
    run = tmp_path / "runs" / "ppo-arm7-1"
    run.mkdir(parents=True)
    for name in ("eval.json", "config.json", "metrics.csv"):
        (run / name).write_text("{}")
    kept = provenance.keep_run(str(run), str(tmp_path / "results" / "cpu-x"))
    assert kept == str(tmp_path / "results" / "runs" / "cpu-x" / "ppo-arm7-1")
    assert sorted(os.listdir(kept)) == ["config.json", "eval.json"]

def test_keep_run_names_keep_runs_of_one_second_apart(tmp_path):
    """Two seeds started in the same second have run directories of one name; their own names keep both."""
    kept = []
    for seed in (0, 1):
        run = tmp_path / "runs" / f"seed{seed}" / "ddpg-arm7-20261125-093504"
        run.mkdir(parents=True)
        (run / "eval.json").write_text(f'{{"seed": {seed}}}')
        kept.append(provenance.keep_run(str(run), str(tmp_path / "results" / "x"), f"seed{seed}/{run.name}"))
    assert kept[0] != kept[1]
    assert [open(os.path.join(k, "eval.json")).read() for k in kept] == ['{"seed": 0}', '{"seed": 1}']


def test_every_results_file_has_provenance_and_json():
    """Every Markdown in benchmarks/results/ (runs/ apart) has its .json beside and a provenance section."""
    results = os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks", "results")
    mds = sorted(f for f in os.listdir(results) if f.endswith(".md") and f != "README.md")  # README: the index
    assert len(mds) >= 20
    missing = [f for f in mds if not os.path.exists(os.path.join(results, f[:-3] + ".json"))
               or "## Provenance" not in open(os.path.join(results, f)).read()]  # fmt: skip
    assert missing == []
