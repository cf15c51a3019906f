"""Forward insertion moves the tip up the descending aorta and the wire stays inside."""

import numpy as np
import trimesh

from cathsim_dmc import tasks


def test_forward_insertion_advances_and_stays_in_the_lumen():
    env = tasks.load("bca", "type1", seed=0)
    env.reset()
    task, physics = env.task, env.physics
    asset = task.aorta.asset
    lumen = trimesh.Trimesh(asset.visual_vertices, asset.visual_faces, process=False)
    entry_y = task.aorta.entry_position_m[1]
    start_y = task.tip_position_m(physics)[1]
    segments = physics.bind(task.guidewire.segments)
    outside_counts = []
    for _ in range(100):
        env.step(np.array([1.0, 0.0]))
        points = np.vstack([segments.xpos, task.tip_position_m(physics)])
        in_vessel_part = points[points[:, 1] > entry_y]
        outside_counts.append(int((~lumen.contains(in_vessel_part)).sum()))
    assert task.tip_position_m(physics)[1] - start_y > 0.03
    assert max(outside_counts) == 0, f"wire points outside the lumen: {outside_counts}"
    assert not task.diverged
