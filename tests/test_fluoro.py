"""What a C-arm shows: the `fluoro` and `tracking_2d` presets (only the observables a
single-plane fluoroscope, the registered roadmap and the robot's encoders give), the
detector's noise, the roadmap overlay, the image-plane tracking and the per-episode view."""

import math

import numpy as np
import pytest

from cathsim_dmc.sim import detector, raster
from cathsim_dmc.sim.arena import carm_camera_axes
from cathsim_dmc.suite.gym import CathSimEnv
from cathsim_dmc.tasks.presets import OBSERVATION_PRESETS
from cathsim_dmc.tasks.tracking2d import (
    HISTORY_STEPS,
    ROADMAP_2D_SIZE,
    TRACKED_MM,
    TRACKING_2D_HISTORY_SIZE,
    TRACKING_2D_SIZE,
)

# What each preset may hold: the image, the overlay or the image-plane tracking, the robot's
# encoders and the C-arm's reported angles. Nothing else.
ALLOWED = {
    "fluoro": {"pixels", "roadmap_overlay", "robot_state", "carm_view"},
    "tracking_2d": {"tracking_2d", "roadmap_2d", "robot_state", "carm_view"},
    "tracking_2d_memory": {"tracking_2d", "tracking_2d_history", "roadmap_2d", "robot_state", "carm_view"},
    "tracking_2d_memory_carriage": {
        "tracking_2d",
        "tracking_2d_history",
        "roadmap_2d",
        "robot_state",
        "carm_view",
        "wrong_branch_heading_2d",
        "catheter_called_2d",
        "catheter_rate",
    },
}
ALLOWED["tracking_2d_memory_carriage_timed"] = ALLOWED["tracking_2d_memory_carriage"] | {"target_depth_time_2d"}
# What the image does not show: the 3-D tip (roadmap, tip_position), depth along the view
# axis (roadmap's tip frame), wall and drive forces, the wire's bending angles and rates
# (joint_pos, joint_vel), its slack, the simulator's own wire segmentation, the depth clock and
# the 3-D wrong-branch memory and catheter flag.
PRIVILEGED = {
    "joint_pos",
    "joint_vel",
    "roadmap",
    "target_depth_time",
    "wrong_branch_heading",
    "catheter_called",
    "tip_position",
    "contact_force",
    "wire_slack",
    "drive_force",
    "guidewire_mask",
}
# What a C-arm suite has but no image preset holds (none now).
C_ARM_NOT_IN_PRESETS = set()
SHAPES = {
    "pixels": (1, 128, 128),
    "roadmap_overlay": (1, 128, 128),
    "robot_state": (5,),
    "carm_view": (2,),
    "tracking_2d": (TRACKING_2D_SIZE,),
    "roadmap_2d": (ROADMAP_2D_SIZE,),
    "tracking_2d_history": (TRACKING_2D_HISTORY_SIZE,),
    "wrong_branch_heading_2d": (3,),
    "catheter_called_2d": (1,),
    "catheter_rate": (1,),
    "target_depth_time_2d": (1,),
}
FORWARD = np.array([1.0, 0.3], dtype=np.float32)


def _drive(env, steps, action=FORWARD):
    obs = None
    for _ in range(steps):
        obs, *_ = env.step(action)
    return obs


def _image_plane_mm(env, points):
    physics = env.physics
    cam = physics.model.name2id("top", "camera")
    axes = physics.data.cam_xmat[cam].reshape(3, 3)
    return 1e3 * (np.asarray(points) - physics.data.cam_xpos[cam]) @ axes[:, :2]


@pytest.fixture(scope="module")
def fluoro_env():
    env = CathSimEnv(task="bca", aorta="type1", obs="fluoro")
    yield env
    env.close()


@pytest.fixture(scope="module")
def tracking_env():
    env = CathSimEnv(task="bca", aorta="type1", obs="tracking_2d")
    yield env
    env.close()


@pytest.fixture(scope="module")
def memory_env():
    env = CathSimEnv(task="bca", aorta="type1", obs="tracking_2d_memory")
    yield env
    env.close()


