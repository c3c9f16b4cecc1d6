"""Imports every command module so each registers on :data:`cli.main.app`."""

# isort: skip_file
from . import analyze  # noqa: F401
from . import report  # noqa: F401
from . import scan  # noqa: F401
from . import validate  # noqa: F401
from . import simulate  # noqa: F401
from . import gap  # noqa: F401
from . import benchmark  # noqa: F401
from . import warmup  # noqa: F401
