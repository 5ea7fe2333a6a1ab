"""How a run's setting differs from the thesis's: the report generators list it under every table.

The thesis's setting of a row is the row's own command line with ``--preset thesis`` (Tables 3.2, 3.3,
4.2, 5.2, 5.3 and Eq. 3.21–3.23 as ``train.presets`` writes them), parsed as ``python -m train.<algo>``
parses it (:func:`thesis_setting`), with :data:`THESIS_ENV` (the thesis's plants) and :data:`THESIS_FIXES`
(where that preset itself keeps one of our decisions) over it. A run's setting is its ``config.json``:
the algorithm's section, and the env's (``env.config``, written by ``train.cli`` since it records it;
for older runs the env settings are those the run's command line gives with the code at hand, which
:func:`run_setting` says). :func:`differences` compares the two field by field; :func:`words` writes
the list.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import os
from collections.abc import Sequence
from typing import Any

THESIS_ENV: dict[str, dict[str, Any]] = {
    "unicycle": {"mode": "kinematic"},  # the thesis's Euler update of Eq. 3.18 (the env's default: dynamic)
    "arm7": {"mode": "kinematic"},  # V-REP's joints set to the IK solution (the env's default: pd servos)
    "arm7_precise": {"mode": "kinematic", "goal_threshold": 0.05},  # the thesis's goal is 5 cm
}
"""The thesis's plant where an env's default config is not it (every other default config field is the
thesis's value: Eq. 3.19-3.23 and §3.5's plants)."""

THESIS_FIXES: dict[tuple[str, str], dict[str, Any]] = {
    ("ddpg", "tracking"): {"actor_output": "sigmoid"},  # §3.5.2: sigmoid × C (ours: tanh, actions in [-1, 1])
}
"""``(algorithm family, row kind) -> fields``: the thesis's value where even the ``thesis`` preset keeps ours."""

ROW_FIELDS = frozenset({"trajectory", "reward", "obs"})
"""Env fields a row sets itself (its reference, reward, observation of the table's row): not deviations."""

IGNORED = frozenset({"per_tree", "episode_length", "seed", "seeds"})
"""Config fields that change how a run is computed or bookkept, not what it learns."""


def family(algo: str) -> str:
    """The presets' family of a ``train.<algo>``: ``ppo``, ``a2c`` (A2C and A3C) or ``ddpg`` (DDPG and TD3)."""
    return {"a3c": "a2c", "td3": "ddpg"}.get(algo, algo)


def cli_of(algo: str) -> Any:
    """The ``train.<algo>`` command line (:class:`train.cli.AlgorithmCLI`)."""
    if algo in ("a2c", "a3c"):
        return importlib.import_module("train.a2c").CLIS[algo]
    return importlib.import_module(f"train.{algo}").CLI


def env_name(argv: Sequence[str]) -> str:
    """The ``--env`` of a command line (``arm7`` where it gives none, the CLIs' default)."""
    argv = list(argv)
    return argv[argv.index("--env") + 1] if "--env" in argv else "arm7"


def _plain(x: Any) -> Any:
    """JSON's view of a value (tuples as lists), so that a config read from ``config.json`` compares equal."""
    return json.loads(json.dumps(x))


def env_config(name: str, settings: dict[str, Any]) -> dict[str, Any]:
    """The full config of env ``name`` under ``settings`` (its default config's fields, ``settings`` over
    them); ``{}`` for an env without a config dataclass (brax's)."""
    import envs_mjx

    if name not in envs_mjx.names():
        return {}
    return _plain(dataclasses.asdict(envs_mjx.make(name, **settings).config))


def thesis_setting(algo: str, argv: Sequence[str], kind: str) -> tuple[dict[str, Any], dict[str, Any]]:
    """``(algorithm config, env config)`` of the thesis for a row ``python -m train.<algo> argv`` of ``kind``
    (``arm``, ``tracking``, ``driving``): ``argv`` with ``--preset thesis``, :data:`THESIS_ENV` and
    :data:`THESIS_FIXES` over it."""
    cli = cli_of(algo)
    args = cli.parse([*argv, "--preset", "thesis"])
    config = _plain(dataclasses.asdict(getattr(args, cli.name)))
    config.update(_plain(THESIS_FIXES.get((family(algo), kind), {})))
    name = env_name(argv)
    env = env_config(name, {**cli.env_settings(args), **THESIS_ENV.get(name, {})})
    env.update(_plain(THESIS_ENV.get(name, {})))
    return config, env


