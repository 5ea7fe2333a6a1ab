"""Agents: one sub-package per algorithm, each with ``make_train(config, env) -> train(key)``."""
