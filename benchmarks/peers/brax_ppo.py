"""brax's own PPO (``brax.training.agents.ppo.train``) and SAC (``sac.train``) as benchmark peers.

COMPATIBILITY SHIM (benchmarks only): brax 0.14.2 calls ``jax.device_put_replicated``, which
current JAX (>= 0.10) removed. :func:`install_shim` restores it for one-host use as "stack
the value once per device along a new leading axis" — what brax's ``pmap``-ed training step
expects — and changes nothing else in brax.
"""

from __future__ import annotations

import functools
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

__all__ = ["install_shim", "run_brax_ppo", "train_published"]


def install_shim() -> bool:
    """Provide ``jax.device_put_replicated`` if JAX lacks it; returns True when the shim was installed."""
    if hasattr(jax, "device_put_replicated"):
        return False

    def device_put_replicated(x: Any, devices: list) -> Any:  # shim: see module docstring
        n = len(devices)
        return jax.tree.map(lambda a: jnp.stack([jnp.asarray(a)] * n), x)

    jax.device_put_replicated = device_put_replicated
    return True


def run_brax_ppo(
    env: Any,
    num_envs: int,
    unroll_length: int,
    num_minibatches: int,
    iterations_per_epoch: int,
    epochs: int,
    episode_length: int,
    hidden: tuple[int, ...] = (200, 200),
    seed: int = 0,
) -> dict[str, Any]:
    """Train brax PPO for ``epochs`` timed epochs (+1 epoch that includes compilation).

    Settings mirror ours: each iteration collects ``num_envs × unroll_length`` steps and makes
    ``num_minibatches`` updates (one pass), mini-batches of ``num_envs / num_minibatches`` unrolls.

    Returns:
      ``{"sps": [per epoch], "first_epoch_s", "steps_per_epoch"}``; epoch 0 includes compilation.
    """
    from brax.training.agents.ppo import networks as ppo_networks
    from brax.training.agents.ppo import train as ppo

    shimmed = install_shim()
    steps_per_iteration = num_envs * unroll_length
    steps_per_epoch = steps_per_iteration * iterations_per_epoch
    records: list[dict[str, float]] = []

    def progress(step: int, metrics: dict) -> None:
        if "training/sps" in metrics:
            sps, wall = float(metrics["training/sps"]), float(metrics["training/walltime"])
            records.append({"step": step, "sps": sps, "wall": wall})

    factory = functools.partial(
        ppo_networks.make_ppo_networks, policy_hidden_layer_sizes=hidden, value_hidden_layer_sizes=hidden
    )
    t0 = time.perf_counter()
    ppo.train(
        environment=env,
        num_timesteps=steps_per_epoch * (epochs + 1),
        num_envs=num_envs,
        episode_length=episode_length,
        unroll_length=unroll_length,
        batch_size=num_envs // num_minibatches,
        num_minibatches=num_minibatches,
        num_updates_per_batch=1,
        learning_rate=3e-4,
        discounting=0.9,
        num_evals=epochs + 2,
        run_evals=False,
        network_factory=factory,
        max_devices_per_host=1,
        seed=seed,
        progress_fn=progress,
    )
    total = time.perf_counter() - t0
    sps = [r["sps"] for r in records]
    return {
        "sps": sps,
        "timed_sps_median": float(np.median(sps[1:])) if len(sps) > 1 else float("nan"),
        "first_epoch_s": records[0]["wall"] if records else float("nan"),
        "steps_per_epoch": steps_per_epoch,
        "total_s": total,
        "shim_installed": shimmed,
    }


