"""Subcommands of ``meris-ortho``: each module has ``register(subparsers)``."""
