"""The ``climbd`` commands: the top layer, which wires the runtime to drivers and the twin."""

from climbd.daemon.cli.main import main

__all__ = ["main"]
