"""Timing of compiled calls shared by the benchmarks: compile apart, one warm-up call, then timed calls."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import jax


def compile_and_time(fn: Callable, state: Any, repeats: int, donate: bool = False) -> tuple[float, list[float], Any]:
    """Time ``fn(state) -> (state, aux)`` jitted, the state carried from call to call.

    Compiles ahead of time, calls once to warm up, then times ``repeats`` calls (each waited on).
    ``donate`` donates the state to every call.
    Returns ``(compile seconds, [repeats] seconds per call, last state)``.
    """
    jitted = jax.jit(fn, donate_argnums=0 if donate else ())
    t0 = time.perf_counter()
    compiled = jitted.lower(state).compile()
    compile_s = time.perf_counter() - t0
    state, _ = jax.block_until_ready(compiled(state))
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        state, _ = jax.block_until_ready(compiled(state))
        times.append(time.perf_counter() - t)
    return compile_s, times, state
