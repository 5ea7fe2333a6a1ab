"""Devices: the lane mesh, ``shard_map`` over it, collectives. The only module that knows about devices.

Batch lanes (parallel workers) are split evenly over a 1-D device mesh whose axis is named
``"lanes"``. Code inside :func:`shard_lanes` sees its device's slice of the lanes and uses
:func:`pmean` / :func:`psum` to combine gradients and statistics, so parameters stay identical
on every device. With one device the same code runs unchanged (the collectives are no-ops).

On a CPU, ``XLA_FLAGS=--xla_force_host_platform_device_count=4`` (set before importing jax)
gives four devices for testing.

Two implementations of the lane map, one semantics
--------------------------------------------------
:func:`shard_lanes` gives ``fn`` a *per-device view*: ``fn`` sees ``[num_lanes / D, ...]`` of every
split input and combines over devices with the collectives of this module. It is built in one
of two ways (``impl``; the environment variable ``JAXRL_LANE_MAP`` overrides the default):

* ``"shard_map"`` — ``jax.shard_map``: XLA compiles ``fn`` once per device as a manually
  partitioned program. The default on a one-device mesh.
* ``"vmap"`` — the split inputs are reshaped to ``[D, num_lanes / D, ...]``; ``fn`` is vmapped
  over the leading device axis with ``axis_name="lanes"`` (so ``pmean``/``psum``/``all_gather``/
  ``axis_index`` become reductions and gathers over that axis) and the axis is constrained to
  the mesh, so XLA's automatic SPMD partitioner places one slice per device and turns the
  reductions into all-reduces. The default on a mesh of several devices.

Why ``vmap`` on several devices: with MuJoCo MJX physics inside the body (``arm7`` in ``pd``
mode, ``unicycle`` in ``dynamic`` mode, ``scara``), XLA:GPU (jax 0.11.2, mujoco-mjx 3.17.0, two
H200s) ends the process with a segmentation fault while compiling the ``shard_map`` program;
the same step under ``jax.jit`` with lane shardings compiles and runs, and so do kinematic envs and
a bare ``shard_map`` + ``psum``. The reproducer is ``python -m benchmarks.multigpu_repro``
(each variant in its own process; see its results file in ``benchmarks/results/``). Both
implementations run the same arithmetic, so they agree up to float summation order
(``tests/agents/test_ppo_devices.py`` checks 4 fake CPU devices of either kind against one).
"""

from __future__ import annotations

import atexit
import contextlib
import os
import re
import selectors
import socket
import sys
import threading
import warnings
from collections.abc import Callable, Sequence
from typing import Any, NoReturn

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

__all__ = [
    "LANES",
    "P",
    "all_gather",
    "device_summary",
    "exit_at_once",
    "global_lane_ids",
    "initialize_multihost",
    "lane_map_impl",
    "lane_mesh",
    "lane_sharding",
    "local_lane_count",
    "local_sharding",
    "lost_peer",
    "on_accelerator",
    "on_gpu",
    "pmean",
    "psum",
    "set_peer_loss_note",
    "shard_lanes",
    "watch_peers",
]

LANES = "lanes"
P = PartitionSpec
IMPLS = ("shard_map", "vmap")
IMPL_ENV = "JAXRL_LANE_MAP"


def on_accelerator() -> bool:
    """Whether JAX's default backend is an accelerator (a GPU or TPU) rather than the CPU."""
    return jax.default_backend() != "cpu"


def on_gpu() -> bool:
    """Whether JAX's default backend is a GPU (where Pallas's Triton kernels run)."""
    return jax.default_backend() == "gpu"


def device_summary() -> list[tuple[int, str, str, int]]:
    """Every device of the run, in JAX's order, as ``(id, platform, kind, process index)``: what a compiled
    program is built for (part of the key of a program kept between processes)."""
    return [(d.id, d.platform, d.device_kind, d.process_index) for d in jax.devices()]


def local_sharding() -> jax.sharding.SingleDeviceSharding:
    """An array whole on this process's first device (e.g. where a checkpoint is restored to be read here)."""
    return jax.sharding.SingleDeviceSharding(jax.local_devices()[0])


