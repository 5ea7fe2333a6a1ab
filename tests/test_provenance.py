"""``benchmarks.provenance``: the record of a benchmark run (command as run, commit, whether the tree
was clean, device, seeds, wall time) and a results writer that puts it into the ``.md`` and the ``.json``.
No training: the writer runs with a stand-in case."""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import shutil
import subprocess

import jax
import pytest

from benchmarks import provenance, tracking_report
from benchmarks.provenance_audit import audit_result


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
    rec = provenance.record("benchmarks.x", ["--seeds", "3", "--note", "a b"], seeds=[0, 1, 2], allow_dirty=True)
    assert rec["command"] == "python -m benchmarks.x --seeds 3 --note 'a b'"
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=provenance.REPO, capture_output=True, text=True)
    assert rec["commit"] == head.stdout.strip() and len(rec["commit"]) == 40
    assert rec["device"]["name"] == jax.devices()[0].device_kind and rec["device"]["count"] == jax.device_count()
    assert rec["seeds"] == [0, 1, 2] and rec["wall_s"] == 0.0

    repo, head = _repo(tmp_path)
    clean = provenance.git_state(repo)
    assert (clean["commit"], clean["dirty"], clean["dirty_files"]) == (head, False, [])
    assert provenance.tree_words(clean) == "clean tree"
    os.makedirs(os.path.join(repo, "benchmarks", "results"))
    open(os.path.join(repo, "benchmarks", "results", "gpu-x.json"), "w").write("{}")  # an output, not code
    assert provenance.git_state(repo)["dirty"] is False
    assert provenance.record("benchmarks.x", [], cwd=repo)["commit"] == head  # a clean tree runs
    open(os.path.join(repo, "a.py"), "a").write("y = 2\n")
    dirty = provenance.git_state(repo)
    assert dirty["commit"] == head and dirty["dirty"] is True and dirty["dirty_files"] == [" M a.py"]
    assert "DIRTY" in provenance.tree_words(dirty) and "a.py" in provenance.tree_words(dirty)
    assert "+y = 2" in dirty["diff"] and dirty["diff_sha1"] == hashlib.sha1(dirty["diff"].encode()).hexdigest()
    assert provenance.git_state(str(tmp_path))["commit"] == "unknown"  # no checkout, no stamp


def test_a_dirty_or_unknown_tree_is_refused_unless_allowed_then_kept_with_its_diff(tmp_path, capsys):
    repo, head = _repo(tmp_path)
    open(os.path.join(repo, "a.py"), "a").write("y = 2\n")
    open(os.path.join(repo, "new.py"), "w").write("z = 3\n")  # a new file: in the diff too
    with pytest.raises(SystemExit) as e:
        provenance.record("benchmarks.x", [], cwd=repo)
    message = str(e.value)
    assert message.startswith("error: the tree has uncommitted edits (a.py, new.py)") and "--allow-dirty" in message
    assert "\n" not in message
    kept = provenance.record("benchmarks.x", [], cwd=repo, allow_dirty=True)
    assert kept["dirty"] is True and "+y = 2" in kept["diff"] and "+z = 3" in kept["diff"]
    assert kept["diff_truncated"] is False
    with pytest.raises(SystemExit) as e:  # no checkout and no stamp: the state cannot be read
        provenance.record("benchmarks.x", [], cwd=str(tmp_path / "nowhere"))
    assert "cannot be read" in str(e.value) and "benchmarks.provenance stamp" in str(e.value)


def _copy_without_git(repo: str, dest: str) -> str:
    shutil.copytree(repo, dest, ignore=shutil.ignore_patterns(".git"))
    return dest


