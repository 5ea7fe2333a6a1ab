"""``jaxrl_robot.checkpoint`` under faults: damaged files, checkpoints of earlier versions, a state that
no longer fits, a failing disk and a second writer; each is one line and loses nothing good."""

import errno
import glob
import json
import logging
import os
import re
import subprocess
import sys
import tarfile

import jax
import jax.numpy as jnp
import numpy as np
import orbax.checkpoint as ocp
import pytest

from jaxrl_robot import checkpoint as ck
from jaxrl_robot.checkpoint import (
    CHECKSUMS,
    CheckpointDamagedError,
    Checkpointer,
    CheckpointMismatchError,
    CheckpointWriteError,
    DirectoryInUseError,
    DirectoryLock,
)
from jaxrl_robot.replay import make_prioritized_replay


def state_of(step):
    """A small state whose every value depends on ``step`` (distinct checkpoints, checkable restores)."""
    rng = np.random.default_rng(step)
    return {
        "params": {"w": jnp.asarray(rng.normal(size=(64, 16)), jnp.float32), "b": jnp.full(16, float(step))},
        "opt": (jnp.asarray(rng.normal(size=8), jnp.float32), jnp.int32(step)),
        "key": jax.random.PRNGKey(step),
        "empty": jnp.zeros((4, 0)),  # saved as None, taken back from the target
    }


def assert_state_equal(state, reference):
    assert jax.tree.structure(state) == jax.tree.structure(reference)
    for a, b in zip(jax.tree.leaves(state), jax.tree.leaves(reference), strict=True):
        assert a.shape == b.shape and a.dtype == b.dtype
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


@pytest.fixture
def saved(tmp_path):
    """A directory with checkpoints 1, 2, 3 of ``state_of(step)``; yields its path."""
    ckpt = Checkpointer(str(tmp_path / "checkpoints"))
    for step in (1, 2, 3):
        ckpt.save(step, state_of(step), {"chunk": step})
    ckpt.close()
    return tmp_path / "checkpoints"


def array_file(directory, step):
    """The largest array data file of checkpoint ``step`` (tensorstore's chunks of ``params.w``)."""
    files = glob.glob(os.path.join(directory, str(step), "state", "**", "d", "*"), recursive=True)
    return max(files, key=os.path.getsize)