def lane_mesh(num_devices: int | None = None, devices: Sequence[jax.Device] | None = None) -> Mesh:
    """A 1-D mesh named ``"lanes"`` over ``devices`` (default: the first ``num_devices`` devices, or all)."""
    devs = list(jax.devices() if devices is None else devices)
    if num_devices is not None:
        if not 1 <= num_devices <= len(devs):
            raise ValueError(f"num_devices={num_devices} is out of range; allowed [1, {len(devs)}]")
        devs = devs[:num_devices]
    return Mesh(np.array(devs), (LANES,))


def local_lane_count(num_lanes: int, mesh: Mesh) -> int:
    """Lanes per device; raises a clear error unless ``num_lanes`` divides evenly over the mesh."""
    n = mesh.shape[LANES]
    if num_lanes % n:
        raise ValueError(f"num_envs={num_lanes} must be a multiple of the number of devices ({n})")
    return num_lanes // n


def lane_sharding(mesh: Mesh, split: bool = True) -> NamedSharding:
    """Sharding that splits the leading axis over the lanes (``split``) or replicates."""
    return NamedSharding(mesh, P(LANES) if split else P())


def lane_map_impl(mesh: Mesh, impl: str | None = None) -> str:
    """The lane-map implementation for ``mesh``: ``impl``, else ``$JAXRL_LANE_MAP``, else by mesh size.

    One device: ``"shard_map"``; several: ``"vmap"`` (see the module docstring for why).
    """
    impl = impl or os.environ.get(IMPL_ENV, "").strip() or None
    if impl is None:
        return "shard_map" if mesh.devices.size == 1 else "vmap"
    if impl not in IMPLS:
        raise ValueError(f"{IMPL_ENV}={impl!r} is not a lane-map implementation; valid: {', '.join(IMPLS)}")
    return impl


def shard_lanes(
    fn: Callable[..., Any], mesh: Mesh, in_specs: Any, out_specs: Any, *, impl: str | None = None
) -> Callable[..., Any]:
    """Map ``fn`` over the lane mesh: ``P("lanes")`` splits a leading lane axis, ``P()`` replicates.

    ``in_specs`` is a tuple with one spec-tree per positional argument (a prefix of the argument's
    pytree); ``out_specs`` a spec-tree prefix of the output. ``fn`` sees this device's slice of
    every split input and may call :func:`pmean`, :func:`psum`, :func:`all_gather` and
    :func:`global_lane_ids`. A ``P()`` output must be the same on every device (the first
    device's value is returned). ``impl``: ``"shard_map"`` or ``"vmap"`` (default:
    :func:`lane_map_impl`).
    """
    if lane_map_impl(mesh, impl) == "shard_map":
        return jax.shard_map(fn, mesh=mesh, in_specs=in_specs, out_specs=out_specs, check_vma=False)
    return _vmap_lanes(fn, mesh, in_specs, out_specs)


def _is_spec(x: Any) -> bool:
    return isinstance(x, PartitionSpec)


def _is_split(spec: PartitionSpec) -> bool:
    if len(spec) == 0 or spec[0] is None:
        return False
    if spec[0] != LANES or any(s is not None for s in spec[1:]):
        raise ValueError(f"lane specs are P('lanes') or P(); got {spec}")
    return True


