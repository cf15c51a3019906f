"""Aorta: an anatomy asset as a composer entity.

The asset folder (format in docs/anatomy.md) holds the lumen surface as one visual mesh,
the wall as convex collision pieces, named sites and centerlines. Collision pieces sit
in geom group 3, which observation renders never draw; the visual mesh is one geom in
group 1, so drawing the vessel costs one mesh whatever the wall's piece count.

With ``hulls_in_mjcf=False`` the wall and the visual mesh stay out of the MJCF tree
(thousands of mesh elements take seconds to build, serialise and parse) and
`add_geoms` puts them into a `mujoco.MjSpec` of the compiled scene instead, in the same
order; `NavigationEnvironment` builds that way. There the wall pieces go into the world
body rather than the aorta's (static) attachment body: MuJoCo's broadphase then costs
about a seventh (154 -> 22 us per physics step in issue 20's probe) with the same
trajectories, bit for bit (`tests/test_build.py`, `tests/test_physics_settings.py`).
"""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
from dm_control import composer, mjcf

from cathsim_dmc.anatomy import AortaAsset, load_asset
from cathsim_dmc.anatomy.validate import open_end_plane
from cathsim_dmc.core.checks import check_parameters
from cathsim_dmc.core.shipped import resolve_asset
from cathsim_dmc.sim import geom_groups


def moved_outward(pieces, distance_m: float) -> tuple:
    """Wall prisms moved `distance_m` outward, away from the lumen.

    A prism is 6 points: a lumen triangle, then the same triangle offset outward along
    its vertex normals (`anatomy.extrude_prisms`); each point moves along its vertex's
    normal. Neighbouring prisms share their points and normals, so they stay joined.
    Pieces of another shape are returned as they are.
    """
    if distance_m == 0:
        return tuple(pieces)
    moved = []
    for piece in pieces:
        piece = np.asarray(piece, dtype=np.float64)
        if len(piece) == 6:
            normals = piece[3:] - piece[:3]
            normals = normals / np.linalg.norm(normals, axis=1, keepdims=True)
            piece = piece + distance_m * np.vstack([normals, normals])
        moved.append(piece)
    return tuple(moved)


WALLS = ("prisms", "field")


