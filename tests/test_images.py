"""Image observations: the raster path against GL renders of the same state, the
fluoroscopy roadmap against the anatomy, and reproducible seeded images."""

from collections import deque

import numpy as np
import pytest

from cathsim_dmc import tasks
from cathsim_dmc.sim import raster
from cathsim_dmc.sim.arena import top_camera_matrix
from cathsim_dmc.sim.render import TopView

SIZE = 80


@pytest.fixture(scope="module")
def bent():
    """An environment after insertion with rotation both ways: the wire climbs the
    descending aorta and its tip bends into the arch."""
    env = tasks.load("bca", "type1", obs="internal", seed=0)
    env.reset()
    for i in range(60):
        env.step(np.array([1.0, 0.6 if i < 30 else -0.6]))
    task = env.task
    views = {
        r: TopView(SIZE, renderer=r, wire=task.guidewire, vessel_geom_id=task.aorta.visual_geom_id)
        for r in ("gl", "raster")
    }
    return env, views


def _iou(a, b):
    return (a & b).sum() / (a | b).sum()


def _project(physics, point):
    u, v = (top_camera_matrix(physics, size=SIZE) @ np.r_[point, 1.0])[:2]
    return int(np.floor(v)), int(np.floor(u))


def _far_end(mask, start):
    """The mask pixel farthest along the mask (8-connected) from the one nearest `start`."""
    pixels = np.argwhere(mask)
    first = tuple(pixels[np.argmin(((pixels - start) ** 2).sum(axis=1))])
    distance = {first: 0}
    queue = deque([first])
    while queue:
        r, c = queue.popleft()
        for dr in (-1, 0, 1):
            for dc in (-1, 0, 1):
                n = (r + dr, c + dc)
                if n not in distance and 0 <= n[0] < SIZE and 0 <= n[1] < SIZE and mask[n]:
                    distance[n] = distance[(r, c)] + 1
                    queue.append(n)
    return np.array(max(distance, key=distance.get))


def test_raster_mask_matches_gl(bent):
    env, views = bent
    physics = env.physics
    gl, ras = (views[r].mask(physics)[..., 0] > 0 for r in ("gl", "raster"))
    assert _iou(gl, ras) >= 0.9
    # The tip pixel: where each mask ends, followed from where the wire enters the vessel.
    entry = _project(physics, env.task.aorta.entry_position_m)
    tip_gl, tip_raster = _far_end(gl, entry), _far_end(ras, entry)
    assert np.abs(tip_gl - tip_raster).max() <= 1
    tip = _project(physics, env.task.tip_position_m(physics))
    assert np.abs(tip_raster - tip).max() <= 1
    # The wire is bent: its mask is no straight column.
    assert len(set(np.argwhere(ras)[:, 1])) > 3


def test_raster_vessel_silhouette_matches_gl(bent):
    env, views = bent
    physics = env.physics
    # GL draws the vessel on black; the fluoro roadmap darkens the vessel below the
    # background grey. Compared away from the wire, which both draw.
    away = views["raster"].mask(physics)[..., 0] == 0
    gl = views["gl"].image(physics, "camera")[..., 0] > 10
    background = 255 * raster.FLUORO_BACKGROUND
    for renderer in ("raster", "gl"):
        fluoro = views[renderer].image(physics, "fluoro")[..., 0] < background - 2
        assert _iou(gl & away, fluoro & away) >= 0.9, renderer
    camera = views["raster"].image(physics, "camera")[..., 0] > 10
    assert _iou(gl, camera) >= 0.95


