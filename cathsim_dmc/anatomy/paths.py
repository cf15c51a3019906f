"""Distances along the vessel: where a point lies on the centerline tree, and how far it is
from a target when travelling inside the lumen.

An asset's centerlines all start at the entry and share the trunk (descending aorta,
arch) before each turns into its branch. A tip in a wrong branch must first come back to
the junction, so the distance that matters for navigation is measured along the tree:

    geodesic = (way back to the junction) + (junction to target along the target's line)

plus how far the point lies outside every centerline's tube (the ascending aorta, which
no entry-to-site centerline covers). Pure numpy: no simulator needed.
"""

from __future__ import annotations

from typing import Mapping

import numpy as np


def deepest_on_polyline(
    points, arclength_m, radius, point, s_min: float = -np.inf, s_max: float = np.inf, segments=None
) -> tuple:
    """(arc length, depth outside the tube) where `point` lies deepest inside the tube of
    `points` (N x 2 or N x 3) +- `radius` (per point), over arc lengths in [s_min, s_max].

    `arclength_m` gives each point's arc length (the polyline's own, or a 3-D line's for
    its projection: t along a projected segment is t along the 3-D one). `segments`, for a
    polyline queried often: (segment vectors, their squared lengths, their arc lengths),
    computed once. Each segment is searched over its part inside the window, so a window
    within one long segment, or a point whose nearest point on a segment lies outside the
    window, still gets the deepest point of the window's stretch. An empty window
    (s_min > s_max, or beyond the line) raises ValueError.
    """
    p = np.asarray(point, dtype=float)
    a, starts = points[:-1], arclength_m[:-1]
    if segments is None:
        seg = np.diff(points, axis=0)
        segments = (seg, np.einsum("ij,ij->i", seg, seg), np.diff(arclength_m))
    seg, length_sq, seg_s = segments
    t = np.einsum("ij,ij->i", p - a, seg) / np.maximum(length_sq, 1e-18)
    inside = True
    if np.isfinite(s_min) or np.isfinite(s_max):
        inside = (arclength_m[1:] >= s_min) & (starts <= s_max)
        if not inside.any():
            raise ValueError(
                f"arc length window [{s_min}, {s_max}] m holds no part of the line (0 to {arclength_m[-1]} m)"
            )
        # each segment's part inside the window, as a range of t
        with np.errstate(divide="ignore", invalid="ignore"):
            lo = np.clip(np.where(seg_s > 0, (s_min - starts) / seg_s, 0.0), 0, 1)
            hi = np.clip(np.where(seg_s > 0, (s_max - starts) / seg_s, 1.0), 0, 1)
        t = np.clip(t, lo, hi)
    else:
        t = np.clip(t, 0, 1)
    s = starts + t * seg_s
    depth = np.linalg.norm(a + t[:, None] * seg - p, axis=1) - np.interp(s, arclength_m, radius)
    depth = np.where(inside, depth, np.inf)
    i = int(np.argmin(depth))
    return float(s[i]), float(depth[i])