def truncate(path):
    """Cut ``path`` to half its size."""
    size = os.path.getsize(path)
    with open(path, "r+b") as f:
        f.truncate(size // 2)


def flip_bytes(path, n=16):
    """Invert ``n`` bytes in the middle of ``path`` (its size stays)."""
    data = bytearray(open(path, "rb").read())
    middle = len(data) // 2
    data[middle : middle + n] = bytes(b ^ 0xFF for b in data[middle : middle + n])
    open(path, "wb").write(bytes(data))


def test_save_writes_the_sha256_of_every_file_and_verify_accepts_them(saved):
    listed = json.load(open(saved / "3" / CHECKSUMS))["files"]
    on_disk = {os.path.relpath(os.path.join(r, n), saved / "3") for r, _, ns in os.walk(saved / "3") for n in ns}
    assert set(listed) == on_disk - {CHECKSUMS} and any(name.startswith("state/") for name in listed)
    assert Checkpointer(str(saved)).verify(3) is True


def test_truncated_newest_checkpoint_falls_back_to_the_previous_one_exactly(saved):
    path = array_file(saved, 3)
    size = os.path.getsize(path)
    truncate(path)
    name = os.path.relpath(path, saved / "3")
    ckpt = Checkpointer(str(saved))
    restored = ckpt.restore_latest(state_of(0))
    assert restored.step == 2 and restored.record == {"chunk": 2}
    reason = f"{name} has {size // 2} bytes, {size} were written"
    assert restored.note == f"checkpoint 3 is damaged ({reason}); resuming from 2"
    assert_state_equal(restored.state, state_of(2))
    # the damaged checkpoint is kept aside, so that step 3 can be written again
    assert ckpt.all_steps() == [1, 2] and os.path.isfile(str(saved) + f".damaged/3/{name}")
    ckpt.save(3, state_of(3), {"chunk": 3})
    assert_state_equal(ckpt.restore(3, state_of(0))[0], state_of(3))


def test_flipped_bytes_are_found_by_their_checksum(saved):
    flip_bytes(array_file(saved, 3))
    ckpt = Checkpointer(str(saved))
    damaged = r"^checkpoint 3 is damaged \(state/\S+ does not match its SHA-256\)$"
    with pytest.raises(CheckpointDamagedError, match=damaged):
        ckpt.restore(3, state_of(0))
    restored = ckpt.restore_latest(state_of(0))
    assert restored.step == 2 and restored.note.endswith("does not match its SHA-256); resuming from 2")
    assert_state_equal(restored.state, state_of(2))


def test_no_good_checkpoint_is_one_error_and_moves_nothing(saved):
    for step in (1, 2, 3):
        flip_bytes(array_file(saved, step))
    with pytest.raises(CheckpointDamagedError) as info:
        Checkpointer(str(saved)).restore_latest(state_of(0))
    message = str(info.value)
    assert "\n" not in message and message.startswith(f"no usable checkpoint in {saved}: checkpoint 3 is damaged (")
    assert message.count("does not match its SHA-256") == 3
    assert sorted(os.listdir(saved)) == ["1", "2", "3"] and not os.path.exists(str(saved) + ".damaged")


def test_checkpoints_of_earlier_versions_without_checksums_restore_unverified(saved):
    for step in (1, 2, 3):
        os.remove(saved / str(step) / CHECKSUMS)
    ckpt = Checkpointer(str(saved))
    assert ckpt.verify(3) is False
    restored = ckpt.restore_latest(state_of(0))
    assert restored.step == 3
    assert restored.note == f"checkpoint 3 has no {CHECKSUMS} (an earlier version wrote it): restored unverified"
    assert_state_equal(restored.state, state_of(3))
    # without checksums a truncated file is still caught when orbax cannot read it
    truncate(array_file(saved, 3))
    restored = Checkpointer(str(saved)).restore_latest(state_of(0))
    assert restored.step == 2 and "\n" not in restored.note
    assert restored.note.startswith("checkpoint 3 is damaged (") and "not valid" in restored.note
    assert restored.note.endswith(f"; resuming from 2 (unverified: it has no {CHECKSUMS})")
    assert_state_equal(restored.state, state_of(2))


def test_a_state_that_no_longer_fits_names_the_paths_that_differ(saved):
    target = state_of(0)
    target["params"]["w"] = jnp.zeros((64, 32))  # another shape
    target["opt"] = (target["opt"][0], jnp.float32(0))  # another dtype
    del target["params"]["b"]  # saved, not in the state now
    target["extra"] = jnp.zeros(3)  # not saved
    ckpt = Checkpointer(str(saved))
    with pytest.raises(CheckpointMismatchError) as info:
        ckpt.restore_latest(target)
    assert info.value.step == 3
    assert info.value.differences == [
        "extra (3,) float32 is not in the checkpoint",
        "opt.1 has dtype int32 saved, float32 now",
        "params.w has shape (64, 16) saved, (64, 32) now",
        "params.b (16,) float32 is saved but not in the state now",
    ]
    assert str(info.value) == (
        "checkpoint 3 does not match the state: extra (3,) float32 is not in the checkpoint; opt.1 has dtype int32 "
        "saved, float32 now; params.w has shape (64, 16) saved, (64, 32) now; 1 more"
    )
    assert ckpt.all_steps() == [1, 2, 3]  # a mismatch is not damage: nothing is set aside


def test_replay_rows_saved_with_terminated_restore_into_the_one_transition_type(tmp_path):
    """Earlier versions stored a replay's termination as ``terminated`` (``checkpoint.RENAMED``): such a
    checkpoint restores into a state holding :class:`jaxrl_robot.types.Transition` rows (``termination``),
    every value in its place; a shape that differs is still named, by its old path."""
    from typing import NamedTuple

    from jaxrl_robot.types import Transition

    class OldRows(NamedTuple):  # the replay rows of earlier versions
        obs: jax.Array
        action: jax.Array
        reward: jax.Array
        next_obs: jax.Array
        terminated: jax.Array

    old = OldRows(jnp.ones((4, 2)), jnp.full((4, 1), 0.5), jnp.arange(4.0), jnp.full((4, 2), 2.0),
                  jnp.array([0.0, 1.0, 0.0, 1.0]))  # fmt: skip
    Checkpointer(str(tmp_path)).save(1, {"replay": {"data": old, "size": jnp.int32(4)}, "key": jnp.arange(2)}, {})
    rows = Transition(*(jnp.zeros_like(x) for x in old))
    target = {"replay": {"data": rows, "size": jnp.int32(0)}, "key": jnp.zeros(2, jnp.int32)}
    state, _ = Checkpointer(str(tmp_path)).restore(1, target)
    assert isinstance(state["replay"]["data"], Transition)
    for name, value in zip(Transition._fields, old, strict=False):
        np.testing.assert_array_equal(getattr(state["replay"]["data"], name), value)
    assert int(state["replay"]["size"]) == 4 and state["replay"]["data"].truncation == ()
    target["replay"]["data"] = rows._replace(termination=jnp.zeros(5))
    with pytest.raises(CheckpointMismatchError, match=r"replay\.data\.terminated has shape \(4,\) saved, \(5,\) now"):
        Checkpointer(str(tmp_path)).restore(1, target)


@pytest.mark.parametrize("where", ["record", "checksums"])
def test_disk_full_while_saving_removes_the_partial_checkpoint_and_keeps_the_others(saved, monkeypatch, caplog, where):
    """ENOSPC raised inside the save: by orbax writing the record item (the state's writer threads still
    running) or by the checksums written after it."""

    def no_space(*args, **kwargs):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    async def no_space_async(*args, **kwargs):
        no_space()

    if where == "record":
        monkeypatch.setattr(ocp.JsonCheckpointHandler, "_save_fn", no_space_async)
    else:
        monkeypatch.setattr(ck.integrity, "write_checksums", no_space)
    ckpt = Checkpointer(str(saved))
    files = [os.path.join(r, n) for r, _, names in os.walk(saved / "3") for n in names]
    with pytest.raises(CheckpointWriteError) as info:
        ckpt.save(4, state_of(4), {"chunk": 4})
    message = str(info.value)
    expected = (rf"cannot write checkpoint 4 to {re.escape(str(saved))}: No space left on device \(checkpoint 3 took "
                r"([\d.]+) kB, [\d.]+ [kM]B free\); the partial checkpoint is removed, earlier ones are intact")
    match = re.fullmatch(expected, message)
    assert match, message
    # the space checkpoint 3 takes on disk: its bytes, rounded up to blocks of at most 4 kB per file
    apparent = sum(os.path.getsize(f) for f in files)
    assert apparent <= float(match.group(1)) * 1e3 + 50 <= apparent + 4096 * len(files) + 100
    assert sorted(os.listdir(saved)) == ["1", "2", "3"] and ckpt.all_steps() == [1, 2, 3]
    assert not [r for r in caplog.records if r.levelno >= logging.ERROR]  # orbax's thread tracebacks held back
    monkeypatch.undo()
    ckpt.save(4, state_of(4), {"chunk": 4})  # space again: the step is written as usual
    restored = Checkpointer(str(saved)).restore_latest(state_of(0))
    assert restored.step == 4 and restored.note is None
    assert_state_equal(restored.state, state_of(4))


def test_os_errors_are_found_in_orbax_and_tensorstore_errors():
    text = ('RESOURCE_EXHAUSTED: Error writing "a.w/0" in OCDBT database at local file "/x/": Failed to write '
            "410103 bytes to file 17: No space left on device [os_error_code='28']")  # fmt: skip
    assert ck.integrity.os_error_code(ValueError(text)) == errno.ENOSPC
    try:
        try:
            raise OSError(errno.EDQUOT, "quota")
        except OSError as e:
            raise RuntimeError("wrapped") from e
    except RuntimeError as e:
        assert ck.integrity.os_error_code(e) == errno.EDQUOT
    assert ck.integrity.os_error_code(ValueError("a shape mismatch")) is None


HOLDER = """
import fcntl, os, sys
fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT)
fcntl.flock(fd, fcntl.LOCK_EX)  # as DirectoryLock does: an flock, the holder's pid in the file
os.ftruncate(fd, 0)
os.write(fd, f"{os.getpid()}\\n".encode())
print("locked", flush=True)
sys.stdin.read()
"""


def test_the_directory_lock_stops_a_second_writer_and_dies_with_its_process(tmp_path):
    with DirectoryLock(str(tmp_path)):
        with pytest.raises(DirectoryInUseError) as info:
            DirectoryLock(str(tmp_path)).acquire()
        assert str(info.value) == f"run directory {tmp_path} is in use by another process (pid {os.getpid()})"
    DirectoryLock(str(tmp_path)).acquire().release()  # released

    # a holder killed with SIGKILL: the kernel drops its flock, its lock file stays and blocks nothing
    holder = subprocess.Popen([sys.executable, "-c", HOLDER, os.path.join(tmp_path, DirectoryLock.NAME)],
                              stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True)  # fmt: skip
    assert holder.stdout.readline() == "locked\n"
    with pytest.raises(DirectoryInUseError, match=rf"in use by another process \(pid {holder.pid}\)$"):
        DirectoryLock(str(tmp_path)).acquire()
    holder.kill()
    holder.wait()
    assert open(os.path.join(tmp_path, DirectoryLock.NAME)).read() == f"{holder.pid}\n"
    lock = DirectoryLock(str(tmp_path)).acquire()  # the killed holder's lock file does not block
    assert open(lock.path).read() == f"{os.getpid()}\n"
    lock.release()


def test_prioritized_replay_state_has_one_layout_on_every_backend(tmp_path):
    """A DDPG checkpoint holds the PER state; its layout depends on the tree (config ``per_tree``), not on the
    platform: ``tree='auto'`` is the sum tree on every backend and the block tree's state is the same for its
    XLA (CPU) and Pallas (GPU; its interpreter here) backends, so a checkpoint moves between them."""
    item = {"obs": jnp.zeros(3), "reward": jnp.zeros(())}

    def filled(tree, backend):
        per = make_prioritized_replay(100, 8, tree=tree, backend=backend)
        state = per.init(item)
        state = per.add(state, {"obs": jnp.arange(30.0).reshape(10, 3), "reward": jnp.arange(10.0)})
        return per.update_priorities(state, jnp.arange(8), jnp.linspace(0.1, 2.0, 8))

    shapes = lambda tree, backend: jax.eval_shape(lambda: filled(tree, backend))  # noqa: E731
    assert shapes("auto", "auto") == shapes("sum", "auto")
    assert shapes("block", "xla") == shapes("block", "interpret") == shapes("block", "pallas")
    ckpt = Checkpointer(str(tmp_path))
    saved = jax.jit(lambda: filled("block", "xla"))()
    ckpt.save(1, saved, {})
    target = make_prioritized_replay(100, 8, tree="block", backend="interpret").init(item)
    assert_state_equal(ckpt.restore(1, target)[0], saved)
    # the two trees differ: a checkpoint of one does not restore into the other, and says where
    ckpt.save(2, make_prioritized_replay(100, 8, tree="sum").init(item), {})
    with pytest.raises(CheckpointMismatchError) as info:
        ckpt.restore(2, target)
    assert info.value.differences == [  # capacity 100: 16-ary leaves 16², 8 blocks of 16 leaves
        "tree.leaf_values has shape (256,) saved, (128,) now",
        "tree.block_sums (8,) float32 is not in the checkpoint",
        "tree.prefix.0 (16,) float32 is saved but not in the state now",
        "tree.prefix.1 (256,) float32 is saved but not in the state now",
    ]


GPU_CHECKPOINT = os.path.join(os.path.dirname(__file__), "data", "per_checkpoint_gpu.tar.gz")
"""Checkpoints 1-3 of prioritised replays (capacity 1000, batch 32, trees ``sum``, ``block`` and ``auto``) written
on an H200 (jax 0.11.2, orbax 0.12.4): each holds 200 items ``obs = arange(600).reshape(200, 3)``,
``reward = arange(200)``, after three sample / ``update_priorities`` steps (one on the CPU, two on the GPU, the
block tree's with its Pallas kernels), so β = 0.4 + 3 · 0.001."""


def test_a_checkpoint_written_on_a_gpu_restores_on_the_cpu(tmp_path):
    with tarfile.open(GPU_CHECKPOINT) as tar:
        tar.extractall(tmp_path, **({"filter": "data"} if hasattr(tarfile, "data_filter") else {}))
    ckpt = Checkpointer(str(tmp_path / "gpu_ckpt"))
    item = {"obs": jnp.zeros(3), "reward": jnp.zeros(())}
    for step, tree in ((1, "sum"), (2, "block"), (3, "auto")):
        assert ckpt.verify(step)
        per = make_prioritized_replay(1000, 32, tree=tree)
        state, record = ckpt.restore(step, per.init(item))
        assert record == {"tree": tree, "platform": "gpu"}
        assert int(state.size) == 200 and int(state.insert_pos) == 200
        np.testing.assert_array_equal(state.data["obs"][:200], np.arange(600.0).reshape(200, 3))
        np.testing.assert_array_equal(state.data["reward"][:200], np.arange(200.0))
        np.testing.assert_allclose(float(state.beta), 0.403, rtol=1e-6)
        leaves = np.asarray(state.tree.leaf_values)
        assert (leaves[:200] > 0).all() and (leaves[200:] == 0).all()
        sample = jax.jit(per.sample)(jax.random.PRNGKey(0), state)  # and it samples here
        assert (np.asarray(sample.indices) < 200).all()
        raw, _ = ckpt.restore(step)  # without a target: onto this machine's device, not the saved cuda:0
        assert raw["size"].devices() == {jax.devices()[0]}
        np.testing.assert_array_equal(raw["tree"]["leaf_values"], leaves)
