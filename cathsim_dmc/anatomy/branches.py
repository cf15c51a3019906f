"""The entry and the supra-aortic branches of a lumen, found from its grid (``sites=auto`` of a mesh import).

In the simulator's frame (+x patient left, +y superior, +z anterior):

* the lumen's nodes at least the wire probe inside the wall form a graph (`centerlines._grid_graph`,
  on a grid of about 1 mm); the largest connected piece is the vessel;
* its **inferior end** (the lowest nodes: the end of the descending aorta) is the root. The vessel's
  other ends are found one at a time as the node farthest (through the lumen) from the tree found so far,
  while it reaches at least `MIN_BRANCH_M` past its parent's wall; each end's path from the root is the
  shortest path weighted by 1/clearance^2 (near the medial axis);
* an end whose path leaves the aorta towards +y (superior) is a **supra-aortic branch**; its ostium is
  where its path parts from the aorta's (the paths to the other ends: the ascending root); the branches are
  named from the patient's right (-x) to the left: BCA, LCCA, LSA. A BCA and LCCA whose paths run
  together past the aorta share a **common trunk** (the bovine variant);
* the **entry** lies `ENTRY_FROM_END_M` up the descending aorta from its inferior end; each **site**
  `SITE_PAST_OSTIUM_M` along its branch's path from the ostium (the shipped arches: 3 cm).
"""

from __future__ import annotations

import dataclasses
from typing import Dict, List, Mapping, Optional

import numpy as np
from scipy.sparse import csgraph

from cathsim_dmc.anatomy.centerlines import _grid_graph
from cathsim_dmc.anatomy.polyline import arclength
from cathsim_dmc.anatomy.sdf import SDFGrid
from cathsim_dmc.anatomy.validate import PROBE_RADIUS_M

NAMES = ("bca", "lcca", "lsa")  # from the patient's right to the left
ORDINALS = ("first", "second", "third")
FULL = {"bca": "BCA", "lcca": "LCCA", "lsa": "LSA"}
FIND_SPACING_M = 0.001
MIN_BRANCH_M = 0.008  # an end counts when it reaches this far past its parent's wall
ENTRY_FROM_END_M = 0.010
SITE_PAST_OSTIUM_M = 0.030
WIDENING = 1.4  # as validate.ostia_from_centerlines
SITE_BEFORE_TIP_M = 0.008  # a short branch: the site this far before its end
TRUNK_MIN_M = 0.005  # a BCA and LCCA together this far past the aorta share a trunk
APART_M = 0.002  # branches whose mean x differ less cannot be told apart
MAX_ENDS = 12
HOW = "give them: entry=[x,y,z] sites.bca=[x,y,z] sites.lcca=[x,y,z]"


class ArchError(ValueError):
    """The lumen's tree cannot be read as an aortic arch (one line: what was found, how to give the sites)."""


@dataclasses.dataclass
class Branch:
    path: np.ndarray  # (N, 3) root -> end, metres
    ostium: int  # index in `path` where it leaves the aorta
    own: int  # index where it parts from every other path (after a common trunk: the bifurcation)
    depth: np.ndarray  # (N,) distance inside the lumen along `path`

    @property
    def opening(self) -> int:
        """Index of the branch's opening: walking back from its end, the last point where the lumen is
        wider than `WIDENING` x the branch's own radius (its parent's lumen)."""
        s = arclength(self.path)
        tail = (s >= s[self.own]) & (s <= s[-1] - 0.003)
        r = float(np.median(self.depth[tail])) if tail.any() else float(self.depth[-1])
        wide = np.nonzero(self.depth[: len(s) - 1] > WIDENING * r)[0]
        return int(wide[-1]) if len(wide) else self.ostium

    def point_past(self, index: int, length: float) -> np.ndarray:
        s = arclength(self.path[index:])
        at = min(length, max(s[-1] - SITE_BEFORE_TIP_M, 0.5 * s[-1]))
        return np.array([np.interp(at, s, self.path[index:, j]) for j in range(3)])

    @property
    def mean_x(self) -> float:
        return float(self.path[self.ostium :, 0].mean())


@dataclasses.dataclass
class ArchTree:
    entry: np.ndarray
    branches: Dict[str, Branch]  # named, from the patient's right
    aorta: List[np.ndarray]  # the paths to the other ends (the ascending root)
    trunk: bool
    found: str  # what was found, for messages

    @property
    def order(self) -> List[str]:
        return list(self.branches)

    def sites(self) -> Dict[str, np.ndarray]:
        return {k: b.point_past(b.opening, SITE_PAST_OSTIUM_M) for k, b in self.branches.items()}

    def notes(self) -> List[str]:
        out = [self.found]
        if self.trunk:
            out.append("the BCA and LCCA leave the arch through a common trunk (bovine arch)")
        return out

    def branch_of(self, point) -> Optional[str]:
        """The named branch whose own part (past any trunk and its parent's wall) `point` lies in, or None."""
        p = np.asarray(point, dtype=np.float64)
        best, best_d = None, np.inf
        for k, b in self.branches.items():
            start = b.own + int(np.searchsorted(arclength(b.path[b.own :]), b.depth[b.own]))
            part = b.path[min(start, len(b.path) - 1) :]
            d = float(np.min(np.linalg.norm(part - p, axis=1)))
            if d < best_d and d <= 2.0 * float(b.depth[b.own :].max()) + 0.002:
                best, best_d = k, d
        if best is None:
            return None
        for path in self.aorta:
            if float(np.min(np.linalg.norm(path - p, axis=1))) < best_d:
                return None
        return best


