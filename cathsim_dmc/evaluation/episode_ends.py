"""Where each evaluation episode ended, and the failures grouped by it.

A success rate says how many episodes failed, not how. The common ways are few: the tip
turns into another branch (at the arch, the LSA or the other carotid) and is pushed to its
end; it reaches the target's depth but rests on the wall just outside the success radius;
it overshoots; it stalls in the arch. Each leaves a trace in the tip's path, read here from
a trajectory file's arrays (`cathsim_dmc.evaluation.trajectory`) and the anatomy's centerline tree
(`cathsim_dmc.anatomy.paths.CenterlineTree`). Pure numpy: no simulator needed.

A tip is *in another branch* when it lies deepest in another centerline's tube, past the
point where that line leaves the target's, and clear of the target line's tube
(`IN_BRANCH_M`); *at the target's depth* when it is within the success radius of the target
along the vessel; *past the target* when it lies on the target's line beyond it; *off the
centerlines* when it is outside every line's tube (the ascending aorta has none).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

from cathsim_dmc.anatomy.paths import CenterlineTree
from cathsim_dmc.evaluation.trajectory import wall_forces_n

OFF_CENTERLINES_M = 1e-3  # a tip this far outside every tube is off the centerlines
# Passing a branch's mouth, the tip bulges up to about 1.2 mm out of the target line's tube for
# one to four steps (type I's arch); a tip that turns in is 2.5-8 mm out within two to four steps.
IN_BRANCH_M = 2e-3
BESIDE_TARGET_M = 4e-3  # the paper's success radius: this close along the vessel is the target's depth
SHORT_OF_TARGET = "short of the target"
PAST_TARGET = "past the target"
BESIDE_TARGET = "at the target's depth, off its axis"
OFF_CENTERLINES = "off the centerlines"
REACHED = "reached the target"
BRANCH = "in the "  # + the line's name in capitals


@dataclass(frozen=True)
class EpisodeEnd:
    """One episode's outcome, in millimetres and newtons."""

    episode: int
    success: bool
    ended: str  # REACHED, SHORT_OF_TARGET, BESIDE_TARGET, PAST_TARGET, OFF_CENTERLINES or "in the <LINE>"
    other_branches: tuple  # the other branches the tip entered, in order ("LSA", ...)
    entered_last_branch_step: int | None  # when it last entered one (1 = after the first action)
    closest_to_target_mm: float  # straight-line distance at its smallest
    end_along_vessel_mm: float  # tip to target along the vessel at the last step
    largest_wall_force_n: float  # the largest step-mean wall force


def place(tree: CenterlineTree, point_m, target: str) -> tuple[str, float]:
    """(where `point_m` lies, its distance to the target along the vessel in metres)."""
    location = tree.locate(point_m, prefer=target)
    name, s, depth = location
    along_m = tree.geodesic_from_location(location, target)
    # Past the point where two centerlines part, both tubes still cover the arch around the
    # branch's mouth: a tip is in the branch once it is clear of the target line's tube.
    if (
        name != target
        and s > tree.junction_arclength_m(name, target)
        and tree.lines[target].locate(point_m)[1] > IN_BRANCH_M
    ):
        where = BRANCH + name.upper()
    elif depth > OFF_CENTERLINES_M:
        where = OFF_CENTERLINES
    elif along_m <= BESIDE_TARGET_M:
        where = BESIDE_TARGET
    elif name == target and s > tree.lines[target].length_m:
        where = PAST_TARGET
    else:
        where = SHORT_OF_TARGET
    return where, along_m


def episode_ends(arrays: dict, tree_for: Callable[[str], CenterlineTree]) -> list:
    """An `EpisodeEnd` per episode of a trajectory file's arrays; `tree_for(aorta)` gives the
    centerline tree of an aorta by name (one aorta, or each episode's with aorta=random)."""
    target = str(arrays["task"])
    forces = wall_forces_n(arrays)
    aortas = arrays.get("episode_aorta")
    ends = []
    for e in range(len(arrays["start_tip_position_m"])):
        rows = arrays["episode"] == e
        if not rows.any():
            continue
        tree = tree_for(str(aortas[e]) if aortas is not None else str(arrays["aorta"]))
        places = [place(tree, p, target) for p in arrays["tip_position_m"][rows]]
        in_branch = [where.startswith(BRANCH) for where, _ in places]
        entries = [i for i, inside in enumerate(in_branch) if inside and (i == 0 or not in_branch[i - 1])]
        branches = tuple(dict.fromkeys(places[i][0][len(BRANCH) :] for i in entries))
        success = bool(arrays["success"][rows].any())
        ends.append(
            EpisodeEnd(
                episode=e,
                success=success,
                ended=REACHED if success else places[-1][0],
                other_branches=branches,
                entered_last_branch_step=int(arrays["step"][rows][entries[-1]]) if entries else None,
                closest_to_target_mm=1e3 * float(arrays["target_distance_m"][rows].min()),
                end_along_vessel_mm=1e3 * places[-1][1],
                largest_wall_force_n=float(forces[rows].max()),
            )
        )
    return ends


def trees_of(env) -> Callable[[str], CenterlineTree]:
    """`tree_for` of a `cathsim_dmc.suite.gym.CathSimEnv`: its anatomy's tree, or with aorta=random
    the tree of each pool anatomy by name (built when first asked for)."""
    from functools import lru_cache

    from cathsim_dmc.anatomy.asset import load_asset

    pool = getattr(env, "dm_env", None)
    if not hasattr(pool, "anatomy_names"):
        tree = env.task.paths
        return lambda aorta: tree
    folders = dict(zip(pool.anatomy_names, pool.anatomies))
    return lru_cache(maxsize=None)(lambda aorta: CenterlineTree.from_asset(load_asset(folders[aorta])))


def _span(values, fmt: str) -> str:
    low, high = fmt.format(min(values)), fmt.format(max(values))
    return low if low == high else f"{low}-{high}"


def failures_table(ends) -> str:
    """Markdown: the failed episodes grouped by where they ended, most common first; "" if
    none failed."""
    failed = [e for e in ends if not e.success]
    if not failed:
        return ""
    groups = {}
    for end in failed:
        groups.setdefault(end.ended, []).append(end)
    lines = [
        f"Failed episodes: {len(failed)} of {len(ends)}, by where the tip ended.",
        "",
        "| Ended | Episodes | Entered that branch at step | Had been in another branch "
        "| Closest to the target (mm) | At the end, along the vessel (mm) | Largest wall force (N) |",
        "|---|---|---|---|---|---|---|",
    ]
    for where, group in sorted(groups.items(), key=lambda item: (-len(item[1]), item[0])):
        ended_in_branch = where.startswith(BRANCH)
        own = {where[len(BRANCH) :]} if ended_in_branch else set()
        visited = [set(e.other_branches) - own for e in group]
        names = ", ".join(sorted(set().union(*visited)))
        count = sum(1 for v in visited if v)
        cells = [
            where,
            str(len(group)),
            _span([e.entered_last_branch_step for e in group], "{:d}") if ended_in_branch else "-",
            f"{count} of {len(group)} ({names})" if count else "-",
            _span([e.closest_to_target_mm for e in group], "{:.1f}"),
            _span([e.end_along_vessel_mm for e in group], "{:.0f}"),
            _span([e.largest_wall_force_n for e in group], "{:.1f}"),
        ]
        lines.append("| " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"
