"""Timing of compiled calls shared by the benchmarks: compile apart, one warm-up call, then timed calls."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import jax

from jaxrl_robot import parallel


def compile_and_time(fn: Callable, state: Any, repeats: int, donate: bool = False,
                     mesh: jax.sharding.Mesh | None = None) -> tuple[float, list[float], Any]:  # fmt: skip
    """Time ``fn(state) -> (state, aux)`` jitted, the state carried from call to call.

    Compiles ahead of time, calls once to warm up, then times ``repeats`` calls (each waited on).
    ``donate`` donates the state to every call. ``mesh`` of several devices: the arrays ``fn`` closes over are
    arguments of the program, replicated over it (``jaxrl_robot.parallel.constants_as_arguments``), not constants.
    Returns ``(compile seconds, [repeats] seconds per call, last state)``.
    """
    t0 = time.perf_counter()
    if mesh is not None and mesh.devices.size > 1:
        g, consts = parallel.constants_as_arguments(fn, state, mesh=mesh)
        program = jax.jit(g, donate_argnums=1 if donate else ()).lower(consts, state).compile()

        def compiled(s: Any) -> Any:
            return program(consts, s)
    else:
        compiled = jax.jit(fn, donate_argnums=0 if donate else ()).lower(state).compile()
    compile_s = time.perf_counter() - t0
    state, _ = jax.block_until_ready(compiled(state))
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        state, _ = jax.block_until_ready(compiled(state))
        times.append(time.perf_counter() - t)
    return compile_s, times, state


def init_state(init: Callable, key: jax.Array, mesh: jax.sharding.Mesh | None = None) -> Any:
    """``init(key)`` jitted and waited on; over a ``mesh`` of several devices with the arrays ``init`` closes over
    as arguments of the program (as :func:`compile_and_time`)."""
    if mesh is not None and mesh.devices.size > 1:
        g, consts = parallel.constants_as_arguments(init, key, mesh=mesh)
        return jax.block_until_ready(jax.jit(g)(consts, key))
    return jax.block_until_ready(jax.jit(init)(key))
