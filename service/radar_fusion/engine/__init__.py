"""The sans-I/O core: plots in, track batches out (DESIGN.md §2). No bus, no clock, no files."""

from .columns import PeriodOutput, TrackColumns
from .engine import Engine

__all__ = ["Engine", "PeriodOutput", "TrackColumns"]
