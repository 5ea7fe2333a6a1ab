"""Command-line entry points: ``python -m train.<algo>``."""