def test_fluoro_roadmap_thickness_and_dark_wire(bent):
    env, views = bent
    physics = env.physics
    geom = env.task.aorta.visual_geom_id(physics)
    vertices, faces = raster.mesh_in_world(physics, geom)
    matrix, towards_camera = raster.camera_axes(physics, "top")
    length, crossings = raster.path_length_map(vertices, faces, matrix, towards_camera, 4 * SIZE)
    assert not np.any(crossings % 2), "a ray enters the closed lumen without leaving it"
    # On the centerline of a tube seen side-on the X-ray path is the lumen diameter.
    centerline = env.task.aorta.asset.centerlines["bca"]
    uv = 4 * np.array([top_camera_matrix(physics, size=SIZE) @ np.r_[p, 1.0] for p in centerline.points])[:, :2]
    sampled = length[np.floor(uv[:, 1]).astype(int), np.floor(uv[:, 0]).astype(int)]
    assert np.median(sampled / (2 * np.asarray(centerline.radius))) == pytest.approx(1.0, abs=0.03)
    image = views["raster"].image(physics, "fluoro")[..., 0].astype(int)
    wire = views["raster"].mask(physics)[..., 0] > 0
    vessel = (image < 255 * raster.FLUORO_BACKGROUND - 2) & ~wire
    assert image.min() == image[wire].min(), "the radio-opaque wire is the darkest thing"
    assert np.median(image[wire]) < np.median(image[vessel]) < np.median(image[~vessel & ~wire])


def test_seeded_episode_images_are_reproducible():
    env = tasks.load("bca", "type1", obs="enn", style="fluoro", noise_std=4.0, seed=0)
    task = env.task
    others = {
        (r, s): TopView(SIZE, renderer=r, wire=task.guidewire, vessel_geom_id=task.aorta.visual_geom_id)
        for r in ("gl", "raster")
        for s in ("camera", "fluoro")
    }

    def episode():
        env.random_state.seed(7)
        frames = [env.reset().observation]
        for _ in range(8):
            frames.append(env.step(np.array([1.0, 0.5])).observation)
        extra = {key: view.image(env.physics, key[1]) for key, view in others.items()}
        return frames, extra

    env.reset()  # the first reset compiles and draws extra numbers: seed after it
    (first, extra1), (second, extra2) = episode(), episode()
    for a, b in zip(first, second):
        for key in ("pixels", "guidewire_mask"):
            assert a[key].dtype == np.uint8 and a[key].shape == (SIZE, SIZE, 1)
            np.testing.assert_array_equal(a[key], b[key])
    for key in extra1:
        assert extra1[key].dtype == np.uint8 and extra1[key].shape == (SIZE, SIZE, 1)
        np.testing.assert_array_equal(extra1[key], extra2[key])
    # The noise is there, and comes from the environment's random state.
    clean = others["raster", "fluoro"].image(env.physics, "fluoro")
    assert np.abs(first[-1]["pixels"].astype(int) - clean).mean() > 1
    assert set(np.unique(first[-1]["guidewire_mask"])) <= {0, 255}


@pytest.mark.parametrize("option", [dict(renderer="vulkan"), dict(style="xray"), dict(noise_std=-1.0)])
def test_bad_image_option_names_the_choices(option):
    with pytest.raises(ValueError, match=next(iter(option))):
        tasks.build_task("bca", "type1", obs="enn", **option)


def test_an_observation_preset_is_one_yaml_file_read_by_the_api(tmp_path):
    from cathsim_dmc.core.shipped import conf_root
    from cathsim_dmc.tasks.presets import OBSERVATION_PRESETS, load_presets

    # The shipped files are what the API uses.
    assert load_presets(conf_root() / "obs") == OBSERVATION_PRESETS
    assert OBSERVATION_PRESETS["enn"].enabled == {"pixels", "guidewire_mask", "joint_pos", "joint_vel"}
    (tmp_path / "mask_fluoro.yaml").write_text("name: mask_fluoro\nobservables: [guidewire_mask]\nstyle: fluoro\n")
    preset = load_presets(tmp_path)["mask_fluoro"]
    assert preset.enabled == {"guidewire_mask"} and preset.style == "fluoro" and preset.renderer == "raster"
    (tmp_path / "bad.yaml").write_text("name: bad\nobservables: [pixels, x_ray_dose]\n")
    with pytest.raises(ValueError, match=r"bad\.yaml.*unknown: \['x_ray_dose'\]"):
        load_presets(tmp_path)
