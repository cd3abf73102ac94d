"""The sans-I/O core: plots in, track batches out (DESIGN.md §2). No bus, no clock, no files."""

from .engine import Engine, PeriodOutput, TrackColumns

__all__ = ["Engine", "PeriodOutput", "TrackColumns"]
