"""Subcommands of ``skin``, one module each."""