def _vmap_lanes(fn: Callable[..., Any], mesh: Mesh, in_specs: Any, out_specs: Any) -> Callable[..., Any]:
    """:func:`shard_lanes` as ``vmap`` over a ``[D]`` device axis partitioned by XLA (module docstring)."""
    num = mesh.shape[LANES]
    split_sharding = NamedSharding(mesh, P(LANES))
    replicated = NamedSharding(mesh, P())

    def to_devices(x: jax.Array) -> jax.Array:
        x = jnp.asarray(x)
        if x.ndim == 0 or x.shape[0] % num:
            raise ValueError(f"a P('lanes') input of shape {x.shape} does not split over {num} devices")
        x = x.reshape((num, x.shape[0] // num) + x.shape[1:])
        return jax.lax.with_sharding_constraint(x, split_sharding)

    def from_devices(x: jax.Array) -> jax.Array:
        x = jax.lax.with_sharding_constraint(x, split_sharding)
        return jax.lax.with_sharding_constraint(x.reshape((x.shape[0] * x.shape[1],) + x.shape[2:]), split_sharding)

    def first(x: jax.Array) -> jax.Array:
        return jax.lax.with_sharding_constraint(x[0], replicated)

    def mapped(*args: Any) -> Any:
        specs = (in_specs,) * len(args) if _is_spec(in_specs) else tuple(in_specs)
        if len(specs) != len(args):
            raise ValueError(f"in_specs has {len(specs)} entries for {len(args)} arguments")
        ins, axes = [], []
        for spec_tree, arg in zip(specs, args, strict=True):
            split = jax.tree.map(lambda s, a: jax.tree.map(lambda _: _is_split(s), a), spec_tree, arg, is_leaf=_is_spec)
            ins.append(jax.tree.map(lambda sp, a: to_devices(a) if sp else a, split, arg))
            axes.append(jax.tree.map(lambda sp: 0 if sp else None, split))
        out = jax.vmap(fn, in_axes=tuple(axes), out_axes=0, axis_name=LANES, spmd_axis_name=LANES)(*ins)
        return jax.tree.map(
            lambda s, o: jax.tree.map(from_devices if _is_split(s) else first, o), out_specs, out, is_leaf=_is_spec
        )

    return mapped


def pmean(tree: Any, axis_name: str = LANES) -> Any:
    """Mean over devices of every leaf (inside :func:`shard_lanes`)."""
    return jax.lax.pmean(tree, axis_name)


def psum(tree: Any, axis_name: str = LANES) -> Any:
    """Sum over devices of every leaf (inside :func:`shard_lanes`)."""
    return jax.lax.psum(tree, axis_name)


def all_gather(tree: Any, axis_name: str = LANES) -> Any:
    """Every leaf's leading axis concatenated over devices, in device order (inside :func:`shard_lanes`).

    ``[n_local, ...]`` on each device -> ``[n_local * devices, ...]`` on every device.
    """
    return jax.lax.all_gather(tree, axis_name, tiled=True)


def global_lane_ids(num_local: int, axis_name: str = LANES) -> jax.Array:
    """``[num_local]`` global indices of this device's lanes (inside :func:`shard_lanes`)."""
    return jax.lax.axis_index(axis_name) * num_local + jnp.arange(num_local)


def initialize_multihost(
    coordinator_address: str | None = None,
    num_processes: int | None = None,
    process_id: int | None = None,
    **kwargs: Any,
) -> bool:
    """Join a run over several processes (``jax.distributed.initialize``) if one is asked for or detected.

    Call before any JAX computation. The run spans several processes when ``coordinator_address``
    (``HOST:PORT`` of process 0), ``num_processes`` or ``process_id`` is given, when
    ``$JAX_COORDINATOR_ADDRESS`` is set, or when JAX detects a cluster launch of several
    processes (SLURM ``srun``, Open MPI ``mpirun``, an indexed Kubernetes job, Cloud TPU);
    arguments left ``None`` are then filled in by JAX from that environment. Otherwise, or with
    ``num_processes=1``, nothing happens and the process runs alone. On a CPU backend the
    cross-process collectives use gloo unless ``jax_cpu_collectives_implementation`` is set.
    Calling it again after a successful start does nothing.

    Afterwards ``jax.devices()`` lists the devices of every process, so :func:`lane_mesh` spans
    them all; every process runs the same program on the same inputs (the same seed).
    A process that dies is then reported by the others at once (:func:`watch_peers`).

    Args:
      coordinator_address, num_processes, process_id: as ``jax.distributed.initialize``.
      kwargs: further arguments of ``jax.distributed.initialize`` (``local_device_ids``, …).
    Returns:
      True if this process is part of a run over several processes.
    """
    if jax.distributed.is_initialized():
        return True
    if num_processes == 1:
        return False
    asked = any(v is not None for v in (coordinator_address, num_processes, process_id))
    if not (asked or os.environ.get("JAX_COORDINATOR_ADDRESS") or _cluster_processes() > 1):
        return False
    if getattr(jax.config, "jax_cpu_collectives_implementation", "gloo") is None:
        jax.config.update("jax_cpu_collectives_implementation", "gloo")
    jax.distributed.initialize(coordinator_address, num_processes, process_id, **kwargs)
    if jax.process_count() > 1:
        watch_peers()
    return jax.process_count() > 1


def _cluster_processes() -> int:
    """Processes of the cluster launch found by JAX's auto-detection (SLURM, Open MPI, …); 0 if none.

    A cluster whose process count cannot be read (e.g. a Kubernetes pod outside an indexed job)
    counts as none, with a warning.
    """
    try:
        from jax._src.clusters import ClusterEnv
    except ImportError:  # the detection's home moved: only explicit settings start a run of several processes
        return 0
    for env in ClusterEnv._cluster_types:
        if env.opt_in_only_method:
            continue
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                if not env.is_env_present():
                    continue
            return int(env.get_process_count())
        except Exception as e:  # any failure of the detection means "not detected"
            warnings.warn(f"{env.__name__} detected, process count unknown ({e}); running alone", stacklevel=2)
            return 0
    return 0



PEER_LOSS_SIGNS = (
    "gloo", "nccl", "connection reset", "connection closed", "socket closed", "broken pipe", "heartbeat",
    "unavailable", "deadline_exceeded", "deadline exceeded",
)  # fmt: skip
"""Words (lower case) of the runtime errors by which a collective of a run over several processes
says that another process is gone (gloo on CPUs, NCCL on GPUs, the coordination service)."""

WATCH_KEY = "jaxrl_robot/peer_watch"
"""Key of the coordination service's store under which process 0 publishes the port of :func:`watch_peers`."""
WATCH_TIMEOUT_S = 120
"""How long :func:`watch_peers` waits to connect before it gives up (with a warning, the run goes on)."""

_exit_lock = threading.Lock()
_peer_loss_note = ""
_watch_sockets: list[socket.socket] = []  # open as long as the process runs, also where the watch gave up


def lost_peer(error: BaseException) -> str | None:
    """A one-line description of the peer that ``error`` (or an error it was raised from) says is gone,
    e.g. ``"process 1 of 2 stopped responding (Gloo AllGather failed: Connection reset by peer)"``;
    None with one process or for any other error.

    A killed process closes its sockets, so a collective that waits on it directly fails at once with
    a ``jax.errors.JaxRuntimeError``. One whose devices wait on each other (several per process)
    hangs instead, until the coordination service misses the dead one's heartbeats
    (``heartbeat_timeout_seconds``, 100 s) and aborts the survivors from C++ with a long trace;
    :func:`watch_peers` reports such a loss at once.
    """
    if jax.process_count() < 2:
        return None
    seen: set[int] = set()
    while error is not None and id(error) not in seen:
        seen.add(id(error))
        text = str(error)
        if isinstance(error, jax.errors.JaxRuntimeError) and any(s in text.lower() for s in PEER_LOSS_SIGNS):
            return f"{_process_text(1 - jax.process_index() if jax.process_count() == 2 else None)} ({_gist(text)})"
        error = error.__cause__ or error.__context__
    return None


def _process_text(index: int | None) -> str:
    """``process 1 of 2 stopped responding`` (``index`` None: which one is not known)."""
    n = jax.process_count()
    who = f"process {index} of {n}" if index is not None else f"one of the {n} processes"
    return f"{who} stopped responding"


def _gist(text: str) -> str:
    """The first line of a runtime error without its status code, source locations and addresses."""
    line = text.strip().splitlines()[0] if text.strip() else "no message"
    line = re.sub(r"^[A-Z_]+: ", "", line)  # UNKNOWN: , UNAVAILABLE: , ...
    line = re.sub(r"\[[^\]]*\.(?:cc|h|cpp):\d+\]\s*", "", line)  # [external/gloo/.../pair.cc:538]
    line = re.sub(r"\s*\[[0-9a-fA-F.:]+\]:\d+", "", line)  # [127.0.0.1]:46474
    return line if len(line) <= 160 else line[:157] + "..."


def set_peer_loss_note(note: str) -> None:
    """What :func:`watch_peers` adds to its line when a peer is lost (e.g. how to resume the run)."""
    global _peer_loss_note
    _peer_loss_note = note


def exit_at_once(code: int, message: str = "") -> NoReturn:
    """Write ``message`` (one line) to stderr and end this process now with ``code``, skipping the exit
    handlers; of several threads calling it, the first ends the process.

    For a process of a run over several processes that lost a peer: the normal exit would wait in
    ``jax.distributed.shutdown`` for the lost process and then abort. Whatever else writes to stderr
    after ``message`` (the runtime's own report of the loss) goes to ``os.devnull``.
    """
    _exit_lock.acquire()  # a second caller waits here while the first ends the process
    if message:
        sys.stderr.write(message + "\n")
    sys.stdout.flush()
    sys.stderr.flush()
    with contextlib.suppress(OSError):  # the runtime's own threads may be logging the loss as well
        os.dup2(os.open(os.devnull, os.O_WRONLY), 2)
    os._exit(code)


def watch_peers() -> bool:
    """Report a process of this run that dies, at once, on every other process.

    Every process keeps a TCP connection to process 0 (its port published in the coordination
    service's store, :data:`WATCH_KEY`), watched by a daemon thread. A process that ends normally
    first says so on its connection (an exit handler); one that dies closes it without a word, and
    the process at the other end writes ``error: process 1 of 2 stopped responding (its connection
    closed); <the note of set_peer_loss_note>`` and ends with exit code 1 (:func:`exit_at_once`).
    Process 0 thus learns of any lost process, the others of process 0. Where process 0 is the one
    lost, the others' coordination clients (process 0 hosts their service) log the loss at the same
    moment and abort from C++: some of their lines may come before this one, or, rarely, their abort
    first. Keep-alive probes (where the OS has them) find a host that vanished without closing its
    connections within about a minute.

    Returns:
      Whether the watch runs (a failure to connect is a warning: the run goes on without it).
    """
    try:
        from jax._src import distributed

        state = distributed.global_state
        host = str(state.coordinator_address).rsplit(":", 1)[0].strip("[]")
        me, count = jax.process_index(), jax.process_count()
        if me == 0:
            server = socket.create_server(("", 0), family=socket.AF_INET6, dualstack_ipv6=True) \
                if socket.has_dualstack_ipv6() else socket.create_server(("", 0))  # fmt: skip
            state.client.key_value_set(WATCH_KEY, str(server.getsockname()[1]))
            peers = {}
            server.settimeout(WATCH_TIMEOUT_S)
            for _ in range(count - 1):
                conn, _ = server.accept()
                _watch_sockets.append(conn)
                conn.settimeout(WATCH_TIMEOUT_S)
                peers[conn] = int(conn.makefile().readline())
            server.close()
        else:
            port = int(state.client.blocking_key_value_get(WATCH_KEY, WATCH_TIMEOUT_S * 1000))
            conn = socket.create_connection((host, port), timeout=WATCH_TIMEOUT_S)
            _watch_sockets.append(conn)
            conn.sendall(f"{me}\n".encode())
            peers = {conn: 0}
    except Exception as e:  # the run goes on; a lost process is then found by JAX's heartbeats only
        warnings.warn(f"no watch for lost processes ({type(e).__name__}: {e})", stacklevel=2)
        return False
    for conn in peers:
        conn.settimeout(None)
        _keep_alive(conn)
    leaving = threading.Event()

    def say_bye() -> None:
        if hasattr(sys, "last_value"):  # ending on an uncaught exception: the others should know
            return
        leaving.set()
        for conn in peers:
            with contextlib.suppress(OSError):
                conn.sendall(b"bye\n")

    def watch() -> None:
        with selectors.DefaultSelector() as sel:
            for conn, index in peers.items():
                sel.register(conn, selectors.EVENT_READ, index)
            while sel.get_map():
                for key, _ in sel.select():
                    try:
                        data = key.fileobj.recv(64)
                    except OSError:
                        data = b""
                    if b"bye" in data:
                        sel.unregister(key.fileobj)
                    elif not data and not leaving.is_set():
                        note = f"; {_peer_loss_note}" if _peer_loss_note else ""
                        exit_at_once(1, f"error: {_process_text(key.data)} (its connection closed){note}")
                    elif not data:
                        sel.unregister(key.fileobj)

    atexit.register(say_bye)
    threading.Thread(target=watch, name="peer-watch", daemon=True).start()
    return True


def _keep_alive(conn: socket.socket) -> None:
    """TCP keep-alive probes on ``conn``: after 20 s of silence, every 10 s, 3 unanswered end it."""
    conn.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
    for name, value in (("TCP_KEEPIDLE", 20), ("TCP_KEEPINTVL", 10), ("TCP_KEEPCNT", 3)):
        if hasattr(socket, name):
            conn.setsockopt(socket.IPPROTO_TCP, getattr(socket, name), value)
