"""Subcommands of ``demcal``; each module has a ``register(app)`` function."""