class CenterlinePath:
    """One polyline with its lumen radius: arc length, closest-point queries, interpolation.

    The line is continued straight for `extension_m` past its last point, so that a tip
    which overshoots the end gets an arc length beyond `length_m` instead of being clamped.
    """

    def __init__(self, points_m, radius_m, extension_m: float = 0.03):
        points = np.asarray(points_m, dtype=float)
        radius = np.broadcast_to(np.asarray(radius_m, dtype=float), (len(points),))
        end_direction = points[-1] - points[-2]
        end_direction /= np.linalg.norm(end_direction)
        self.points = np.vstack([points, points[-1] + extension_m * end_direction])
        self.radius = np.append(radius, radius[-1])
        self._seg = np.diff(self.points, axis=0)
        self._seg_len = np.linalg.norm(self._seg, axis=1)
        self.arclength = np.concatenate([[0.0], np.cumsum(self._seg_len)])
        self.length_m = float(self.arclength[-2])  # arc length of the last given point (the site)
        self._segments = (self._seg, self._seg_len**2, self._seg_len)  # for locate, every step

    def locate(self, point_m, s_min: float = -np.inf, s_max: float = np.inf) -> tuple[float, float]:
        """(arc length, depth outside the tube) of `point_m`, over arc lengths in [s_min, s_max].

        The tube is the centerline +- the lumen radius. The arc length chosen is where the
        point lies deepest inside it, so near an ostium a tip in the parent vessel is placed
        in the parent, not in the closer but narrower start of the branch. A negative depth
        means inside the tube.
        """
        return deepest_on_polyline(self.points, self.arclength, self.radius, point_m, s_min, s_max, self._segments)

    def at(self, s_m: float) -> np.ndarray:
        s = float(np.clip(s_m, 0.0, self.arclength[-1]))
        return np.array([np.interp(s, self.arclength, self.points[:, k]) for k in range(3)])

    def aim_error(self, tip_m, tip_base_m, shaft, s_m: float, lookahead_m: float) -> tuple[float, float]:
        """How far an angled tip's bend is turned from where the line goes next.

        The bend is the tip seen from the base of its curve, across the shaft (`shaft`: a
        unit vector along the wire at the tip base); the aim is the line's point
        `lookahead_m` past `s_m` (the site at most), seen the same way. Returns (signed
        angle from bend to aim about the shaft in radians, off-axis share of the aim):
        the share is the aim's component across the shaft over its length, near 0 when
        the line runs straight ahead and the bend's direction does not matter.
        """
        tip, base, axis = (np.asarray(v, dtype=float) for v in (tip_m, tip_base_m, shaft))
        aim_point = self.at(min(s_m + lookahead_m, self.length_m))
        bend = component_across(tip - base, axis)
        aim = component_across(aim_point - base, axis)
        off_axis = float(np.linalg.norm(aim) / max(np.linalg.norm(aim_point - base), 1e-12))
        return signed_angle_rad(bend, aim, axis), off_axis

    def radius_at(self, s_m: float) -> float:
        return float(np.interp(s_m, self.arclength, self.radius))

    def distance_to_polyline_m(self, other: "CenterlinePath") -> np.ndarray:
        """Distance of each of this line's given points to `other`'s polyline (extension excluded)."""
        a, seg, seg_len = other.points[:-2], other._seg[:-1], other._seg_len[:-1]
        p = self.points[:-1, None, :]
        t = np.clip(np.einsum("nij,ij->ni", p - a, seg) / np.maximum(seg_len**2, 1e-18), 0, 1)
        return np.linalg.norm(a + t[..., None] * seg - p, axis=2).min(axis=1)