@pytest.fixture(scope="module")
def carriage_env():
    env = CathSimEnv(task="bca", aorta="type1", obs="tracking_2d_memory_carriage")
    yield env
    env.close()


@pytest.fixture(scope="module")
def timed_env():
    env = CathSimEnv(task="bca", aorta="type1", obs="tracking_2d_memory_carriage_timed")
    yield env
    env.close()


FIXTURES = {
    "fluoro": "fluoro_env",
    "tracking_2d": "tracking_env",
    "tracking_2d_memory": "memory_env",
    "tracking_2d_memory_carriage": "carriage_env",
    "tracking_2d_memory_carriage_timed": "timed_env",
}


@pytest.mark.parametrize("preset", sorted(ALLOWED))
def test_the_presets_hold_only_what_a_c_arm_shows(preset, request):
    fixture = FIXTURES[preset]
    env = request.getfixturevalue(fixture)
    assert OBSERVATION_PRESETS[preset].enabled == ALLOWED[preset]
    # Every observable the task can make is classified: a new one must be added to a list here.
    assert set(env.task.task_observables) == set().union(*ALLOWED.values(), PRIVILEGED, C_ARM_NOT_IN_PRESETS)
    assert not ALLOWED[preset] & PRIVILEGED
    assert set(env.dm_env.observation_spec()) == ALLOWED[preset]
    obs, _ = env.reset(seed=0)
    assert set(obs) == ALLOWED[preset] and set(env.observation_space.spaces) == ALLOWED[preset]
    obs = _drive(env, 3)
    assert set(obs) == ALLOWED[preset]
    for key, value in obs.items():
        assert value.shape == SHAPES[key], key
        assert value.dtype == (np.uint8 if key in ("pixels", "roadmap_overlay") else np.float32)
    np.testing.assert_allclose(obs["carm_view"], 0.0)  # AP, as the C-arm reports it
    robot = env.task.robot
    encoders = np.concatenate([robot.pose_features(env.physics), robot.rate_features(env.physics)])
    np.testing.assert_allclose(obs["robot_state"], encoders, rtol=1e-6, atol=1e-6)


def test_the_fluoro_image_is_a_noisy_detector_frame(fluoro_env):
    """The background's grey-level noise is the Poisson noise of the detector's quanta per
    pixel; the vessel and the wire stay where the clean image has them."""
    env = fluoro_env
    env.reset(seed=1)
    obs = _drive(env, 20)
    clean = env.task.top_view.image(env.physics, "fluoro")[..., 0].astype(float)
    noisy = obs["pixels"][0].astype(float)
    level = 255.0 * raster.FLUORO_BACKGROUND
    background = np.abs(clean - level) < 0.6
    assert background.mean() > 0.5
    quanta = detector.background_quanta(34.0, env.task.top_view.pixel_size_m(env.physics))
    assert 4000 < quanta < 10000  # about 1.2% relative noise per 1.9 mm pixel
    expected_std = level / math.sqrt(quanta)
    assert np.std(noisy[background]) == pytest.approx(expected_std, rel=0.1)
    assert np.mean(noisy[background]) == pytest.approx(np.mean(clean[background]), abs=0.3)
    assert np.abs(noisy - clean).max() < 8 * expected_std + 1  # noise, not a different picture
    # Seeded: the same episode gives the same frames.
    env.reset(seed=1)
    np.testing.assert_array_equal(_drive(env, 20)["pixels"], obs["pixels"])


@pytest.mark.parametrize("quanta", [20.0, 5000.0])  # the Poisson law itself, and its normal limit
def test_the_detector_counts_quanta(quanta):
    level = 100.0  # room above it for the noise in 8 bits
    image = np.full((200, 200, 1), level, np.uint8)
    image[:, 100:] = 25  # a quarter of the background's transmission
    frame = detector.fluoroscopy_frame(image, np.random.RandomState(0), quanta, 0.0, level).astype(float)
    for part, t in ((frame[:, :100], 1.0), (frame[:, 100:], 0.25)):
        counts = part * quanta / level  # back to quanta: mean and variance are the same number
        assert np.mean(counts) == pytest.approx(t * quanta, rel=0.02)
        rounding = (quanta / level) ** 2 / 12  # the 8-bit levels' own variance, in quanta
        assert np.var(counts) == pytest.approx(t * quanta + rounding, rel=0.06)
    again = detector.fluoroscopy_frame(image, np.random.RandomState(0), quanta, 0.0, level)
    np.testing.assert_array_equal(again, frame.astype(np.uint8))


