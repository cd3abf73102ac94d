"""Geodesy: the system plane, radar polar coordinates, units."""
