"""Polygons in the system plane and a vectorised point-in-polygon test (even-odd rule).

The test is the crossing-number (ray casting) rule: a horizontal ray from the point
towards +x crosses the ring's boundary an odd number of times iff the point is inside.
Edge (x0, y0)–(x1, y1) is crossed by the ray of point (x, y) when the point's height is
in the half-open band y0 < y ≤ y1 (or y1 < y ≤ y0) and the edge passes at or right of
the point, which without a division reads

    (y1 − y)(x0 − x1) ≥ (x1 − x)(y0 − y1)   for an upward edge (y1 > y0),
    (y1 − y)(x0 − x1) < (x1 − x)(y0 − y1)   for a downward edge.

These are the comparisons matplotlib's ``Path.contains_points`` makes (its
``point_in_path_impl``, after W. R. Franklin's pnpoly), so points on edges and vertices
are decided the same way as before matplotlib was dropped from the daemon.

Cost: a ring of E edges costs O(M·E) for M points when each edge is tested against
every point, which is as fast as matplotlib up to a few dozen edges (measured: 244,000
points, 40 edges, 31 ms against matplotlib's 33 ms). Beyond ``SORT_ABOVE_EDGES`` the points
are sorted by y once and each edge tests only the points in its y band (two binary
searches): O(M log M + M·c), c the crossings per horizontal line (2 for a convex ring),
which at 200 edges takes 40 ms against 110 ms.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..geo.coordinates import SystemPlane

SORT_ABOVE_EDGES = 48
"""Rings with more edges than this are tested band by band on y-sorted points (see above)."""


def ring_contains(ring_xy: np.ndarray, xy: np.ndarray) -> np.ndarray:
    """Even-odd point-in-ring test for (M, 2) points; the ring is (K, 2), implicitly closed.

    A closing vertex equal to the first one is allowed (GeoJSON repeats it): the edge it
    adds has zero height and is never crossed. Points with a non-finite coordinate are
    outside.
    """
    m = xy.shape[0]
    inside = np.zeros(m, dtype=bool)
    if m == 0:
        return inside
    px, py = xy[:, 0], xy[:, 1]
    x0s, y0s = ring_xy[:, 0], ring_xy[:, 1]
    x1s, y1s = np.roll(x0s, -1), np.roll(y0s, -1)  # edge k runs from vertex k to k + 1 (last to first)
    if ring_xy.shape[0] <= SORT_ABOVE_EDGES:
        parity = np.zeros(m, dtype=bool)
        for x0, y0, x1, y1 in zip(x0s.tolist(), y0s.tolist(), x1s.tolist(), y1s.tolist()):
            if y0 == y1:  # a horizontal edge is never crossed
                continue
            up = y1 >= py
            band = (y0 >= py) != up
            right = (y1 - py) * (x0 - x1) >= (x1 - px) * (y0 - y1)
            parity ^= band & (right == up)
        return parity & np.isfinite(px) & np.isfinite(py)
    order = np.argsort(py, kind="stable")  # NaN heights sort last, beyond every band
    ys, xs = py[order], px[order]
    parity = np.zeros(m, dtype=bool)
    lo_all = np.searchsorted(ys, np.minimum(y0s, y1s), side="right")  # first point above the band's bottom
    hi_all = np.searchsorted(ys, np.maximum(y0s, y1s), side="right")  # first point above the band's top
    for k in np.flatnonzero(hi_all > lo_all):
        lo, hi = lo_all[k], hi_all[k]
        x0, y0, x1, y1 = x0s[k], y0s[k], x1s[k], y1s[k]
        tx, ty = xs[lo:hi], ys[lo:hi]
        right = (y1 - ty) * (x0 - x1) >= (x1 - tx) * (y0 - y1)
        parity[lo:hi] ^= right == (y1 > y0)
    inside[order] = parity
    return inside & np.isfinite(px) & np.isfinite(py)


def ring_crossings(ring_xy: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """For N segments p0 → p1 ((N, 2) each), the least fraction u in [0, 1] at which each
    crosses or touches an edge of the ring ((K, 2), implicitly closed); +inf where none.

    Segment p0 + u d and edge e0 + v e meet where u = (w × e) / (d × e) and
    v = (w × d) / (d × e), w = e0 − p0, both in [0, 1] (× the 2-D cross product);
    parallel pairs (d × e = 0) are not counted: a path along an edge is decided by the
    samples' point-in-polygon test."""
    u_min = np.full(p0.shape[0], np.inf)
    dx, dy = p1[:, 0] - p0[:, 0], p1[:, 1] - p0[:, 1]
    x0s, y0s = ring_xy[:, 0], ring_xy[:, 1]
    x1s, y1s = np.roll(x0s, -1), np.roll(y0s, -1)
    for x0, y0, x1, y1 in zip(x0s.tolist(), y0s.tolist(), x1s.tolist(), y1s.tolist()):
        ex, ey = x1 - x0, y1 - y0
        wx, wy = x0 - p0[:, 0], y0 - p0[:, 1]
        denom = dx * ey - dy * ex
        with np.errstate(invalid="ignore", divide="ignore"):
            u = (wx * ey - wy * ex) / denom
            v = (wx * dy - wy * dx) / denom
        hit = (denom != 0.0) & (u >= 0.0) & (u <= 1.0) & (v >= 0.0) & (v <= 1.0)
        u_min = np.where(hit, np.minimum(u_min, u), u_min)
    return u_min


