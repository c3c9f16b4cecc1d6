"""Closed-loop replay: the fitted valve in the identified loop, compared with the data."""

from stictiondiag.replay.closed_loop import Replay, replay

__all__ = ["Replay", "replay"]
