"""cathsim-view's replay: a recorded episode played back reproduces the recorded tip path."""

import pytest

from cathsim_dmc.app.cli.view import episode_actions, replay
from cathsim_dmc.control.teleop import KEY_LEFT, KEY_R, KEY_UP, TeleopSession
from cathsim_dmc.evaluation.trajectory import TrajectoryRecorder
from cathsim_dmc.suite.gym import CathSimEnv


def test_replay_reproduces_the_recording():
    env = CathSimEnv(task="bca", aorta="type1", max_steps=100)
    recorder = TrajectoryRecorder("bca", "type1", env.task.target_position_m, policy="human")
    teleop = TeleopSession(env, recorder, seed=3)
    for tick, key in enumerate([KEY_UP] + [None] * 9 + [KEY_R, KEY_UP, KEY_LEFT] + [None] * 12):
        if key is not None:
            teleop.press(key)
        teleop.tick()
    arrays = recorder.arrays()
    assert len(episode_actions(arrays, 1)) > 0
    assert replay(env, arrays, episode=1, seed=3) < 1e-6
    with pytest.raises(ValueError, match="episodes 0..1"):
        episode_actions(arrays, 2)
    env.close()