def train_published(
    env: Any, row: dict[str, float], num_timesteps: int, seed: int = 0, algo: str = "ppo",
    deterministic_eval: bool = False, num_evals: int = 10, on_eval: Callable[[dict[str, Any]], None] | None = None,
    wrap_env_fn: Callable[..., Any] | None = None,
) -> dict[str, Any]:  # fmt: skip
    """brax's ``ppo.train`` (or, with ``algo='sac'``, ``sac.train``) with a task's published settings (``row``:
    brax's own argument names, a row of ``train.presets.BRAX_PPO`` or ``BRAX_SAC``, or MuJoCo Playground's
    ``train.presets.playground_row``) for ``num_timesteps`` env steps; brax's default networks (the row's
    ``network_factory`` keywords over them where it has them), normalised observations (unless the row's
    ``normalize_observations`` is false), PPO's ``num_resets_per_eval`` where the row has it, ``num_evals``
    evaluations (the first before training), each followed by ``on_eval`` with the record so far.
    ``wrap_env_fn``: brax's ``wrap_env_fn`` (a MuJoCo Playground env: ``wrapper.wrap_for_brax_training``).

    Returns ``final_return`` (brax's last ``eval/episode_reward``: 128 episodes of the policy's sampled
    actions, brax's default, or with ``deterministic_eval`` of its mode), ``curve_steps`` / ``curve``
    (every evaluation), ``curve_wall_s`` (the seconds since the call at each evaluation), ``wall_s`` (the whole
    call, compilation included) and ``env_steps`` (brax's count at its last evaluation).
    """
    if algo == "ppo":
        from brax.training.agents.ppo import networks
        from brax.training.agents.ppo import train as trainer

        names = ("num_envs", "batch_size", "num_minibatches", "unroll_length", "num_updates_per_batch",
                 "episode_length", *(("num_resets_per_eval",) if "num_resets_per_eval" in row else ()))  # fmt: skip
        extra = {"entropy_cost": float(row["entropy_cost"])}
        make_networks = networks.make_ppo_networks
    elif algo == "sac":
        from brax.training.agents.sac import networks
        from brax.training.agents.sac import train as trainer

        names = ("num_envs", "batch_size", "grad_updates_per_step", "episode_length", "max_replay_size",
                 "min_replay_size")  # fmt: skip
        extra = {}
        make_networks = networks.make_sac_networks
    else:
        raise ValueError(f"algo={algo!r}: expected 'ppo' or 'sac'")
    if row.get("network_factory"):
        extra["network_factory"] = functools.partial(make_networks, **row["network_factory"])
    if wrap_env_fn is not None:
        extra["wrap_env_fn"] = wrap_env_fn

    install_shim()
    evals: list[tuple[int, float, float]] = []  # (env steps, return, seconds since the call) per evaluation

    def so_far() -> dict[str, Any]:
        return {"final_return": evals[-1][1], "curve_steps": [e[0] for e in evals], "curve": [e[1] for e in evals],
                "curve_wall_s": [e[2] for e in evals], "wall_s": time.perf_counter() - t0,
                "env_steps": evals[-1][0]}  # fmt: skip

    def progress(step: int, metrics: dict) -> None:
        if "eval/episode_reward" in metrics:
            evals.append((int(step), float(metrics["eval/episode_reward"]), time.perf_counter() - t0))
            print(f"  brax {algo} seed {seed}: {int(step):,} env steps, eval return {evals[-1][1]:.1f}, "
                  f"{time.perf_counter() - t0:.0f} s", flush=True)  # fmt: skip
            if on_eval is not None:
                on_eval(so_far())

    t0 = time.perf_counter()
    trainer.train(
        environment=env,
        num_timesteps=int(num_timesteps),
        num_evals=int(num_evals),
        normalize_observations=bool(row.get("normalize_observations", True)),
        deterministic_eval=deterministic_eval,
        action_repeat=int(row.get("action_repeat", 1)),
        discounting=float(row["discounting"]),
        reward_scaling=float(row["reward_scaling"]),
        learning_rate=float(row["learning_rate"]),
        max_devices_per_host=1,
        seed=seed,
        progress_fn=progress,
        **extra,
        **{k: int(row[k]) for k in names},
    )
    return so_far()