def test_a_lower_dose_is_noisier_and_a_wider_blur_spreads_the_wire():
    env = CathSimEnv(task="bca", aorta="type1", obs="fluoro", detector_dose_ngy=3.4, blur_mm=2.0)
    try:
        env.reset(seed=1)
        obs = _drive(env, 20)
        top_view = env.task.top_view
        clean = top_view.image(env.physics, "fluoro")[..., 0].astype(float)
        pixel_m = top_view.pixel_size_m(env.physics)
        level = 255.0 * raster.FLUORO_BACKGROUND
        far = np.abs(clean - level) < 0.6
        far[:, 40:100] = False  # away from the vessel, where the blur changes nothing
        quanta = detector.background_quanta(3.4, pixel_m)
        assert np.std(obs["pixels"][0][far].astype(float)) == pytest.approx(level / math.sqrt(quanta), rel=0.1)
        # The blur alone (no quanta) is a Gaussian of blur_mm at the vessel: the wire's dark line is shallower.
        blurred = detector.fluoroscopy_frame(clean[..., None], None, 0.0, 2e-3 / pixel_m, level)[..., 0]
        assert blurred.min() > clean.min() + 20
    finally:
        env.close()


def test_the_overlay_is_the_registered_lumen_with_the_target_marked():
    env = CathSimEnv(task="bca", aorta="type1", obs="fluoro", registration_error_m=0.004)
    try:
        obs, _ = env.reset(seed=2)
        overlay = obs["roadmap_overlay"][0].astype(float)
        task, physics = env.task, env.physics
        top_view, size = task.top_view, task.top_view.size
        matrix, _ = raster.camera_axes(physics, "top")
        offset = task.registration_offset_m
        assert np.linalg.norm(offset) > 1e-3
        # The target, off by the registration error, is marked.
        u, v = raster.project((task.target_position_m + offset)[None], matrix, size)[0]
        assert overlay[int(v), int(u)] == 255
        # Registered exactly, the lumen's silhouette is where the live image shows contrast
        # (the wire aside: it also runs outside the lumen, in the sheath).
        exact = top_view.roadmap_overlay(physics, np.zeros(3), task.target_position_m, task.success_radius_m)[..., 0]
        clean = top_view.image(physics, "fluoro")[..., 0].astype(float)
        wire = top_view.mask(physics)[..., 0] > 0
        wire = wire | np.roll(wire, 1, 0) | np.roll(wire, -1, 0) | np.roll(wire, 1, 1) | np.roll(wire, -1, 1)
        vessel, lumen = (clean < 255.0 * raster.FLUORO_BACKGROUND - 5) & ~wire, (exact >= 64) & ~wire
        assert (vessel & lumen).sum() / (vessel | lumen).sum() > 0.95
        # The registration error moves it by the offset's projection (the target put out of
        # the picture: the lumen alone).
        shift = raster.project(offset[None], matrix, size)[0] - raster.project(np.zeros((1, 3)), matrix, size)[0]
        away = task.target_position_m + [1.0, 0.0, 0.0]
        moved, still = (top_view.roadmap_overlay(physics, o, away, 0.004)[..., 0] for o in (offset, np.zeros(3)))
        assert np.all(exact >= still) and (exact != still).sum() < 20  # the same lumen, the target's disc aside
        centroids = [
            np.array([(w * np.arange(size)[None]).sum(), (w * np.arange(size)[:, None]).sum()]) / w.sum()
            for w in (moved.astype(float), still.astype(float))
        ]
        np.testing.assert_allclose(centroids[0] - centroids[1], shift, atol=0.05)
        # One registration per episode: the overlay does not change while the wire moves.
        np.testing.assert_array_equal(_drive(env, 5)["roadmap_overlay"], obs["roadmap_overlay"])
        other, _ = env.reset(seed=3)
        assert not np.array_equal(other["roadmap_overlay"], obs["roadmap_overlay"])
    finally:
        env.close()


