"""The files of a cathsim-train run, written and read apart from the training loop.

    <run>/policy.json                       what evaluating a checkpoint needs (write_policy_file)
    <run>/final_model.zip                   the model at the end of the run
    <run>/evaluations.jsonl                 one line per periodic evaluation
    <run>/checkpoints/step_<n>.zip          the model at environment step n
    <run>/checkpoints/last.zip              the newest of them: writing it commits a checkpoint
    <run>/checkpoints/replay_buffer_step_<n>.pkl   the replay buffer saved with step n (optional)
    <run>/checkpoints/best.zip, best.json   the best periodic evaluation's model and its scores
                                            (a tie broken on more episodes: callbacks.break_best_tie)

Beside every model, `<name>.vecnormalize.pkl` holds its observation normaliser when it
has one. Every file is written atomically (`cathsim_dmc.core.run_files`), so a run killed at
any moment leaves a checkpoint that `resume_checkpoint` can continue from.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

from cathsim_dmc.core import run_files

CHECKPOINT_DIR = "checkpoints"
LAST_CHECKPOINT = "last.zip"
REPLAY_BUFFER_FORMAT = "replay_buffer_step_{}.pkl"  # saved with the checkpoint of that step
REPLAY_BUFFER_GLOB = "replay_buffer_step_*.pkl"
FINAL_MODEL = "final_model.zip"
BEST_MODEL = "best.zip"  # the checkpoint with the best periodic deterministic evaluation
BEST_RECORD = "best.json"
EVALUATIONS = "evaluations.jsonl"  # one line per periodic evaluation: step, success rate, return, wall time
CHECKPOINT_EVERY_WITHOUT_EVALUATION = 1000  # steps: trainer.checkpoint_every=null with trainer.eval_every=0


def checkpoint_interval(trainer: dict) -> int:
    """Environment steps between checkpoints: trainer["checkpoint_every"], or when it is
    None the periodic evaluation's eval_every (CHECKPOINT_EVERY_WITHOUT_EVALUATION without
    one). 0: only at the end of the run."""
    if trainer.get("checkpoint_every") is not None:
        return int(trainer["checkpoint_every"])
    return int(trainer.get("eval_every") or 0) or CHECKPOINT_EVERY_WITHOUT_EVALUATION


def write_policy_file(
    run_dir: Path,
    cfg_obs: str,
    task: str,
    aorta: str,
    image_options: dict | None = None,
    env_options: dict | None = None,
    normalize_observations: bool = False,
) -> None:
    """policy.json: what evaluating the checkpoint needs (observation preset, image options,
    and the environment options it was trained with that change what it sees or drives), in
    this version's run format (`run_files.RUN_FORMAT`)."""
    info = {
        "algo": "sac",
        "obs": cfg_obs,
        "image_options": dict(image_options or {}),
        "task": task,
        "aorta": aorta,
        "env_options": dict(env_options or {}),
        "normalize_observations": bool(normalize_observations),
    }
    run_files.write_policy_file(run_dir, info)


def save_model(model, path: Path) -> None:
    """`model` to `path` (atomic), and its observation normaliser beside it if it has one."""
    normalizer = model.get_vec_normalize_env()
    if normalizer is not None:
        run_files.write_atomic(run_files.normalizer_path(path), lambda tmp: normalizer.save(tmp))
    run_files.write_atomic(path, lambda tmp: model.save(tmp))


def load_policy_model(path: Path, device: str = "cpu"):
    """The SAC model saved at `path` (a .zip of a run), its actor the deterministic policy
    the run evaluated: SACfD's averaged actor when it kept one (`actor_average_tau` > 0).
    Its observation normaliser, if any, is `run_files.normalizer_path(path)`."""
    from cathsim_dmc.learning.rl.sacfd import SACfD

    model = SACfD.load(path, device=device)
    if model.actor_average is not None:
        model.actor.load_state_dict(model.actor_average)
    return model


def replay_buffer_path(folder: Path, step: int) -> Path:
    """The replay buffer saved with the checkpoint of `step`."""
    return Path(folder) / REPLAY_BUFFER_FORMAT.format(int(step))


def _replay_buffer_steps(folder: Path) -> dict:
    """step -> path of every replay buffer file in `folder`."""
    found = {}
    for path in Path(folder).glob(REPLAY_BUFFER_GLOB):
        digits = path.stem.rsplit("_", 1)[-1]
        if digits.isdigit():
            found[int(digits)] = path
    return found


def checkpoint_step(path: Path) -> int:
    """The environment steps an SB3 checkpoint had taken, read without loading it."""
    with zipfile.ZipFile(path) as archive:
        return int(json.loads(archive.read("data"))["num_timesteps"])