class CenterlineTree:
    """The asset's centerlines as a tree rooted at the entry, with distances along it.

    Args:
      centerlines: name -> (points (n, 3) in metres from the entry to the site, lumen
        radius in metres at each point).
      junction_tolerance_m: two lines are one vessel while they stay this close; the
        junction is where one leaves the other.
      tie_tolerance_m: on a shared stretch every line is equally deep; a line within this
        of the deepest counts as a tie and the target's own line wins.
    """

    def __init__(
        self, centerlines: Mapping[str, tuple], junction_tolerance_m: float = 1e-3, tie_tolerance_m: float = 0.5e-3
    ):
        self.lines = {name: CenterlinePath(points, radius) for name, (points, radius) in centerlines.items()}
        self._tie = float(tie_tolerance_m)
        # junction[(a, b)]: arc length along a where a leaves b.
        self._junction = {}
        for a, line_a in self.lines.items():
            for b, line_b in self.lines.items():
                if a == b:
                    continue
                apart = np.flatnonzero(line_a.distance_to_polyline_m(line_b) > junction_tolerance_m)
                index = apart[0] if len(apart) else len(line_a.points) - 2
                self._junction[(a, b)] = float(line_a.arclength[max(index - 1, 0)])

    @classmethod
    def from_asset(cls, asset, **kwargs) -> "CenterlineTree":
        """The tree of an `AortaAsset` (its `centerlines`: name -> (points, radius_m))."""
        return cls({name: (line.points, line.radius) for name, line in asset.centerlines.items()}, **kwargs)

    def junction_arclength_m(self, line: str, target: str) -> float:
        """Arc length along `line` at which it leaves `target`'s line (the ostium it turns into)."""
        return self._junction[(line, target)]

    def locate(self, point_m, prefer: str | None = None) -> tuple[str, float, float]:
        """(line name, arc length, depth outside its tube) where `point_m` lies deepest.

        On a stretch that several lines share they tie; `prefer` (if within the tie
        tolerance) wins, otherwise the first deepest line.
        """
        found = {name: line.locate(point_m) for name, line in self.lines.items()}
        best = min(found, key=lambda name: found[name][1])
        if prefer is not None and found[prefer][1] <= found[best][1] + self._tie:
            best = prefer
        s, depth = found[best]
        return best, s, depth

    def geodesic_distance_m(self, point_m, target: str) -> float:
        """Distance from `point_m` to `target`'s site travelling inside the vessel, in metres.

        Along the target's own line it is the remaining arc length (the overshoot past the
        site counts too). In another line past its junction with the target's, it is the way
        back to the junction plus the way on from there. A point outside every tube adds
        its depth outside (the ascending aorta has no centerline of its own).
        """
        return self.geodesic_from_location(self.locate(point_m, prefer=target), target)

    def geodesic_from_location(self, location: tuple[str, float, float], target: str) -> float:
        """`geodesic_distance_m` for a point already located (`locate(point, prefer=target)`)."""
        name, s, depth = location
        target_line = self.lines[target]
        if name == target:
            along = abs(target_line.length_m - s)
        else:
            junction = self.junction_arclength_m(name, target)
            if s <= junction:
                along = target_line.length_m - s
            else:
                along = (s - junction) + (target_line.length_m - self.junction_arclength_m(target, name))
        return float(along + max(depth, 0.0))


class WrongBranchMemory:
    """The wrong branches a tip has entered on its way to `target`, and which way each heads.

    `note(tip_m)`, called while the tip is lost (outside the tube of the path to the
    target), remembers the branch whose tube the tip is in (once per branch; `note_branch`
    when the caller has found the branch itself, as the image tracker does): the arc length
    along the target's path where the branch leaves it and the branch's heading from its
    ostium (over two of its lumen radii). `heading_near(s_m, radius_m)` is the heading of a
    remembered branch whose ostium lies within two lumen radii of arc length `s_m`, or None.
    The scripted expert turns its aim away from that heading; the `wrong_branch_heading`
    observable shows it (tasks/roadmap.py).
    """

    def __init__(self, tree: CenterlineTree, target: str):
        self._tree, self._target = tree, target
        self._branches = {}  # name -> (arc length on the target's path where it leaves, unit heading)

    def note(self, tip_m) -> None:
        name, _, depth = self._tree.locate(tip_m, prefer=self._target)
        if depth <= 0:
            self.note_branch(name)

    def note_branch(self, name: str) -> None:
        """Remember branch `name` as entered (the target's own line and a known one are ignored)."""
        if name == self._target or name in self._branches:
            return
        other = self._tree.lines[name]
        s_leave = self._tree.junction_arclength_m(self._target, name)
        s_other = self._tree.junction_arclength_m(name, self._target)
        heading = other.at(s_other + 2 * other.radius_at(s_other)) - other.at(s_other)
        self._branches[name] = (s_leave, heading / max(np.linalg.norm(heading), 1e-12))

    def heading_near(self, s_m: float, radius_m: float):
        for s_leave, heading in self._branches.values():
            if s_leave - 2 * radius_m <= s_m <= s_leave + 2 * radius_m:
                return heading
        return None


def signed_angle_rad(a, b, axis) -> float:
    """Angle from a to b about axis, in radians; 0 when either is degenerate."""
    if np.linalg.norm(a) < 1e-9 or np.linalg.norm(b) < 1e-9:
        return 0.0
    return float(np.arctan2(np.dot(axis, np.cross(a, b)), np.dot(a, b)))


def component_across(v, axis):
    """`v` without its component along the unit vector `axis`."""
    return v - np.dot(v, axis) * axis
