"""cathsim-view: look at a (task, aorta) in MuJoCo's viewer, or replay a recorded episode.

    cathsim-view task=lcca aorta=bovine
    cathsim-view trajectory=outputs/eval/bca-type1/<run>/trajectories.npz episode=2

Without `trajectory` the scene sits at its reset state (the viewer's mouse controls
work; the wall pieces are geom group 3, off by default). With it, the file's task and
aorta are loaded, the episode's reset is repeated (seed + episode, as cathsim-eval and
cathsim-teleop seed them) and its actions are played back in real time; the printed
tip deviation from the recording tells whether the replay is faithful.
"""

from __future__ import annotations

import contextlib
import time

import numpy as np


def episode_actions(arrays: dict, episode: int) -> np.ndarray:
    """The actions of `episode` in a loaded trajectory file."""
    count = len(arrays["start_tip_position_m"])
    if not 0 <= episode < count:
        raise ValueError(f"episode={episode}: the file holds episodes 0..{count - 1}")
    return arrays["action"][arrays["episode"] == episode]


def replay(env, arrays: dict, episode: int, seed: int, after_step=None, lock=contextlib.nullcontext) -> float:
    """Play the episode's actions on `env` (a CathSimEnv); returns the largest tip deviation (m).

    `after_step()` runs after each step (False stops); each step runs inside `lock()`.
    """
    rows = arrays["episode"] == episode
    env.reset(seed=seed + episode)
    deviation = 0.0
    for action, recorded in zip(episode_actions(arrays, episode), arrays["tip_position_m"][rows]):
        with lock():
            _, _, terminated, truncated, info = env.step(action)
        deviation = max(deviation, float(np.linalg.norm(np.asarray(info["tip_position_m"]) - recorded)))
        if after_step is not None and after_step() is False:
            break
        if terminated or truncated:
            break
    return deviation


def view(cfg) -> None:
    import mujoco
    import mujoco.viewer

    from cathsim_dmc.evaluation.trajectory import load_trajectories
    from cathsim_dmc.suite.gym import CathSimEnv

    task, aorta, arrays = cfg.task.target, cfg.aorta.name, None
    if cfg.trajectory:
        arrays = load_trajectories(cfg.trajectory)
        task, aorta = str(arrays["task"]), str(arrays["aorta"])
        episode_actions(arrays, cfg.episode)  # a bad episode number fails before the window opens
        print(f"replaying episode {cfg.episode} of {cfg.trajectory} ({arrays['policy']} on {task}/{aorta})")
    env = CathSimEnv(task=task, aorta=aorta, obs="internal")
    try:
        env.reset(seed=cfg.seed)
        physics = env.physics
        period_s = env.dm_env.control_timestep()
        with mujoco.viewer.launch_passive(physics.model.ptr, physics.data.ptr) as viewer:
            viewer.cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
            viewer.cam.fixedcamid = physics.model.name2id(cfg.camera, "camera")
            viewer.opt.sitegroup[:] = 1

            def show():
                viewer.sync()
                time.sleep(period_s)
                return viewer.is_running()

            if arrays is not None:
                deviation = replay(env, arrays, cfg.episode, cfg.seed, after_step=show, lock=viewer.lock)
                print(f"replayed; largest tip deviation from the recording {deviation * 1e3:.3f} mm")
            while viewer.is_running():
                viewer.sync()
                time.sleep(0.05)
    finally:
        env.close()


def main():
    from cathsim_dmc.app.cli._common import fail, run_hydra
    from cathsim_dmc.app.cli.teleop import has_display

    if not has_display():
        fail(
            "no display: cathsim-view opens a window; run it under a virtual one with "
            'xvfb-run -s "-screen 0 1024x768x24" cathsim-view ...'
        )
    run_hydra(view, "view")


if __name__ == "__main__":
    main()