def test_tracking_2d_is_the_wire_projected_into_the_image(tracking_env):
    env = tracking_env
    env.reset(seed=4)
    obs = _drive(env, 12)
    task, physics = env.task, env.physics
    tracked = obs["tracking_2d"].reshape(-1, 2).astype(float)
    np.testing.assert_allclose(tracked[0], _image_plane_mm(env, task.tip_position_m(physics)), atol=1e-3)
    # The points behind the tip lie on the projected wire, TRACKED_MM apart along it.
    wire = np.concatenate([physics.bind(task.guidewire.segments).xpos, [task.tip_position_m(physics)]])
    wire_2d = _image_plane_mm(env, wire)
    chords = np.linalg.norm(np.diff(tracked, axis=0), axis=1)
    assert np.all(chords <= np.diff(TRACKED_MM) + 1e-3) and np.all(chords > 0.8 * np.diff(TRACKED_MM))
    a, seg = wire_2d[:-1], np.diff(wire_2d, axis=0)
    for point in tracked:
        t = np.clip(((point - a) * seg).sum(1) / np.maximum((seg * seg).sum(1), 1e-12), 0, 1)
        assert np.linalg.norm(a + t[:, None] * seg - point, axis=1).min() < 1e-3
    # The roadmap's target relative to the tip is the projected target's.
    road = obs["roadmap_2d"].astype(float)
    target = _image_plane_mm(env, task.target_position_m) - tracked[0]
    np.testing.assert_allclose(road[16:18], target, atol=1e-3)
    # The tip inside the descending aorta: inside the projected tube, the roadmap running on up.
    assert road[-1] < 0 and road[15] > road[1]
    remaining = road[-2]
    assert _drive(env, 10, np.array([1.0, 0.0], np.float32))["roadmap_2d"][-2] < remaining - 20


def test_the_tracking_history_is_the_earlier_frames_relative_to_the_tip(memory_env, tracking_env):
    """tracking_2d_memory: the tracked points of the HISTORY_STEPS frames before this one,
    newest first, relative to this frame's tip; at the reset, the first frame repeated.
    Its other observables are tracking_2d's."""
    frames = []
    obs, _ = memory_env.reset(seed=2)
    plain, _ = tracking_env.reset(seed=2)
    for step in range(8):
        frames.append(obs["tracking_2d"].reshape(-1, 2).astype(float))
        np.testing.assert_array_equal(obs["tracking_2d"], plain["tracking_2d"])
        np.testing.assert_array_equal(obs["roadmap_2d"], plain["roadmap_2d"])
        tip = frames[-1][0]
        earlier = [frames[max(step - k, 0)] for k in range(1, HISTORY_STEPS + 1)]
        expected = np.concatenate([(points - tip).ravel() for points in earlier])
        np.testing.assert_allclose(obs["tracking_2d_history"], expected, atol=1e-4)
        obs, *_ = memory_env.step(FORWARD)
        plain, *_ = tracking_env.step(FORWARD)
    assert np.abs(obs["tracking_2d_history"][:2]).max() > 0.5  # the wire moved: the tip of one frame ago differs


