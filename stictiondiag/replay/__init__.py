"""Closed-loop replay: the fitted valve in the identified loop, compared with the data."""

from stictiondiag.replay.closed_loop import replay
from stictiondiag.replay.result import Replay

__all__ = ["Replay", "replay"]
