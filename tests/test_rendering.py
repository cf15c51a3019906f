"""Headless image observations: real pictures, and a mask where the wire is."""

import numpy as np

from cathsim_dmc import tasks
from cathsim_dmc.arena import top_camera_matrix


def test_images_render_headless_and_mask_covers_the_wire():
    env = tasks.load("bca", "type1", obs="pixels_mask", seed=0)
    env.reset()
    for _ in range(15):
        timestep = env.step(np.array([1.0, 0.0]))
    pixels = timestep.observation["pixels"][..., 0]
    mask = timestep.observation["guidewire_mask"][..., 0]
    assert pixels.dtype == np.uint8 and mask.dtype == np.uint8
    assert pixels.std() > 10, "the top view is blank"
    assert set(np.unique(mask)) <= {0, 255}
    # Project the wire's segment centres into the image: the mask must be set there.
    physics = env.physics
    points = physics.bind(env.task.guidewire.segments).xpos
    uv = (top_camera_matrix(physics, size=80) @ np.c_[points, np.ones(len(points))].T).T[:, :2]
    inside = np.all((uv >= 0) & (uv < 80), axis=1)
    assert inside.sum() > 10, "the wire is not in the camera's view"
    cols, rows = np.floor(uv[inside]).astype(int).T
    hit = mask[rows, cols] > 0
    assert hit.mean() > 0.9
    # The mask is the wire alone: a thin curve, not the vessel.
    assert 0 < (mask > 0).mean() < 0.05
