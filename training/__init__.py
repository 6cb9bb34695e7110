"""Command-line entry points: ``run`` (train), ``evaluate``."""
