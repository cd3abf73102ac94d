"""radar-fusion: multi-radar data fusion and tracking for air traffic control."""

__version__ = "0.1.0"
