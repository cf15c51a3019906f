"""cathsim-teleop: drive the guidewire with the keyboard in MuJoCo's viewer, recorded.

    cathsim-teleop task=bca aorta=type2
    xvfb-run -s "-screen 0 1024x768x24" cathsim-teleop ...     # on a machine without a display

The window shows the scene from the top camera with the keys on screen (see
`cathsim_dmc.control.teleop.HELP`). Every step goes into trajectories.npz in the run folder, in
the schema `cathsim-eval` writes, and on quit (Q or closing the window) the same
metrics.json / metrics.md / path.png / forces.png report is written with policy
"human", so `cathsim-eval`'s combined tables can show a Human row.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

NO_DISPLAY = (
    "no display: cathsim-teleop opens a window; run it under a virtual one with "
    'xvfb-run -s "-screen 0 1024x768x24" cathsim-teleop ...'
)


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def teleop(cfg) -> dict | None:
    import queue

    import mujoco
    import mujoco.viewer
    from hydra.core.hydra_config import HydraConfig

    from cathsim_dmc.app.cli._common import env_kwargs
    from cathsim_dmc.control.teleop import HELP, TeleopSession
    from cathsim_dmc.core.checks import check_number
    from cathsim_dmc.evaluation.episode_ends import trees_of
    from cathsim_dmc.evaluation.rollouts import METRICS_MD, write_report
    from cathsim_dmc.evaluation.trajectory import TrajectoryRecorder
    from cathsim_dmc.suite.gym import CathSimEnv

    check_number("speed", cfg.speed, 0.0, inclusive=False)  # 1 = real time
    seed = check_number("seed", cfg.seed, 0, whole=True)
    kwargs = env_kwargs(cfg)  # teleop has no obs group: the person watches the viewer
    out_dir = Path(HydraConfig.get().runtime.output_dir)
    env = CathSimEnv(**kwargs)
    recorder = TrajectoryRecorder(
        env.task.target_name,
        env.aorta_name,
        env.task.target_position_m,
        policy="human",
        safe_force_n=env.task.safe_force_n,
    )
    session = TeleopSession(env, recorder, seed=seed)
    physics = env.physics
    period_s = env.dm_env.control_timestep() / cfg.speed
    keys: queue.SimpleQueue = queue.SimpleQueue()
    help_keys, help_what = "\n".join(k for k, _ in HELP), "\n".join(w for _, w in HELP)
    try:
        with mujoco.viewer.launch_passive(
            physics.model.ptr, physics.data.ptr, key_callback=keys.put, show_left_ui=False, show_right_ui=False
        ) as viewer:
            viewer.cam.type = mujoco.mjtCamera.mjCAMERA_FIXED
            viewer.cam.fixedcamid = physics.model.name2id(cfg.camera, "camera")
            viewer.opt.sitegroup[:] = 1  # the target and the wire tip
            while viewer.is_running() and not session.quit:
                start = time.monotonic()
                while not keys.empty():
                    session.press(keys.get())
                with viewer.lock():
                    session.tick()
                viewer.set_texts(
                    [
                        (None, mujoco.mjtGridPos.mjGRID_TOPLEFT, help_keys, help_what),
                        (None, mujoco.mjtGridPos.mjGRID_BOTTOMLEFT, session.status(), None),
                    ]
                )
                viewer.sync()
                time.sleep(max(0.0, period_s - (time.monotonic() - start)))
        if not session.quit:  # the window was closed
            session.press(ord("Q"))
        if not recorder.rows["step"]:
            print("nothing recorded")
            return None
        recorder.save(out_dir / "trajectories.npz")
        label = {
            "task": env.task.target_name,
            "aorta": env.aorta_name,
            "policy": "human",
            "safe_force_n": env.task.safe_force_n,
        }
        report = write_report(recorder.arrays(), env.task.aorta.asset, label, out_dir, session.summaries, trees_of(env))
    finally:
        env.close()
    print((out_dir / METRICS_MD).read_text(), end="")
    print(f"results in {out_dir}")
    return report


def main():
    from cathsim_dmc.app.cli._common import fail, run_hydra

    if not has_display():
        fail(NO_DISPLAY)
    run_hydra(teleop, "teleop")


if __name__ == "__main__":
    main()