def test_a_stamp_carries_commit_and_diff_to_a_copy_and_only_while_the_files_match(tmp_path):
    repo, head = _repo(tmp_path)
    open(os.path.join(repo, "a.py"), "a").write("y = 2\n")
    stamp = provenance.write_stamp(repo)
    assert (stamp["commit"], stamp["dirty"]) == (head, True) and set(stamp["files"]) == {"a.py"}
    # a copy of the tree without .git (the GPU machine's): commit, flag and diff come from the stamp
    copy = _copy_without_git(repo, str(tmp_path / "copy"))
    got = provenance.git_state(copy)
    assert (got["commit"], got["dirty"], got["diff_sha1"]) == (head, True, stamp["diff_sha1"])
    assert got["commit_source"].startswith(f"stamp {provenance.STAMP_NAME}") and got["tree_sha1"] == stamp["tree_sha1"]
    # a copy with a stale .git (another commit, another tree): the stamp wins while every file matches
    stale = _copy_without_git(repo, str(tmp_path / "stale"))
    _git(stale, "init", "-q")
    open(os.path.join(stale, "old.txt"), "w").write("old\n")
    _git(stale, "add", "old.txt")
    _git(stale, "commit", "-q", "-m", "stale")
    os.remove(os.path.join(stale, "old.txt"))  # tracked by the stale .git, gone from the tree: not a tree file
    assert provenance.git_state(stale)["commit"] == head
    # an edit after stamping: the stamp no longer holds and is named; git (here: none) is asked instead
    open(os.path.join(copy, "a.py"), "a").write("w = 4\n")
    moved = provenance.git_state(copy)
    assert moved["commit"] == "unknown" and moved["dirty"] is None and "a.py" in moved["stamp_note"]
    with pytest.raises(SystemExit):
        provenance.record("benchmarks.x", [], cwd=copy)
    # the checkout itself, committed and stamped clean: a clean record from the stamp
    _git(repo, "commit", "-qam", "two")
    clean = provenance.write_stamp(repo)
    assert clean["dirty"] is False and provenance.record("benchmarks.x", [], cwd=repo)["dirty"] is False


def test_audit_lists_results_whose_provenance_does_not_verify():
    clean = {"commit": "a" * 40, "dirty": False, "commit_source": "git rev-parse HEAD"}
    typed = {"commit": "abc1234", "dirty": None,
             "commit_source": "given with --commit; the tree it ran from was not checked"}
    assert audit_result({"provenance": clean}) == []
    assert audit_result({"provenance": typed}) == ["commit typed by hand (--commit); the tree it ran from "
                                                              "was not checked"]  # fmt: skip
    assert audit_result({"provenance": {**clean, "assembled_by_hand": True}}) == [
        "assembled by hand from the runs' files: no tool took the commit the runs ran from"]
    merged = {"provenance": clean, "sources": [clean, {**clean, "dirty": True}]}
    assert audit_result(merged) == ["1 of its 3 invocations: ran from a tree with uncommitted edits"]
    assert audit_result({"provenance_recovered": {}})[0].startswith("written before the benchmark")
    assert audit_result({"commit": "d5d2c30"}) == ["names no commit"]
    recorded = {"seeds": [{"skipped": True}], "provenance": {"missing": 0, "clean": True}}
    earlier = {"provenance": clean, "rows": [{"seeds": [{"skipped": True}]}, {"seeds": [{}]}, recorded]}
    assert audit_result(earlier) == ["1 of its 3 rows were run by an earlier invocation whose commit the "
                                                "file does not record"]  # fmt: skip


def _case(reference, method, args):
    sums = [[1.0, 2.0, 3.0], [3.0, 2.0, 1.0], [2.0, 2.0, 8.0]]
    return {"reference": reference, "method": method, "label": "", "sums": sums, "mean": [2.0, 2.0, 4.0],
            "std": [0.8, 0.0, 3.0], "median": [2.0, 2.0, 3.0], "goal": (1.0, 1.0, 1.0), "thesis": None,
            "env_steps": 1000, "train_s": 1.0, "compile_s": 0.5}  # fmt: skip


def test_writer_puts_the_record_into_md_and_json(tmp_path, monkeypatch):
    repo, head = _repo(tmp_path)
    open(os.path.join(repo, "a.py"), "a").write("y = 2\n")  # a run from a dirty tree is recorded as such
    monkeypatch.setattr(provenance, "REPO", repo)
    args = argparse.Namespace(preset="fast", purpose="report", seeds=3, first_seed=0, allow_dirty=True, label="",
                              out=str(tmp_path / "out"))  # fmt: skip
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
    assert prov["seeds"] == {"purpose": "report", "ids": [1000000, 1000001, 1000002],
                             "keys": "training key PRNGKey(seed)"}  # fmt: skip
    assert "## Provenance" in md and f"`{prov['command']}`" in md and f"Commit: {head}" in md
    assert "DIRTY tree: uncommitted edits" in md and "a.py" in md and "+y = 2" in prov["diff"]
    assert jax.devices()[0].device_kind in md and "Wall time:" in md
    assert "3 seed(s) 1000000, 1000001, 1000002 (the report range: never used to choose a setting)" in md


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
    docs = ("README.md", "why-presets.md")  # the index, and the presets' reasons (each citing its results files)
    mds = sorted(f for f in os.listdir(results) if f.endswith(".md") and f not in docs)
    assert len(mds) >= 20
    missing = [f for f in mds if not os.path.exists(os.path.join(results, f[:-3] + ".json"))
               or "## Provenance" not in open(os.path.join(results, f)).read()]  # fmt: skip
    assert missing == []