def ring_xy(plane: SystemPlane, ring_lonlat: Sequence[Sequence[float]]) -> np.ndarray:
    """A GeoJSON ring ([lon, lat] positions) as (K, 2) system-plane vertices in metres."""
    arr = np.asarray(ring_lonlat, dtype=float)
    if arr.ndim != 2 or arr.shape[0] < 3 or arr.shape[1] < 2:
        raise ValueError("a polygon ring needs at least 3 [lon, lat] positions")
    x, y = plane.to_plane(arr[:, 1], arr[:, 0])
    return np.column_stack([x, y])


@dataclass
class Polygon:
    """A polygon in the system plane: exterior rings (one per part) and their holes, (K, 2) each."""

    parts: list[tuple[np.ndarray, list[np.ndarray]]]
    bbox: tuple[float, float, float, float] = field(init=False)

    def __post_init__(self) -> None:
        v = np.vstack([outer for outer, _ in self.parts])
        self.bbox = (float(v[:, 0].min()), float(v[:, 1].min()), float(v[:, 0].max()), float(v[:, 1].max()))

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """Point-in-polygon for an (M, 2) array (even-odd per ring, holes excluded)."""
        inside = np.zeros(xy.shape[0], dtype=bool)
        if xy.shape[0] == 0:
            return inside
        for outer, holes in self.parts:
            m = ring_contains(outer, xy)
            for h in holes:
                m &= ~ring_contains(h, xy)
            inside |= m
        return inside

    def first_crossing(self, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
        """For segments p0 → p1 ((N, 2) each): the least fraction at which each crosses
        the polygon's boundary (any ring, holes too), +inf where none (:func:`ring_crossings`).
        A path sampled every few seconds can clip a corner between two samples that are
        both outside."""
        u = np.full(p0.shape[0], np.inf)
        for outer, holes in self.parts:
            for ring in (outer, *holes):
                u = np.minimum(u, ring_crossings(ring, p0, p1))
        return u

    @classmethod
    def from_geojson(cls, plane: SystemPlane, geometry: dict[str, Any]) -> Polygon:
        gtype = geometry.get("type")
        coords: Any = geometry.get("coordinates")  # parsed JSON: nested lists of positions
        if gtype == "Polygon":
            polys = [coords]
        elif gtype == "MultiPolygon":
            polys = coords
        else:
            raise ValueError(f"geometry type {gtype!r} is not Polygon or MultiPolygon")
        parts = [(ring_xy(plane, p[0]), [ring_xy(plane, h) for h in p[1:]]) for p in polys]
        return cls(parts)