def _chain(pred, src, node):
    out = [node]
    while out[-1] != src:
        out.append(int(pred[out[-1]]))
    return out[::-1]


def _common(a, b) -> int:
    n = min(len(a), len(b))
    neq = np.nonzero(np.asarray(a[:n]) != np.asarray(b[:n]))[0]
    return int(neq[0]) if len(neq) else n


def find_arch(grid: SDFGrid, probe: float = PROBE_RADIUS_M) -> ArchTree:
    """The entry and the named supra-aortic branches of the lumen `grid` (see the module docstring);
    ArchError when the tree does not show at least two of them apart."""
    step = max(1, int(round(FIND_SPACING_M / grid.spacing)))
    coarse = SDFGrid(grid.origin, grid.spacing * step, grid.values[::step, ::step, ::step])
    g_len, coords = _grid_graph(coarse, probe, power=0)
    if len(coords) == 0:
        raise ArchError(f"no part of the lumen is {2 * probe * 1e3:.1f} mm wide; {HOW}")
    g_med, _ = _grid_graph(coarse, probe)
    _, labels = csgraph.connected_components(g_len, directed=False)
    keep = np.nonzero(labels == np.bincount(labels).argmax())[0]
    g_len, g_med, coords = g_len[keep][:, keep], g_med[keep][:, keep], coords[keep]
    depth = -coarse(coords)
    low = np.nonzero(coords[:, 1] <= coords[:, 1].min() + 0.003)[0]
    root = int(low[np.argmax(depth[low])])
    d_root = csgraph.dijkstra(g_len, directed=False, indices=root)
    _, pred = csgraph.dijkstra(g_med, directed=False, indices=root, return_predecessors=True)
    # Ends: the first is the farthest node; the rest the farthest from the tree found so far.
    near_root = d_root < 3.0 * float(depth[d_root < 0.03].max())
    ends: List[int] = []
    paths: List[List[int]] = []
    to_tree = d_root.copy()
    attach = np.full(len(coords), root)
    for _ in range(MAX_ENDS):
        if ends:
            score = np.where(near_root | ~np.isfinite(to_tree), -np.inf, to_tree - depth[attach])
            n = int(np.argmax(score))
            if score[n] < MIN_BRANCH_M:
                break
        else:
            n = int(np.argmax(np.where(np.isfinite(d_root), d_root, -1.0)))
        ends.append(n)
        paths.append(_chain(pred, root, n))
        d_new, _, src = csgraph.dijkstra(
            g_len, directed=False, indices=paths[-1], min_only=True, return_predecessors=True
        )
        closer = d_new < to_tree
        to_tree[closer], attach[closer] = d_new[closer], src[closer]
    common = np.array([[_common(a, b) if a is not b else len(a) for b in paths] for a in paths])
    up = []
    for i, p in enumerate(paths):
        o = max([common[i, j] for j in range(len(paths)) if j != i] or [1]) - 1
        v = coords[p[-1]] - coords[p[o]]
        up.append(bool(v[1] > 0.5 * np.linalg.norm(v)))
    others = [j for j in range(len(paths)) if not up[j]]
    supra = [i for i in range(len(paths)) if up[i]]
    found_txt = (
        f"{len(supra)} branch{'es' * (len(supra) != 1)} leaving the arch towards +y and "
        f"{len(others)} other end{'s' * (len(others) != 1)} besides the inferior one"
    )
    if len(supra) < 2 or len(supra) > len(NAMES):
        raise ArchError(f"the lumen's centerline tree shows {found_txt}, not 2-3 supra-aortic branches; {HOW}")
    branches = []
    for i in supra:
        pool = others or [j for j in supra if j != i]
        ostium = max(common[i, j] for j in pool) - 1
        own = max(common[i, j] for j in range(len(paths)) if j != i) - 1
        p = paths[i]
        branches.append(Branch(coords[p], ostium, max(own, ostium), depth[p]))
    branches.sort(key=lambda b: b.mean_x)
    xs = [b.mean_x for b in branches]
    if min(np.diff(xs)) < APART_M:
        raise ArchError(
            f"the lumen's centerline tree shows {found_txt}, but two of them run side by side "
            f"(mean x {', '.join(f'{x * 1e3:.1f}' for x in xs)} mm) and cannot be told apart; {HOW}"
        )
    named = dict(zip(NAMES, branches))
    trunk = False
    if "lcca" in named:
        bca = named["bca"]
        s = arclength(bca.path)
        trunk = bool(s[bca.own] - s[bca.ostium] >= TRUNK_MIN_M)
    first = paths[0] if not others else paths[others[0]]
    fp = coords[first]
    s = arclength(fp)
    entry = np.array([np.interp(min(ENTRY_FROM_END_M, 0.5 * s[-1]), s, fp[:, j]) for j in range(3)])
    found = f"found {', '.join(FULL[k] for k in named)} (from the patient's right) and the entry, {found_txt}"
    return ArchTree(entry, named, [coords[paths[j]] for j in others], trunk, found)


def swapped_site(tree: ArchTree, sites: Mapping[str, np.ndarray]) -> Optional[tuple]:
    """(given name, found name) of the first named site that lies in another named branch, or None."""
    for k, p in sites.items():
        if k not in NAMES:
            continue
        where = tree.branch_of(p)
        if where is not None and where != k:
            return k, where
    return None


def swap_message(given: str, found: str, tree: ArchTree, shown: str) -> str:
    i = tree.order.index(found)
    return (
        f"sites.{given}={shown} lies in the {ORDINALS[i]} branch from the patient's right (the {FULL[found]}); "
        f"give the sites the other way round or check frame="
    )
