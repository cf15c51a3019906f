"""cathsim-export: write a (task, aorta) scene as a self-contained MJCF folder.

    cathsim-export task=bca aorta=type2 out=scenes/bca-type2
    simulate scenes/bca-type2/scene.xml          # MuJoCo's standalone viewer

The folder holds scene.xml and meshes/*.stl (see `cathsim_dmc.sim.export`): it loads in
MuJoCo's `simulate`, `mujoco.MjModel.from_xml_path` and MuJoCo's Unity plug-in.
"""

from __future__ import annotations

from pathlib import Path


def export(cfg) -> Path:
    from cathsim_dmc import tasks
    from cathsim_dmc.app.cli._common import env_kwargs
    from cathsim_dmc.sim.export import SCENE_FILE, export_scene

    out = Path(str(cfg.out))
    if (out / SCENE_FILE).exists() and not cfg.overwrite:
        raise ValueError(f"{out / SCENE_FILE} exists; pass overwrite=true to replace it")
    env = tasks.load(**env_kwargs(cfg), seed=cfg.seed)
    try:
        env.reset()
        scene = export_scene(env, out)
    finally:
        env.close()
    print(f"wrote {scene}")
    return scene


def main():
    from cathsim_dmc.app.cli._common import run_hydra

    run_hydra(export, "export")


if __name__ == "__main__":
    main()
