"""Our PPO beside brax's own on brax's standard tasks (our TD3 / DDPG beside brax's SAC with ``--algo``):
return at equal env steps, wall time, steps/s.

    python -m benchmarks.brax_tasks                                   # 5 tasks, 3 seeds, brax's budgets
    python -m benchmarks.brax_tasks --tasks inverted_pendulum --seeds 3
    python -m benchmarks.brax_tasks --tasks reacher --steps 5000000    # a shorter budget for both
    python -m benchmarks.brax_tasks --algo td3 --tasks hopper --steps 1000000   # off-policy: brax's SAC beside
    python -m benchmarks.brax_tasks --tasks halfcheetah --no-brax --ours activation=swish state_std=true \
        tanh_actions=true clip_actions=false                           # brax's policy parametrisation
    python -m benchmarks.brax_tasks --tasks hopper --ours segments=true   # brax's update (advantage_segment)
    python -m benchmarks.brax_tasks --tasks reacher --no-brax --devices 2 --seed-map loop   # each seed on 2 GPUs

Off-policy (``--algo td3``, ``ddpg`` or ``sac``; SAC takes DDPG's config, :func:`train.sac.sac_config`): the
tasks brax trains with SAC (:data:`train.presets.BRAX_SAC`,
hopper and walker2d), brax's ``sac.train`` with the row as it is, ours through
:func:`train.presets.brax_sac_ddpg_config`: the same envs, memory and networks, with TD3's own settings
(mini-batches of 256, γ 0.99, unscaled rewards) and two updates per env step on hopper and walker2d
(:data:`train.presets.BRAX_SAC_TUNED`; ``--ours tuned=false``: TD3's one; ``--ours own_settings=false``:
the row's ``grad_updates_per_step`` per ``num_envs`` env steps, discount and reward scaling), for the
env steps brax's SAC makes of the budget (:func:`brax_sac_steps`), split into update calls that end on
that count where it allows (:func:`update_chunk`). The updates
dominate the wall time: where env steps are cheap (thousands of simulated lanes) PPO's budget of 10–50 M
steps usually takes less time than the off-policy budget of a few million, and an off-policy method
is the tool when env steps are what costs (a real robot, a slow simulator).

Both train on the same env object (``brax.envs.get_environment(task, backend=--backend)``, MJX by
default) for the same env steps with the settings of :data:`train.presets.BRAX_PPO`: brax's
``ppo.train`` takes the row as it is; ours takes it through :func:`train.presets.brax_ppo_config`,
with our fields of :data:`train.presets.BRAX_PPO_TUNED` over it on the tasks that table names
(``--ours tuned=false``: the row alone; ``python -m train.ppo --env brax:<task>`` picks the same
preset). Our seeds run through one compiled program called per seed (``--seed-map vmap``: one vmapped
program), brax's one after another.

* **return**: brax: its own final evaluation (``eval/episode_reward``, 128 episodes of
  ``episode_length`` steps) of its policy's sampled actions (brax's default; PPO's unless
  ``--eval-mode`` says otherwise) or, with ``--eval-mode deterministic`` (TD3's and DDPG's default), of
  its mean action (``deterministic_eval``); ours: ``--eval-episodes`` fresh episodes
  of the same length (:func:`jaxrl_robot.evaluation.run_test_episodes`) in the same mode
  (``Trainer.sample_policy`` for sampled actions; TD3 and DDPG have only their deterministic policy), and
  with the mean action beside it (both modes' episodes in one rollout,
  :func:`jaxrl_robot.evaluation.two_policies`). Mean ± std over seeds; the goal compares returns of the
  same mode.
* **wall**: from the call to the trained parameters, compilation included (per seed: the seeds' total
  over their number); brax's includes the ``--evals`` evaluations (10 unless given) its trainer runs
  along the way (128 episodes each), ours its evaluations at the same points (:func:`eval_points`, twice
  the episodes: both modes); **env steps/s**: env steps of all seeds over that wall time. On a short
  off-policy budget the evaluations can take most of the wall: ``--evals 3`` evaluates before training,
  half-way and at the end.

MuJoCo Playground's tasks (``--tasks playground:<Name>`` of its ``dm_control_suite``; the ``playground``
extra): the row is Playground's own ``brax_ppo_config`` / ``brax_sac_config``
(:func:`train.presets.playground_row`: its steps, envs, batch, unroll, epochs, mini-batches, discount, reward
scaling, learning rate, entropy cost, normalisation, episode length, action repeat), brax's side trains the
Playground env wrapped by Playground's ``wrapper.wrap_for_brax_training`` (as Playground's training scripts
do), ours the same env object through :class:`envs_mjx.playground.PlaygroundEnv`, converted as brax's rows
(:func:`train.presets.ppo_config_of_row`, brax's own update; :func:`train.presets.ddpg_config_of_sac_row`);
``--env-config`` gives Playground's ``config_overrides`` (``impl=jax`` unless given)::

    python -m benchmarks.brax_tasks --tasks playground:CartpoleBalance playground:CartpoleSwingup \
        playground:PendulumSwingup playground:ReacherEasy playground:CheetahRun playground:WalkerWalk \
        --seeds 3 --label playground                                # Playground's own step counts

Each side's record is written as it grows (ours with ``--seed-map vmap``: after every evaluation; seeds
one after another: after every evaluation of the first seed, then after every seed), so a run cut short
(a time limit) leaves its evaluations so far, shown as ``cut at N steps`` and not compared with the other
side.

Goals: per task our return ≥ brax's and our wall per seed ≤ brax's. Results:
``benchmarks/results/<device>-brax_tasks[-<algo>].json`` and ``.md`` with one learning-curve figure per task.
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Callable
from typing import Any

import jax

from benchmarks import provenance
from benchmarks import seeds as bench_seeds
from benchmarks.arguments import at_least, nonnegative, positive
from benchmarks.brax_tasks_merge import (
    merge,
    missing,  # noqa: F401  (read here by the tests)
    stem_of,
    write,
)
from benchmarks.brax_tasks_report import (
    ALGOS,
    EVAL_MODES,
    PLAYGROUND,
    default_eval_mode,
    is_playground,
    to_markdown,  # noqa: F401  (read here by the tests)
)
from benchmarks.brax_tasks_sides import (  # noqa: F401  (read here by the tests)
    our_config,
    our_trainer,
    ours,
    theirs,
    update_chunk,
)
from benchmarks.tracking_report import pairs
from benchmarks.train_throughput import RESULTS, device_label
from envs_mjx.config import ConfigError
from train.presets import (
    BRAX_PPO,
    BRAX_SAC,
    playground_row,
    playground_task,
)


def brax_row(task: str, num_envs: int, algo: str = "ppo") -> dict[str, float]:
    """The task's row of ``algo``'s table (a ``playground:<Name>`` task: MuJoCo Playground's own settings of
    ``algo``'s brax peer, :func:`train.presets.playground_row`); with ``num_envs`` that many envs (PPO: the
    batch scaled alike, the same unrolls per env and mini-batches per pass: a small machine's version of the
    task)."""
    row = playground_row(task, ALGOS[algo][1]) if is_playground(task) else dict(ALGOS[algo][2][task])
    if num_envs:
        if algo == "ppo":
            row["batch_size"] = max(1, int(row["batch_size"] * num_envs) // int(row["num_envs"]))
        row["num_envs"] = num_envs
    return row


def whole_epochs(steps: int, per_step: int, num_evals: int) -> int:
    """The env steps of ``num_evals − 1`` epochs (at least one) of whole training steps of ``per_step`` env
    steps that cover ``steps``: each epoch ``ceil`` of its share of the budget, as brax's trainers count."""
    epochs = max(num_evals - 1, 1)
    return epochs * per_step * -(-max(steps, 0) // (epochs * per_step))


def brax_ppo_steps(row: dict[str, float], steps: int, num_evals: int = 10) -> int:
    """The env steps brax's ``ppo.train`` makes of a ``steps`` budget: whole training steps of
    ``batch_size · num_minibatches · unroll_length · action_repeat`` env steps, ``ceil`` of the budget over
    ``num_evals − 1`` epochs of them (brax/training/agents/ppo/train.py), so never fewer than ``steps``; with
    the row's ``num_resets_per_eval`` R (MuJoCo Playground's rows: 10) an epoch is R rounds of ``ceil`` of
    the budget over ``(num_evals − 1) · R`` training steps."""
    per_step = int(row["batch_size"]) * int(row["num_minibatches"]) * int(row["unroll_length"])
    resets = max(int(row.get("num_resets_per_eval", 0)), 1)
    return whole_epochs(steps, per_step * int(row.get("action_repeat", 1)) * resets, num_evals)


def brax_sac_steps(row: dict[str, float], steps: int, num_evals: int = 10) -> int:
    """The env steps brax's ``sac.train`` makes of a ``steps`` budget (brax/training/agents/sac/train.py):
    a prefill of ``ceil(min_replay_size / num_envs)`` actor steps, then ``num_evals − 1`` epochs of
    ``ceil((steps − prefill) / ((num_evals − 1) · num_envs · action_repeat))`` actor steps each, an actor
    step being ``num_envs · action_repeat`` env steps; so never fewer than ``steps``."""
    per_step = int(row["num_envs"]) * int(row.get("action_repeat", 1))
    prefill = -(-int(row["min_replay_size"]) // int(row["num_envs"])) * per_step
    return prefill + whole_epochs(steps - prefill, per_step, num_evals)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--algo", default="ppo", choices=list(ALGOS), help="ours: ppo (brax's PPO beside) or td3 / ddpg / "
                   "sac (brax's SAC beside)")  # fmt: skip
    p.add_argument("--tasks", nargs="+", default=None, metavar="TASK",
                   help=f"PPO: {', '.join(BRAX_PPO)} (default: all); TD3 / DDPG: {', '.join(BRAX_SAC)} (default: all)")
    p.add_argument("--seeds", type=positive, default=3)
    p.add_argument("--purpose", default="tune", choices=bench_seeds.PURPOSES,
                   help="both sides' seeds: the tuning range or the report range, which no tuning run draws "
                   "(benchmarks.seeds)")  # fmt: skip
    p.add_argument("--brax-seeds", type=nonnegative, default=0, help="brax's seeds (0: --seeds)")
    p.add_argument("--brax-first-seed", type=nonnegative, default=0,
                   help="brax's first seed in the purpose's range (its seeds split over invocations, e.g. two GPUs, "
                   "then --merge)")  # fmt: skip
    p.add_argument("--steps", type=nonnegative, default=0, help="env steps per seed (0: brax's budget of the task)")
    p.add_argument("--backend", default="mjx", help="brax physics backend (mjx, generalized, positional, spring)")
    p.add_argument("--env-config", nargs="*", default=[], metavar="KEY=VALUE",
                   help="playground:<Name> tasks: MuJoCo Playground's config_overrides (impl=jax unless given, e.g. "
                   "impl=warp)")  # fmt: skip
    p.add_argument("--eval-episodes", type=positive, default=128)
    p.add_argument("--evals", type=at_least(2), default=10,
                   help="evaluations of each side along training, the first before it (brax's num_evals; at "
                   "least 2); fewer cost less where they take much of a short run")  # fmt: skip
    p.add_argument("--eval-mode", default=None, choices=EVAL_MODES,
                   help="final evaluation of both sides: sampled actions (PPO's default, brax's) or the mean "
                   "action (TD3's and DDPG's default: they act deterministically); ours is also evaluated "
                   "with its mean action either way")  # fmt: skip
    p.add_argument("--num-envs", type=nonnegative, default=0,
                   help="envs of both trainers, batch scaled alike (0: the row's)")
    p.add_argument("--row", nargs="*", default=[], metavar="KEY=VALUE",
                   help="settings of both trainers in brax's terms over the task's row (e.g. min_replay_size=1024)")
    p.add_argument("--ours", nargs="*", default=[], metavar="KEY=VALUE",
                   help="our config's fields over the preset (PPOConfig / DDPGConfig), e.g. activation=swish "
                   "tanh_actions=true clip_actions=false")  # fmt: skip
    p.add_argument("--no-brax", action="store_true", help="ours only")
    p.add_argument("--no-ours", action="store_true", help="brax's only (e.g. on another GPU, then --merge)")
    p.add_argument("--merge", nargs="+", default=None, metavar="JSON",
                   help="write one report from results files of this benchmark (e.g. ours and brax's run on two "
                   "GPUs at once): per task, our side and brax's from the files that ran them")  # fmt: skip
    p.add_argument("--brax-from", nargs="+", default=[], metavar="JSON",
                   help="with --merge: brax's side alone from these results files (e.g. brax's SAC beside our TD3, "
                   "now beside our SAC); their own side of ours is left out")  # fmt: skip
    p.add_argument("--seed-map", default="loop", choices=["loop", "vmap"],
                   help="our seeds: one program called per seed, or one vmapped program (an accelerator's only: "
                   "XLA's CPU compiler stops with a floating point exception on the vmapped MJX program, "
                   "jax 0.10.2)")  # fmt: skip
    p.add_argument("--devices", type=nonnegative, default=1,
                   help="devices our lanes are spread over (0: all; more than 1 with --seed-map loop)")
    p.add_argument("--out", default=RESULTS)
    p.add_argument("--label", default="", help="appended to the results files' name (e.g. 5M)")
    p.add_argument("--note", default="", help="a paragraph written under the table (e.g. how to read it)")
    provenance.add_args(p)
    args = p.parse_args(argv)
    if args.brax_from and not args.merge:
        p.error("--brax-from: only with --merge (the files whose side of ours is merged)")
    if args.merge:
        return merge(args.merge, args.out, argv, args.label, args.note, args.brax_from)
    if args.no_brax and args.no_ours:
        p.error("--no-brax and --no-ours: nothing would run; give at most one")
    if not 0 <= args.devices <= jax.device_count():
        p.error(f"--devices {args.devices}: this machine has {jax.device_count()} (0: all of them)")
    if args.seed_map == "vmap" and not args.no_ours and jax.default_backend() == "cpu":
        p.error("--seed-map vmap: on the CPU, XLA stops with a floating-point exception compiling our trainer "
                "vmapped over seeds on brax's MJX envs (jax 0.10.2); use --seed-map loop")
    if args.seed_map == "vmap" and args.seeds > 1 and (args.devices or jax.device_count()) > 1:
        p.error(f"--seed-map vmap runs its {args.seeds} seeds on one device; add --devices 1 or --seed-map loop")
    args.eval_mode = args.eval_mode or default_eval_mode(args.algo)
    if args.evals < 2:
        p.error(f"--evals {args.evals}: at least 2 (one before training, one at its end)")
    table = ALGOS[args.algo][2]
    args.tasks = args.tasks or list(table)
    try:
        unknown = [t for t in args.tasks if not (playground_task(t, args.algo) if is_playground(t) else t in table)]
    except ValueError as e:  # MuJoCo Playground is not installed
        p.error(f"--tasks: {e}")
    if unknown:
        p.error(f"--tasks {unknown[0]!r}: no brax settings for --algo {args.algo}; valid: {', '.join(table)} or "
                f"{PLAYGROUND}<Name> of MuJoCo Playground's dm_control_suite")  # fmt: skip
    overrides = pairs(args.ours)
    try:  # a bad --ours field ends here with one line, before anything trains
        our_config(args.algo, args.tasks[0], 1, brax_row(args.tasks[0], args.num_envs, args.algo), 1, overrides)
    except ConfigError as e:
        p.error(f"--ours: {e}")
    from brax import envs as brax_envs

    brax_seeds = args.brax_seeds or args.seeds
    try:
        our_ids = bench_seeds.seed_ids(args.purpose, args.seeds)
        brax_ids = bench_seeds.seed_ids(args.purpose, brax_seeds, args.brax_first_seed)
    except ValueError as e:
        p.error(f"--seeds/--brax-first-seed: {e}")
    prov = provenance.record("benchmarks.brax_tasks", argv, allow_dirty=args.allow_dirty,
                             seeds=bench_seeds.record(args.purpose, our_ids, "ours: training key PRNGKey(seed), "
                                                      f"evaluation key fold_in(PRNGKey(seed), EVAL_KEY_OFFSET); brax: "
                                                      f"its seed argument {brax_ids[0]}..{brax_ids[-1]}"))  # fmt: skip
    stem = stem_of(args.out, device_label(), args.algo, args.label)
    env_config = pairs(args.env_config)
    result = {"benchmark": "brax_tasks", "algo": args.algo, "provenance": prov, "device": device_label(),
              "backend": args.backend, **({"note": args.note} if args.note else {}),
              **({"playground_config": {"impl": "jax", **env_config}} if any(map(is_playground, args.tasks)) else {}),
              "seeds": args.seeds, "seed_map": args.seed_map, "brax_seeds": brax_seeds,
              "eval_episodes": args.eval_episodes, "evals": args.evals,
              "figures": stem + "-figures", "tasks": []}  # fmt: skip
    os.makedirs(result["figures"], exist_ok=True)
    for task in args.tasks:
        env, theirs_env, wrap_env_fn = playground_envs(task, env_config) if is_playground(task) else (
            (brax_envs.get_environment(task, backend=args.backend),) * 2 + (None,))  # fmt: skip
        published = brax_row(task, args.num_envs, args.algo)
        steps = args.steps or int(published["num_timesteps"])
        settings = {**published, **pairs(args.row)}
        counts = brax_ppo_steps if args.algo == "ppo" else brax_sac_steps
        our_steps = counts(settings, steps, args.evals)  # brax's count of env steps
        row = {"task": task, "settings": settings, "sides": []}
        result["tasks"].append(row)
        if not args.no_ours:
            row["sides"].append("ours")  # before it runs: a run cut short keeps its evaluations so far

            def ours_so_far(record: dict[str, Any], row: dict[str, Any] = row) -> None:  # a killed run keeps it
                row["ours"] = record
                write(stem, result)

            row["ours"] = ours(env, task, settings, our_steps, args.seeds, args.eval_episodes, args.seed_map,
                               args.algo, args.eval_mode, overrides, args.evals, ours_so_far,
                               args.devices, our_ids)  # fmt: skip
            print(task, "ours", [round(r, 1) for r in row["ours"]["returns"]], f"{row['ours']['wall_s']:.0f} s",
                  flush=True)  # fmt: skip
        if not args.no_brax:
            row["sides"].append("brax")

            def partial(record: dict[str, Any], row: dict[str, Any] = row) -> None:  # a killed run keeps its seeds
                row["brax"] = record
                write(stem, result)

            theirs(theirs_env, settings, steps, brax_seeds, ALGOS[args.algo][1], partial, args.eval_mode,
                   brax_ids[0], args.evals, wrap_env_fn)
            print(task, "brax", [round(r, 1) for r in row["brax"]["returns"]], f"{row['brax']['wall_s']:.0f} s",
                  flush=True)  # fmt: skip
        write(stem, result, echo=task == args.tasks[-1])
    return result


def playground_envs(task: str, config_overrides: dict[str, Any]) -> tuple[Any, Any, Callable[..., Any]]:
    """``(ours, brax's, wrap_env_fn)`` of a ``playground:<Name>`` task: one Playground env object
    (``impl='jax'`` unless ``config_overrides`` say otherwise), ours through :class:`envs_mjx.playground.PlaygroundEnv`,
    brax's as it is with Playground's ``wrapper.wrap_for_brax_training``, as Playground's training scripts
    wrap it for brax's trainers."""
    from envs_mjx import playground

    ours_env = playground.load(task, **config_overrides)
    return ours_env, ours_env.env, playground.require().wrapper.wrap_for_brax_training


if __name__ == "__main__":
    main()
