"""TargetMarker: a non-colliding sphere marking a navigation target."""

from __future__ import annotations

from dm_control import composer, mjcf

from cathsim_dmc.sim import geom_groups


class TargetMarker(composer.Entity):
    """A sphere of the success radius; drawn in videos, never in observations."""

    def _build(self, radius_m: float = 0.004, rgba=(0.1, 0.9, 0.2, 0.4), name: str = "target"):
        self._mjcf_root = mjcf.RootElement(model=name)
        self._geom = self._mjcf_root.worldbody.add(
            "geom",
            name="marker",
            type="sphere",
            size=[radius_m],
            rgba=list(rgba),
            contype=0,
            conaffinity=0,
            group=geom_groups.MARKER,
        )
        self._site = self._mjcf_root.worldbody.add("site", name="centre", size=[radius_m / 4], group=geom_groups.MARKER)

    @property
    def mjcf_model(self):
        return self._mjcf_root

    @property
    def site(self):
        return self._site