def test_the_c_arm_view_is_drawn_per_episode_from_its_seed():
    ranges = dict(view_deg_range=[-45, 45], cranial_deg_range=[-20, 20])
    env = CathSimEnv(task="bca", aorta="type1", obs="tracking_2d", **ranges)
    ap = CathSimEnv(task="bca", aorta="type1", obs="tracking_2d")
    try:
        views = []
        for seed in (0, 1, 2):
            obs, info = env.reset(seed=seed)
            lao, cranial = env.task.carm_view_deg
            assert -45 <= lao <= 45 and -20 <= cranial <= 20
            np.testing.assert_allclose(obs["carm_view"], np.radians([lao, cranial]), rtol=1e-6)
            cam = env.physics.model.name2id("top", "camera")
            xmat = env.physics.data.cam_xmat[cam].reshape(3, 3)
            for axis, column in zip(carm_camera_axes(lao, cranial), xmat.T):
                np.testing.assert_allclose(axis, column, atol=1e-6)
            # The whole lumen is in the turned image.
            matrix, _ = raster.camera_axes(env.physics, "top")
            uv = raster.project(env.task.aorta.asset.visual_vertices.astype(float), matrix, 128)
            assert uv.min() >= 0 and uv.max() <= 128
            # The view is drawn after the start pose: the same seed starts the wire where AP does.
            ap_obs, ap_info = ap.reset(seed=seed)
            np.testing.assert_array_equal(info["tip_position_m"], ap_info["tip_position_m"])
            np.testing.assert_allclose(ap_obs["carm_view"], 0.0)
            np.testing.assert_allclose(obs["tracking_2d"][:2], _image_plane_mm(env, info["tip_position_m"]), atol=1e-3)
            views.append((lao, cranial, obs["tracking_2d"].copy()))
        assert len({round(v[0], 6) for v in views}) == 3
        again, _ = env.reset(seed=1)
        assert env.task.carm_view_deg == views[1][:2]
        np.testing.assert_array_equal(again["tracking_2d"], views[1][2])
        # Without a range nothing is drawn: the AP camera is the one the scene was built with.
        cam = ap.physics.model.name2id("top", "camera")
        np.testing.assert_array_equal(ap.physics.data.cam_xmat[cam], np.eye(3).ravel())
    finally:
        env.close()
        ap.close()


@pytest.mark.parametrize(
    "options, message",
    [
        (dict(view_deg_range=[-60, 0]), r"view_deg_range=\[-60.0, 0.0\] must be \[low, high\] with -45 <= low"),
        (dict(cranial_deg_range=[10]), r"cranial_deg_range=\[10\] must be \[low, high\] in degrees"),
        (dict(view_deg_range=[-30, 30], lao_deg=20), r"lao_deg=20 and view_deg_range=\[-30.0, 30.0\]: give one"),
        (dict(obs="pixels", detector_dose_ngy=10.0), r"detector_dose_ngy=10.0 .* needs style='fluoro'"),
        (
            dict(obs="tracking_2d", tracking_source="camera"),
            r"tracking_source='camera'; choose one of \['projection', 'fluoro_image'\]",
        ),
    ],
)
def test_bad_view_and_detector_options_are_one_line(options, message):
    from cathsim_dmc import tasks

    options = {"obs": "fluoro", **options}
    with pytest.raises(ValueError, match=message):
        tasks.build_task("bca", "type1", **options)


def test_the_view_range_reaches_the_environment_from_the_tools_config():
    from hydra import compose, initialize_config_dir

    from cathsim_dmc.app.cli._common import env_kwargs
    from cathsim_dmc.core.shipped import conf_root

    with initialize_config_dir(config_dir=str(conf_root()), version_base="1.3"):
        drawn = env_kwargs(compose("eval", ["obs=fluoro", "obs.view_deg_range=[-45,45]"]))
        pixels = env_kwargs(compose("eval", ["obs=pixels", "obs.view_deg_range=[-30,30]"]))
        ap = env_kwargs(compose("eval", ["obs=pixels"]))
    assert drawn["view_deg_range"] == [-45, 45] and type(drawn["view_deg_range"]) is list
    assert drawn["detector_dose_ngy"] == 34.0 and drawn["obs"] == "fluoro"
    assert pixels["view_deg_range"] == [-30, 30]
    assert "view_deg_range" not in ap and "cranial_deg_range" not in ap, "off by default, recorded as before"
    for name, preset in OBSERVATION_PRESETS.items():
        if name not in ALLOWED:
            assert preset.view_deg_range is None and preset.cranial_deg_range is None and preset.lao_deg == 0


