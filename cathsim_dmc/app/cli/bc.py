"""cathsim-bc: behavioural cloning of an image-only student from demonstrations.

    cathsim-bc task=bca aorta=type1 data=outputs/collect/bca-type1/<run>
    cathsim-bc data=<dataset of an ENN agent> bc.distill_coef=1.0   # feature distillation
    cathsim-eval policy=outputs/bc/bca-type1/<run>                   # evaluate it again

The run folder gets config.yaml, bc_policy.pt + policy.json (a checkpoint cathsim-eval
loads like any other), history.json (train and validation losses per epoch) and eval/
(the cathsim-eval report of the student over `eval_episodes` episodes).
"""

from __future__ import annotations

import json
import logging
from pathlib import Path

log = logging.getLogger("cathsim-bc")


def dataset_paths(data) -> list:
    from omegaconf import ListConfig

    if data is None or data == "":
        raise ValueError("data=<dataset folder> is required: a folder written by cathsim-collect")
    return [str(d) for d in data] if isinstance(data, (list, ListConfig)) else [str(data)]


def dataset_manifests(paths) -> list:
    from cathsim_dmc.learning.datasets import MANIFEST, read_manifest

    return [read_manifest(Path(p) / MANIFEST) for p in paths if (Path(p) / MANIFEST).is_file()]


def run(cfg) -> dict:
    import torch
    from hydra.core.hydra_config import HydraConfig
    from omegaconf import OmegaConf
    from tqdm import tqdm

    from cathsim_dmc.agents.trained import CheckpointPolicy
    from cathsim_dmc.app.cli._common import IMAGE_OPTIONS, env_kwargs, pick
    from cathsim_dmc.evaluation.rollouts import METRICS_MD, evaluate_policy
    from cathsim_dmc.learning.datasets import has_keys, load_arrays, stack_frames
    from cathsim_dmc.learning.supervised.bc import (
        PRESET_FOR_IMAGE,
        BCConfig,
        BCPolicyModel,
        epoch_seconds_per_10k,
        save_bc,
        train_bc,
    )
    from cathsim_dmc.suite.gym import CathSimEnv

    # Every value's type and range was checked before Hydra started (cathsim_dmc/app/tool_schemas.py).
    image_key = str(cfg.bc.image_key)
    options = {k: v for k, v in OmegaConf.to_container(cfg.bc).items() if k != "image_key"}
    bc_cfg = BCConfig(**options, seed=cfg.seed)
    eval_episodes, eval_seed = cfg.eval_episodes, cfg.eval_seed
    kwargs = env_kwargs(cfg)
    paths = dataset_paths(cfg.data)
    manifests = dataset_manifests(paths)
    images_opts = {**pick(kwargs, IMAGE_OPTIONS), **(manifests[0]["image_options"] if manifests else {})}
    for m in manifests:
        if (m["task"], m["aorta"]) != (cfg.task.target, cfg.aorta.name):
            log.warning(
                "data was collected on %s/%s; the student is evaluated on %s/%s",
                m["task"],
                m["aorta"],
                cfg.task.target,
                cfg.aorta.name,
            )
    if cfg.torch_threads:
        torch.set_num_threads(int(cfg.torch_threads))

    # Noise-injected demonstrations label each image with the expert's clean action.
    label = "expert_action" if has_keys(paths, ("expert_action",)) else "action"
    keys = [f"obs_{image_key}", label, "step"] + (["feature_z"] if bc_cfg.distill_coef > 0 else [])
    arrays = load_arrays(paths, keys, before_action=True)
    images = stack_frames(arrays[f"obs_{image_key}"], arrays["episode"], arrays["step"], bc_cfg.frames)
    actions = arrays[label]
    log.info("%d samples from %d episodes in %s; labels: %s", len(actions), len(set(arrays["episode"])), paths, label)

    run_dir = Path(HydraConfig.get().runtime.output_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    (run_dir / "config.yaml").write_text(OmegaConf.to_yaml(cfg, resolve=True))
    bar = tqdm(total=bc_cfg.epochs, unit="epoch", desc="training", disable=not cfg.progress_bar)

    def progress(epoch, train, val):
        bar.update(1)
        bar.set_postfix(loss=f"{train['loss']:.3f}", val_mse=f"{val.get('action_mse', float('nan')):.4f}")
        log.info("epoch %d: train %s val %s", epoch, _fmt(train), _fmt(val))

    result = train_bc(images, actions, arrays["episode"], bc_cfg, arrays.get("feature_z"), progress)
    bar.close()
    per_10k = epoch_seconds_per_10k(result.history, len(result.train_rows))
    log.info(
        "trained %d epochs on %d samples in %.0f s (%.1f s per epoch per 10K samples)",
        bc_cfg.epochs,
        len(result.train_rows),
        result.seconds,
        per_10k,
    )
    (run_dir / "history.json").write_text(
        json.dumps(
            {
                "train_samples": int(len(result.train_rows)),
                "val_samples": int(len(result.val_rows)),
                "seconds": result.seconds,
                "seconds_per_epoch_per_10k": per_10k,
                "epochs": result.history,
            },
            indent=2,
        )
    )
    save_bc(
        result.net,
        run_dir,
        image_key,
        images_opts,
        {"task": cfg.task.target, "aorta": cfg.aorta.name, "data": paths},
        frames=bc_cfg.frames,
    )

    if eval_episodes == 0:
        return {"history": result.history}
    policy = CheckpointPolicy(
        BCPolicyModel(result.net, image_key, bc_cfg.frames), PRESET_FOR_IMAGE[image_key], images_opts
    )
    env = CathSimEnv(**env_kwargs(cfg, policy=policy))
    try:
        report = evaluate_policy(
            env,
            policy,
            f"bc-{image_key}",
            eval_episodes,
            eval_seed,
            run_dir / "eval",
            video=cfg.video,
            show_progress=cfg.progress_bar,
        )
    finally:
        env.close()
    print((run_dir / "eval" / METRICS_MD).read_text(), end="")
    print(
        f"success {report['summary']['success_pct']['mean']:.0f}% over {eval_episodes} episodes; run folder: {run_dir}"
    )
    return report


def _fmt(terms: dict) -> str:
    return " ".join(f"{k}={v:.4g}" for k, v in terms.items())


def main():
    from cathsim_dmc.app.cli._common import run_hydra

    run_hydra(run, "bc")


if __name__ == "__main__":
    main()