def run_setting(algo: str, config_json: dict[str, Any]) -> tuple[dict[str, Any], dict[str, Any], str]:
    """``(algorithm config, env config, source)`` of a run from its ``config.json``: the env config as the run
    recorded it (``env.config``), else rebuilt from the command line it saved with the code at hand
    (``source`` says which)."""
    cli = cli_of(algo)
    config = _plain(config_json[cli.name])
    recorded = (config_json.get("env") or {}).get("config")
    if recorded is not None:
        return config, _plain(recorded), "the run's config.json"
    saved = config_json.get("args", {})
    argv = ["--env", saved.get("env", "arm7"), "--preset", saved.get("preset", "auto")]
    argv += ["--env-config", *saved["env_config"]] if saved.get("env_config") else []
    argv += ["--reward", saved["reward"]] if saved.get("reward") else []
    argv += ["--trajectory", saved["trajectory"]] if saved.get("trajectory") else []
    section = config_json[cli.name]
    argv += ["--distributed"] if section.get("distributed") else []
    for k in ("policy", "pretrain"):
        if k in section:
            argv += [f"--{k}", str(section[k])]
    args = cli.parse(argv)
    source = ("the run's config.json; the env's settings rebuilt from its command line by the code at hand (the "
              "run did not record them)")
    return config, env_config(saved.get("env", "arm7"), cli.env_settings(args)), source


def differences(ours: dict[str, Any], thesis: dict[str, Any], ignore: frozenset[str] = IGNORED) -> list[tuple]:
    """``[(field, thesis's value, ours)]`` for every field of ``thesis`` whose value ``ours`` does not share
    (a field ``ours`` lacks is left out), in ``thesis``'s order; ``ignore``: fields left out."""
    return [(k, v, ours[k]) for k, v in thesis.items() if k not in ignore and k in ours and _plain(ours[k]) != v]


def _value(v: Any) -> str:
    if isinstance(v, list | tuple):
        return "(" + ", ".join(_value(x) for x in v) + ")" if v else "()"
    if isinstance(v, bool) or v is None:
        return str(v)
    if v == "":
        return '""'
    if isinstance(v, int) and abs(v) >= 10_000:
        return f"{v:,}".replace(",", " ")
    if isinstance(v, float):
        return f"{v:g}"
    return str(v)


def words(env: list[tuple], algo: list[tuple]) -> str:
    """One row's deviations in words: ``env a_p 1 → 300, mode kinematic → dynamic; gamma 0.9 → 0.99``
    (the thesis's value first); ``none`` where there are none."""
    parts = [", ".join(f"{k} {_value(t)} → {_value(o)}" for k, t, o in diffs) for diffs in (env, algo)]
    text = "; ".join(p for p in (f"env {parts[0]}" if parts[0] else "", parts[1]) if p)
    return text or "none"


def row_deviations(algo: str, argv: Sequence[str], kind: str, config_json: dict[str, Any] | None,
                   preset: str) -> dict[str, Any]:  # fmt: skip
    """A row's deviations from the thesis: ``{"env": [...], "algo": [...], "source": ..., "text": ...}``
    (:func:`differences` of :func:`run_setting` or, without a ``config.json``, of the row's command line with
    ``--preset preset`` as the code at hand parses it, against :func:`thesis_setting`)."""
    thesis_algo, thesis_env = thesis_setting(algo, argv, kind)
    if config_json is not None:
        ours_algo, ours_env, source = run_setting(algo, config_json)
    else:
        cli = cli_of(algo)
        args = cli.parse([*argv, "--preset", preset])
        ours_algo = _plain(dataclasses.asdict(getattr(args, cli.name)))
        ours_env = env_config(env_name(argv), cli.env_settings(args))
        source = f"the row's command line with --preset {preset}, parsed by the code at hand (no config.json kept)"
    env_ignore = IGNORED | ROW_FIELDS
    env, alg = differences(ours_env, thesis_env, env_ignore), differences(ours_algo, thesis_algo)
    return {"env": env, "algo": alg, "source": source, "text": words(env, alg)}


def kept_config(results: str, stem: str, table: str, row: str) -> dict[str, Any] | None:
    """The ``config.json`` kept for a row of a thesis report (``<results>/runs/<stem>/<table>/<row>/…``, the
    first seed's), None where none was kept."""
    root = os.path.join(results, "runs", os.path.basename(stem), table, row)
    for folder, _, files in sorted(os.walk(root)):
        if "config.json" in files:
            with open(os.path.join(folder, "config.json")) as f:
                return json.load(f)
    return None