def test_the_image_trackers_depth_clock_counts_as_the_3d_trackers():
    """target_depth_time_2d (LAO 30) beside target_depth_time (obs=roadmap_timed), the expert's
    actions driving both: the same count at every step of a type III BCA episode."""
    from cathsim_dmc.control.expert import CenterlineExpert

    env = CathSimEnv("bca", "type3", "roadmap_timed")
    image = CathSimEnv("bca", "type3", "tracking_2d_memory_carriage_timed", lao_deg=30)
    expert = CenterlineExpert()
    observation, _ = env.reset(seed=0)
    seen, _ = image.reset(seed=0)
    clocks = []
    try:
        for _ in range(300):
            clocks.append((observation["target_depth_time"][0], seen["target_depth_time_2d"][0]))
            action = expert(observation, env)
            observation, _, terminated, truncated, _ = env.step(action)
            seen, *_ = image.step(action)
            if terminated or truncated:
                break
    finally:
        env.close()
        image.close()
    clocks = np.array(clocks)
    assert clocks[:, 0].max() > 0
    np.testing.assert_array_equal(clocks[:, 0], clocks[:, 1])


def test_the_wire_finder_walks_a_thin_dark_line_from_the_sheath_to_its_tip_past_vessel_edges():
    """A synthetic frame: a dark vessel band with sharp edges, and a wire (10% transmission, one
    pixel wide) entering at the bottom, turning, with a one-pixel gap. The vessel's edges are
    not wire; the path runs from the tip to the sheath."""
    from cathsim_dmc.sim.wire_finder import wire_mask, wire_path_px

    frame = np.full((64, 64), 200.0)
    frame[:, 20:44] *= 0.4  # the vessel: a 24 px band
    rows = np.arange(63, 15, -1)
    cols = np.where(rows > 30, 30, 30 + (30 - rows) // 2)  # up the band, then turning right
    for r, c in zip(rows, cols):
        if r != 40:  # a gap the noise could open
            frame[r, c] *= 0.1
    frame = frame.astype(np.uint8)
    mask = wire_mask(frame)
    assert not mask[:, 19:21].any() and not mask[:, 43:45].any()  # the vessel's edges
    path = wire_path_px(mask, entry_px=(30.5, 70.0))
    np.testing.assert_allclose(path[0], (cols[-1] + 0.5, rows[-1] + 0.5))  # the tip
    np.testing.assert_allclose(path[-1], (30.5, 63.5))  # the pixel nearest the sheath
    assert wire_path_px(np.zeros((8, 8), bool), (4, 4)) is None


@pytest.mark.parametrize("lao_deg", [0, 30])
def test_the_wire_found_in_the_fluoro_frame_is_where_the_projection_puts_it(lao_deg):
    """tracking_source=fluoro_image beside the projection, the same expert episode (LCCA, type II):
    the tracked tip is within a pixel or so of the projected one at nearly every step, and the
    memories kept from it agree."""
    from cathsim_dmc.control.expert import CenterlineExpert

    kw = dict(catheter="angled_5f", lao_deg=lao_deg)
    env = CathSimEnv("lcca", "type2", "roadmap_memory_carriage", catheter="angled_5f")
    projected = CathSimEnv("lcca", "type2", "tracking_2d_memory_carriage", **kw)
    found = CathSimEnv("lcca", "type2", "tracking_2d_memory_carriage", tracking_source="fluoro_image", **kw)
    expert = CenterlineExpert()
    observation, _ = env.reset(seed=0)
    projected.reset(seed=0)
    found.reset(seed=0)
    errors, flags = [], []
    try:
        for _ in range(300):
            action = expert(observation, env)
            observation, _, terminated, truncated, _ = env.step(action)
            a, *_ = projected.step(action)
            b, *_ = found.step(action)
            errors.append(np.linalg.norm(a["tracking_2d"][:2] - b["tracking_2d"][:2]))
            flags.append((a["wrong_branch_heading_2d"][0], b["wrong_branch_heading_2d"][0]))
            if terminated or truncated:
                break
    finally:
        for e in (env, projected, found):
            e.close()
    errors, flags = np.array(errors), np.array(flags)
    pixel_mm = 1.9
    assert np.median(errors) < pixel_mm and np.mean(errors > 3 * pixel_mm) < 0.05
    assert np.mean(flags[:, 0] == flags[:, 1]) >= 0.9
