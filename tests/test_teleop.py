"""Teleoperation without a window: the key handler, a scripted session scored like cathsim-eval."""

import json
import os
import subprocess
import sys

import numpy as np

from cathsim_dmc.control.teleop import (
    KEY_DOWN,
    KEY_LEFT,
    KEY_Q,
    KEY_R,
    KEY_RIGHT,
    KEY_SPACE,
    KEY_UP,
    QUIT,
    RESET,
    TeleopSession,
    TeleopState,
    handle_key,
)
from cathsim_dmc.evaluation.rollouts import METRICS_JSON, write_report
from cathsim_dmc.evaluation.trajectory import TrajectoryRecorder, load_trajectories


def _keys(*keys, state=TeleopState()):
    command = None
    for key in keys:
        state, command = handle_key(key, state)
    return state, command


def test_motion_keys_latch_and_opposite_keys_stop_first():
    assert _keys(KEY_UP)[0] == TeleopState(1.0, 0.0)
    assert _keys(KEY_UP, KEY_UP)[0] == TeleopState(1.0, 0.0)
    assert _keys(KEY_UP, KEY_DOWN)[0] == TeleopState(0.0, 0.0)
    assert _keys(KEY_UP, KEY_DOWN, KEY_DOWN)[0] == TeleopState(-1.0, 0.0)
    assert _keys(KEY_LEFT)[0] == TeleopState(0.0, 1.0)
    assert _keys(KEY_RIGHT)[0] == TeleopState(0.0, -1.0)
    assert _keys(KEY_UP, KEY_LEFT, KEY_SPACE)[0] == TeleopState()
    np.testing.assert_array_equal(_keys(KEY_UP, KEY_RIGHT)[0].action, [1.0, -1.0])


def test_commands_and_unknown_keys():
    assert _keys(KEY_UP, KEY_R) == (TeleopState(), RESET)
    assert _keys(KEY_UP, KEY_Q) == (TeleopState(1.0, 0.0), QUIT)
    assert _keys(KEY_UP, ord("X")) == (TeleopState(1.0, 0.0), None)


# A human-style session: push in, steer a little, back off, push again, start over, quit.
SCRIPT = {
    0: [KEY_UP],
    8: [KEY_LEFT],
    11: [KEY_RIGHT],
    18: [KEY_DOWN, KEY_DOWN],
    21: [KEY_UP, KEY_UP],
    30: [KEY_R],
    31: [KEY_UP],
    40: [KEY_Q],
}


def test_scripted_session_is_recorded_and_scored(tmp_path):
    from cathsim_dmc.suite.gym import CathSimEnv

    env = CathSimEnv(task="bca", aorta="type1", max_steps=100)
    recorder = TrajectoryRecorder(env.task.target_name, env.aorta_name, env.task.target_position_m, policy="human")
    session = TeleopSession(env, recorder, seed=0)
    expected = []
    for tick in range(60):
        for key in SCRIPT.get(tick, []):
            session.press(key)
        if session.quit:
            break
        expected.append(session.state.action)
        session.tick()
    path = recorder.save(tmp_path / "trajectories.npz")
    arrays = load_trajectories(path)
    report = write_report(
        arrays, env.task.aorta.asset, {"task": "bca", "aorta": "type1", "policy": "human"}, tmp_path, session.summaries
    )
    env.close()

    np.testing.assert_array_equal(arrays["action"], np.asarray(expected))
    assert list(np.bincount(arrays["episode"])) == [30, 10]
    assert arrays["tip_position_m"][29, 2] != arrays["start_tip_position_m"][0, 2]  # the wire moved
    assert len(session.summaries) == 2 and [len(report["per_episode"]), len(report["episodes"])] == [2, 2]
    assert json.loads((tmp_path / METRICS_JSON).read_text())["policy"] == "human"


def test_without_a_display_it_says_so_and_exits_2(tmp_path):
    env = {k: v for k, v in os.environ.items() if k not in ("DISPLAY", "WAYLAND_DISPLAY")}
    run = subprocess.run(
        [sys.executable, "-m", "cathsim_dmc.app.cli.teleop"], capture_output=True, text=True, cwd=tmp_path, env=env
    )
    assert run.returncode == 2 and run.stderr.count("\n") == 1 and "xvfb-run" in run.stderr, run.stderr
