"""Keyboard teleoperation: key codes -> actions, and a recorded session on the Gym env.

The key handling is a plain function of (key code, state), so it is tested without a
window; `cathsim-teleop` feeds it the key codes MuJoCo's viewer reports (GLFW codes).
The viewer reports presses (and the system's key repeats), not releases, so motion
keys latch: Up inserts until Down or Space, and pressing Down while inserting stops
first, then retracts; Left and Right do the same for rotation.
"""

from __future__ import annotations

import dataclasses

import numpy as np

# GLFW key codes (what mujoco.viewer's key_callback receives).
KEY_SPACE, KEY_Q, KEY_R = 32, 81, 82
KEY_RIGHT, KEY_LEFT, KEY_DOWN, KEY_UP = 262, 263, 264, 265

RESET, QUIT = "reset", "quit"

HELP = (
    ("Up / Down", "insert / retract (press again to stop)"),
    ("Left / Right", "rotate left / right"),
    ("Space", "stop"),
    ("R", "new episode"),
    ("Q", "quit and write the report"),
)


@dataclasses.dataclass(frozen=True)
class TeleopState:
    """Latched commands in [-1, 1]: insertion (+ inserts) and rotation (+ turns left)."""

    insertion: float = 0.0
    rotation: float = 0.0

    @property
    def action(self) -> np.ndarray:
        return np.array([self.insertion, self.rotation], dtype=np.float32)


def _step_towards(value: float, direction: float) -> float:
    return float(np.clip(value + direction, -1.0, 1.0))


def handle_key(key: int, state: TeleopState) -> tuple[TeleopState, str | None]:
    """The state after `key` and a command (RESET, QUIT or None); unknown keys change nothing."""
    if key == KEY_UP:
        return dataclasses.replace(state, insertion=_step_towards(state.insertion, 1.0)), None
    if key == KEY_DOWN:
        return dataclasses.replace(state, insertion=_step_towards(state.insertion, -1.0)), None
    if key == KEY_LEFT:
        return dataclasses.replace(state, rotation=_step_towards(state.rotation, 1.0)), None
    if key == KEY_RIGHT:
        return dataclasses.replace(state, rotation=_step_towards(state.rotation, -1.0)), None
    if key == KEY_SPACE:
        return TeleopState(), None
    if key == KEY_R:
        return TeleopState(), RESET
    if key == KEY_Q:
        return state, QUIT
    return state, None


class TeleopSession:
    """Drives a `CathSimEnv` from key presses and records every step.

    `press(key)` applies a key; `tick()` takes one control step with the latched action.
    An episode that ends (target reached, time limit) waits for R; Q ends the session.
    R or Q before the first step of an episode leaves no empty episode in the recording.
    """

    def __init__(self, env, recorder, seed: int = 0):
        from cathsim_dmc.evaluation.metrics import remaining_centerline_length_m

        self.env, self.recorder, self.seed = env, recorder, seed
        self._centerline = env.task.aorta.centerline(env.task.target_name)
        self._remaining = remaining_centerline_length_m
        self.state = TeleopState()
        self.episodes = 0
        self.done = False  # the current episode ended
        self.quit = False
        self.info: dict = {}
        self.summaries: list = []
        self._return = 0.0
        self.reset()

    def reset(self) -> None:
        _, self.info = self.env.reset(seed=self.seed + self.episodes)
        self.recorder.start_episode(
            self.info["tip_position_m"], self._remaining(self._centerline, self.info["tip_position_m"])
        )
        self.state, self.done, self._return, self._steps = TeleopState(), False, 0.0, 0
        self.episodes += 1

    def press(self, key: int) -> None:
        self.state, command = handle_key(key, self.state)
        if command == RESET and self._steps:
            self._close_episode()
            self.reset()
        elif command == QUIT:
            if self._steps:
                self._close_episode()
            else:  # nothing recorded since the last reset
                self.recorder.starts.pop()
                self.recorder.optimal_paths.pop()
                self.episodes -= 1
            self.quit = True

    def tick(self) -> None:
        if self.done or self.quit:
            return
        action = self.state.action
        observation, reward, terminated, truncated, self.info = self.env.step(action)
        self.recorder.record(action, reward, self.info, terminated, truncated, observation)
        self._return += reward
        self._steps += 1
        if terminated or truncated:
            self.done = True
            self._close_episode()

    def _close_episode(self) -> None:
        if len(self.summaries) == self.episodes:
            return  # already summarised (the episode ended before R or Q)
        info = self.info
        self.summaries.append(
            {
                "episode": self.episodes - 1,
                "seed": self.seed + self.episodes - 1,
                "steps": info["step"],
                "return": self._return,
                "success": bool(info["success"]),
                "diverged": bool(info["diverged"]),
                "final_distance_m": info["target_distance_m"],
            }
        )

    def status(self) -> str:
        info = self.info
        ended = "  (ended: R for a new episode)" if self.done else ""
        return (
            f"episode {self.episodes}  step {info.get('step', 0)}  "
            f"target {info.get('target_distance_m', 0) * 1e3:.1f} mm  "
            f"force {info.get('mean_contact_force_n', 0):.2f} N  "
            f"action {self.state.insertion:+.0f} {self.state.rotation:+.0f}{ended}"
        )
