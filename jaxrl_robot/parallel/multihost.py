"""Runs over several processes: joining one (:func:`initialize_multihost`), and a process that dies found at
once by the others (:func:`watch_peers`, :func:`lost_peer`, :func:`exit_at_once`).

Afterwards ``jax.devices()`` lists the devices of every process, so :func:`jaxrl_robot.parallel.lane_mesh`
spans them all; every process runs the same program on the same inputs (the same seed).
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
from typing import Any, NoReturn

import jax

__all__ = ["exit_at_once", "initialize_multihost", "lost_peer", "set_peer_loss_note", "watch_peers"]


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