def save_checkpoint(model, folder: Path, replay_buffer: bool) -> Path:
    """One checkpoint of `model` at its current step n: step_<n>.zip, then last.zip (the
    same content), and before them, optionally, replay_buffer_step_<n>.pkl. Returns last.zip.

    Every file is written atomically, and last.zip is written last: it commits the
    checkpoint. A process killed at any point leaves last.zip at the previous step with
    that step's replay buffer still on disk (an older buffer is deleted only after the new
    last.zip is in place), so `resume_checkpoint` always finds a matching pair.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    step = int(model.num_timesteps)
    if replay_buffer:
        run_files.write_atomic(replay_buffer_path(folder, step), lambda tmp: model.save_replay_buffer(tmp))
    step_file = folder / f"step_{step}.zip"
    save_model(model, step_file)
    last = folder / LAST_CHECKPOINT
    copy_model(step_file, last)
    for old_step, path in _replay_buffer_steps(folder).items():
        if old_step != step or not replay_buffer:
            path.unlink(missing_ok=True)
    return last


def resume_checkpoint(folder: Path) -> tuple:
    """(last.zip, its step, the replay buffer saved with it or None) of a checkpoint folder.

    Removes what a killed run left half-done (temporary files, a replay buffer newer than
    last.zip), and refuses, naming the files, a replay buffer that cannot belong to
    last.zip: resuming with it would pair the weights of one step with the data of another.
    """
    folder = Path(folder)
    last = folder / LAST_CHECKPOINT
    if not last.is_file():
        raise FileNotFoundError(f"nothing to resume: no {LAST_CHECKPOINT} in {folder}")
    run_files.remove_temporaries(folder)
    step = checkpoint_step(last)
    buffers = _replay_buffer_steps(folder)
    for newer in [s for s in buffers if s > step]:  # written by a checkpoint that was never committed
        buffers.pop(newer).unlink()
    if step in buffers:
        return last, step, buffers[step]
    if buffers:
        found = ", ".join(p.name for p in buffers.values())
        raise RuntimeError(
            f"{last} is at step {step} but the replay buffer in {folder} ({found}) is not; "
            f"delete the buffer to resume with an empty one"
        )
    return last, step, None


def check_replay_buffer_step(buffer, step: int, source) -> None:
    """RuntimeError if `buffer` cannot hold the transitions of a run at `step` environment
    steps: every step stores one transition per environment, so a buffer that has not
    wrapped around holds exactly step / n_envs rows."""
    rows = buffer.buffer_size if buffer.full else buffer.pos
    if buffer.full and rows * buffer.n_envs <= step or not buffer.full and rows * buffer.n_envs == step:
        return
    raise RuntimeError(
        f"{source} holds {rows * buffer.n_envs:,} transitions{' (full)' if buffer.full else ''}, "
        f"not the {step:,} of the checkpoint it was saved with; delete it to resume with an empty one"
    )


def keep_if_best(
    model, run_dir: Path, step: int, success_rate: float, mean_return: float, episodes: int | None = None
) -> bool:
    """Save `model` as best.zip if its evaluation beats the best so far (success rate first,
    then return; a tie keeps the earlier one). best.json records the scores, the step and
    how many episodes the scores are over."""
    record_file = Path(run_dir) / CHECKPOINT_DIR / BEST_RECORD
    best = json.loads(record_file.read_text()) if record_file.is_file() else None
    if best is not None and (success_rate, mean_return) <= (best["success_rate"], best["mean_return"]):
        return False
    record_file.parent.mkdir(parents=True, exist_ok=True)
    save_model(model, record_file.parent / BEST_MODEL)
    record = {"step": int(step), "success_rate": success_rate, "mean_return": mean_return}
    if episodes is not None:
        record["episodes"] = int(episodes)
    write_best_record(run_dir, record)
    return True


def write_best_record(run_dir: Path, record: dict) -> None:
    """best.json of a run: the scores of best.zip, its step and how many episodes they are over."""
    run_files.write_atomic(Path(run_dir) / CHECKPOINT_DIR / BEST_RECORD, lambda tmp: tmp.write_text(json.dumps(record)))


def copy_model(source: Path, destination: Path) -> None:
    """A saved model copied (atomic), with its observation normaliser if it has one."""
    normalizer = run_files.normalizer_path(source)
    if normalizer.is_file():
        stats = normalizer.read_bytes()
        run_files.write_atomic(run_files.normalizer_path(destination), lambda tmp: tmp.write_bytes(stats))
    content = Path(source).read_bytes()
    run_files.write_atomic(destination, lambda tmp: tmp.write_bytes(content))


def best_record(run_dir: Path) -> dict | None:
    """best.json of a run (None if no periodic evaluation saved a best model)."""
    record_file = Path(run_dir) / CHECKPOINT_DIR / BEST_RECORD
    return json.loads(record_file.read_text()) if record_file.is_file() else None


def read_evaluations(run_dir: Path) -> list:
    """The run's periodic evaluations (evaluations.jsonl), oldest first."""
    path = Path(run_dir) / EVALUATIONS
    return [json.loads(line) for line in path.read_text().splitlines() if line.strip()] if path.is_file() else []


def append_evaluation(run_dir: Path, record: dict) -> None:
    """`record` appended to the run's evaluations.jsonl as one line."""
    with open(Path(run_dir) / EVALUATIONS, "a") as f:
        f.write(json.dumps(record) + "\n")


def evaluated_wall_seconds(run_dir: Path | None) -> float:
    """Wall seconds a run had taken at its last periodic evaluation (0 without one): where
    a resumed run's clock continues from."""
    evaluations = read_evaluations(run_dir) if run_dir is not None else []
    return float(evaluations[-1]["wall_s"]) if evaluations else 0.0
