"""Imports every command module so each registers on :data:`cli.main.app`."""
from . import analyze  # noqa: F401
from . import scan  # noqa: F401