class Aorta(composer.Entity):
    """Vessel anatomy: wall collision pieces, one visual mesh, sites and centerlines."""

    def _build(
        self,
        asset: str | Path = "type1",
        friction: float = 0.1,  # wet, smooth endothelium / silicone phantom against a coated wire
        solref: tuple = (0.01, 1.0),  # 2 timesteps at the 5 ms default; MuJoCo raises less to 2 dt
        solimp: tuple = (0.99, 0.999, 0.0005, 0.5, 2),
        rgba: tuple = (0.85, 0.45, 0.45, 0.35),  # see-through, so the wire inside is visible
        name: str | None = None,
        hulls_in_mjcf: bool = True,
        contact_margin_m: float = 1e-3,  # see below: the seam artefact then needs a wire 1.45 mm deep
        wall: str = "prisms",
    ):
        """Builds the anatomy.

        Args:
          asset: a shipped asset name (see `available_aortas`) or an asset folder path.
          friction: sliding friction of the wall (MuJoCo takes the larger of the two
            geoms' coefficients).
          solref: contact time constant (s) and damping ratio of the wall. MuJoCo mixes
            wall and wire parameters, so the wire should carry the same values.
          solimp: contact impedance of the wall (see MuJoCo's solimp).
          rgba: colour of the visual mesh.
          name: model name (default: the asset's name).
          hulls_in_mjcf: put the wall pieces and the visual mesh into the MJCF model
            (works with any composer environment). False leaves them to `add_geoms`,
            which an environment must call on the scene's spec before compiling (as
            `NavigationEnvironment` does); a physics without them raises at reset.
            The MJCF path leaves the pieces in the aorta's attachment body, where the
            broadphase costs more (see `add_geoms`); the results are the same.
          contact_margin_m: contact margin of the wall pieces, in metres. The pieces
            are moved outward by the same distance (`wall_pieces`), so the contact
            constraint still starts on the lumen surface, but the convex pieces lie this
            far behind it. A wire that sinks into the wall (a contact appears up to one
            step's travel deep) then meets a rounded surface, not the pieces' seams:
            without the margin, a segment more than its radius deep at a seam between
            two pieces got the seam's side faces as contact normals, opposite to each
            other, and the solver pushed them against each other (3,568 N of contact
            force on a 12 N load in one physics step; see docs/model.md, "Contact
            forces"). With the margin a segment must sink more than its radius plus the
            margin (1.45 mm) for that; the deepest wall contact measured was 0.78 mm. The
            moved pieces' constraint surface follows the lumen within 0.2 mm (it is
            rounded at ridges, and a face moves back by less than the margin where its
            vertex normals lean off it). 0 keeps the pieces where the asset has them.
          wall: how the wall meets the wire. "prisms": one convex MuJoCo geom per lumen
            triangle (MuJoCo's own contact tests). "field": one SDF geom whose contacts
            come from the lumen's signed distance, sampled every 0.5 mm, through a
            compiled contact test (`cathsim_dmc.sim.wall_field`; needs a C compiler once, and
            `hulls_in_mjcf=False`). Both put the contact constraint on the lumen surface.
        """
        if wall not in WALLS:
            raise ValueError(f"wall={wall!r} is not a wall representation; choose one of {list(WALLS)}")
        if wall == "field" and hulls_in_mjcf:
            raise ValueError(
                "wall='field' (physics='fast_field') needs hulls_in_mjcf=False: its distance "
                "field goes into the compiled model through add_geoms (NavigationEnvironment does this); "
                "for the wall in the MJCF model use wall='prisms' (physics='fast')"
            )
        check_parameters(
            "Aorta",
            non_negative=dict(friction=friction, contact_margin_m=contact_margin_m),
            finite=dict(solref=solref, solimp=solimp, rgba=rgba),
        )
        self.wall = wall
        if wall == "field":
            from cathsim_dmc.sim import wall_field

            wall_field.native()  # built and in MuJoCo's table before any model with this wall steps
        self._asset: AortaAsset = load_asset(resolve_asset(asset))
        self._mjcf_root = mjcf.RootElement(model=name or self._asset.name)
        root = self._mjcf_root
        if not contact_margin_m >= 0:
            raise ValueError(f"contact_margin_m={contact_margin_m!r} must be >= 0 (metres)")
        self.contact_margin_m = float(contact_margin_m)
        self._wall = dict(
            contype=geom_groups.WALL_CONTYPE,
            conaffinity=geom_groups.WALL_CONAFFINITY,
            condim=3,
            margin=self.contact_margin_m,
            friction=[friction, 0.005, 0.0001],
            solref=list(solref),
            solimp=list(solimp),
            group=geom_groups.COLLISION,
            rgba=[0.5, 0.5, 0.5, 0.3],
        )
        self._visual = dict(contype=0, conaffinity=0, group=geom_groups.VISUAL, rgba=list(rgba))
        self.hulls_in_mjcf = bool(hulls_in_mjcf)
        body = root.worldbody
        if self.hulls_in_mjcf:
            root.default.geom.set_attributes(**self._wall)
            for i, hull in enumerate(self.wall_pieces):
                mesh = root.asset.add("mesh", name=f"hull{i}", vertex=np.asarray(hull, dtype=float).ravel())
                body.add("geom", name=f"hull{i}", type="mesh", mesh=mesh)
            visual = root.asset.add(
                "mesh", name="lumen", vertex=self._asset.visual_vertices.ravel(), face=self._asset.visual_faces.ravel()
            )
            body.add("geom", name="lumen", type="mesh", mesh=visual, **self._visual)
        self._sites = {}
        for site_name, pos in {**self._asset.sites, "entry": self._asset.entry_position}.items():
            self._sites[site_name] = body.add(
                "site", name=site_name, pos=pos, size=[0.0015], rgba=[0, 0.6, 1, 1], group=geom_groups.MARKER
            )

    @property
    def mjcf_model(self):
        return self._mjcf_root

    def _prefix(self) -> str:
        """The namespace of this entity's elements in the compiled model ("type1/")."""
        entry = self._sites["entry"].full_identifier
        return entry[: -len("entry")]

    def add_geoms(self, spec: mujoco.MjSpec, wall: str | None = None) -> None:
        """Adds the wall pieces and the visual mesh to `spec` (a spec of the compiled
        scene that holds this aorta without them), named as `hulls_in_mjcf` names them.
        `wall` overrides the aorta's wall representation (`export` writes the prisms,
        which MuJoCo alone can simulate)."""
        if self.hulls_in_mjcf:
            raise ValueError("this Aorta already has its wall in the MJCF model")
        prefix = self._prefix()
        # The attachment frame is a body named after the namespace; unattached, the world.
        body = spec.body(prefix) if prefix else spec.worldbody
        if body is None:
            body = spec.worldbody
        # The wall pieces go into the world body, placed where the attachment frame puts
        # them. In a static non-world body (the frame) MuJoCo's broadphase costs about 7x
        # more (issue 20's probe: 154 against 22 us per physics step; a whole physics step
        # 8-18% more, experiments/physics_probe.py); contacts, forces and trajectories come
        # out bit-identical (tests/test_physics_settings.py).
        placement = {}
        if body.name != spec.worldbody.name:
            if body.parent.name != spec.worldbody.name:
                raise ValueError(
                    f"aorta {self.name!r} is attached below body {body.parent.name!r}: attach it to "
                    f"the arena (the world body) so that its wall can go into the world body"
                )
            if np.any(body.pos != 0) or np.any(body.quat != [1, 0, 0, 0]):
                placement = dict(pos=np.array(body.pos), quat=np.array(body.quat))

        def add(parent, name, vertices, faces, settings):
            mesh = spec.add_mesh(name=prefix + name)
            mesh.uservert = np.asarray(vertices, dtype=float).ravel()
            if faces is not None:
                mesh.userface = np.asarray(faces).ravel()
            geom = parent.add_geom(name=prefix + name, type=mujoco.mjtGeom.mjGEOM_MESH, meshname=prefix + name)
            for key, value in settings.items():
                setattr(geom, key, value)

        if (wall or self.wall) == "field":
            self._add_field(spec, prefix, placement)
        else:
            for i, hull in enumerate(self.wall_pieces):
                add(spec.worldbody, f"hull{i}", hull, None, {**self._wall, **placement})
        # As in the MJCF path, the visual geom inherits the wall's settings but draws only.
        add(body, "lumen", self._asset.visual_vertices, self._asset.visual_faces, {**self._wall, **self._visual})

    def _add_field(self, spec: mujoco.MjSpec, prefix: str, placement: dict) -> None:
        """The wall as one static SDF geom in the world body, with its distance field in a
        numeric field of the same name (world coordinates; see `cathsim_dmc.sim.wall_field`)."""
        from cathsim_dmc.sim import wall_field

        rotation = np.eye(3)
        offset = np.zeros(3)
        if placement:
            mujoco.mju_quat2Mat(rotation.ravel(), np.asarray(placement["quat"], dtype=float))
            offset = np.asarray(placement["pos"], dtype=float)
        pieces = [np.asarray(piece, dtype=float) for piece in self._asset.hulls]
        if any(piece.shape != (6, 3) for piece in pieces):
            raise ValueError(
                f"aorta {self.name!r}: wall='field' builds on the asset's prisms (a lumen triangle and "
                f"its outward copy), and this asset has other wall pieces; use wall='prisms'"
            )
        lumen = np.asarray([piece[:3] for piece in pieces]) @ rotation.T + offset
        centre, outward, _ = self._open_end()
        cut = (rotation @ centre + offset, rotation @ outward)
        field = wall_field.build_field(lumen, shift_m=self.contact_margin_m, cut=cut)
        spec.add_numeric(name=prefix + "wall", data=field, size=len(field))
        # The geom's own shape only bounds it for MuJoCo's broadphase: a box around the wall.
        lo = lumen.reshape(-1, 3).min(axis=0) - self.wall_thickness_m - self.contact_margin_m
        hi = lumen.reshape(-1, 3).max(axis=0) + self.wall_thickness_m + self.contact_margin_m
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        mesh = spec.add_mesh(name=prefix + "wall")
        mesh.uservert = corners.ravel()
        geom = spec.worldbody.add_geom(name=prefix + "wall", type=mujoco.mjtGeom.mjGEOM_SDF, meshname=prefix + "wall")
        for key, value in self._wall.items():
            setattr(geom, key, value)

    @property
    def geoms_key(self) -> bytes:
        """Identifies what `add_geoms` adds (for caching compiled models)."""
        asset = self._asset
        # The pieces as simulated (moved by the margin), so that a change in how they are
        # moved never reuses a stale compiled model.
        pieces = np.concatenate(self.wall_pieces) if self.wall_pieces else np.zeros((0, 3))
        wall = b"wall in worldbody"
        if self.wall == "field":
            from cathsim_dmc.sim import wall_field

            wall = b"field wall %r %s" % (
                (wall_field.FIELD_SPACING_M, wall_field.FIELD_BAND_M),
                wall_field.source_digest().encode(),
            )
        return b"".join(
            [
                wall,
                repr((self._wall, self._visual)).encode(),
                pieces.tobytes(),
                asset.hull_offsets.tobytes(),
                asset.visual_vertices.tobytes(),
                asset.visual_faces.tobytes(),
            ]
        )

    def initialize_episode(self, physics, random_state):
        if not self.hulls_in_mjcf and len(self.wall_geom_ids(physics)) == 0:
            raise RuntimeError(
                "Aorta(hulls_in_mjcf=False) has no wall in this physics: build the environment with "
                "NavigationEnvironment, or call aorta.add_geoms on the scene's spec"
            )

    @property
    def asset(self) -> AortaAsset:
        return self._asset

    @composer.cached_property
    def wall_pieces(self) -> tuple:
        """The wall's convex pieces as simulated, each a (k, 3) array in metres.

        The asset's prisms (a lumen triangle, then the same triangle offset outward
        along its vertex normals) moved outward along those normals by
        `contact_margin_m`. Neighbouring prisms share their vertices and normals, so the
        moved wall has no gaps either. Pieces of another shape are kept as they are.
        """
        return moved_outward(self._asset.hulls, self.contact_margin_m)

    @property
    def name(self) -> str:
        return self._asset.name

    @property
    def targets(self) -> dict:
        """Target positions in metres, by site name (bca, lcca, lsa)."""
        return dict(self._asset.sites)

    @property
    def sites(self) -> dict:
        """MJCF sites by name: the targets and `entry`."""
        return dict(self._sites)

    @property
    def entry_position_m(self) -> np.ndarray:
        return np.asarray(self._asset.entry_position, dtype=float)

    @property
    def entry_direction(self) -> np.ndarray:
        return np.asarray(self._asset.entry_direction, dtype=float)

    @property
    def access_position_m(self) -> np.ndarray:
        """Where the wire enters the vessel: the entry axis (through `entry_position_m`
        along `entry_direction`) crossing the plane of the vessel's open end, in metres.

        An introducer sheath comes in through here (see `FollowerRobot`): put its seal on
        this point and its tip lies inside the lumen. The open end must face the entry
        direction (within 1 degree), or a seal across the axis would leave the rim open
        on one side; generated and imported assets are built that way.
        """
        centre, outward, _ = self._open_end()
        direction = self.entry_direction / np.linalg.norm(self.entry_direction)
        if float(-outward @ direction) < np.cos(np.radians(1.0)):
            raise ValueError(
                f"aorta {self.name!r}: the open end (normal {outward.round(3).tolist()}) does not face "
                f"the entry direction {direction.round(3).tolist()}; an introducer cannot seal it"
            )
        entry = self.entry_position_m
        return entry + float((centre - entry) @ outward) / float(direction @ outward) * direction

    @property
    def access_radius_m(self) -> float:
        """Radius of the vessel's open end (the lumen at the access), in metres."""
        return self._open_end()[2]

    @property
    def wall_thickness_m(self) -> float:
        """Thickness of the vessel wall's collision pieces, in metres."""
        return float(self._asset.wall_thickness_m)

    def _open_end(self):
        plane = open_end_plane(self._asset)
        if plane is None:
            raise ValueError(
                f"aorta {self.name!r} has no open_end in its meta.json: rebuild or re-import it with cathsim-aorta"
            )
        return plane

    @property
    def bounds_m(self) -> np.ndarray:
        return np.asarray(self._asset.bounds, dtype=float)

    def centerline(self, target: str) -> np.ndarray:
        """Polyline (n, 3) in metres from the entry to `target`."""
        return np.asarray(self._asset.centerlines[target].points)

    @composer.cached_property
    def collision_geoms(self):
        """The wall pieces as MJCF elements (empty with `hulls_in_mjcf=False`)."""
        return tuple(g for g in self._mjcf_root.find_all("geom") if g.name.startswith("hull"))

    def wall_geom_ids(self, physics) -> np.ndarray:
        """Geom ids of the wall pieces in `physics`, whichever way the wall was added."""
        model = physics.model.ptr
        prefix = self._prefix()
        if self.wall == "field":
            ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"{prefix}wall")]
            return np.asarray([i for i in ids if i >= 0], dtype=int)
        ids = [
            mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_GEOM, f"{prefix}hull{i}")
            for i in range(self._asset.hull_count)
        ]
        return np.asarray([i for i in ids if i >= 0], dtype=int)

    def visual_geom_id(self, physics) -> int:
        """Geom id of the visual lumen mesh in `physics` (-1 if absent)."""
        return int(mujoco.mj_name2id(physics.model.ptr, mujoco.mjtObj.mjOBJ_GEOM, self._prefix() + "lumen"))
