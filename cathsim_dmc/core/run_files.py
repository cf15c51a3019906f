"""Files beside a checkpoint, shared by their writers (learning/rl/checkpoints.py,
learning/supervised/bc.py, agents/collect.py) and their readers (agents/trained.py,
learning/datasets.py), so that neither side imports the other. policy.json records the run
format (`RUN_FORMAT`) its readers check.

Every file is written under a temporary name and renamed into place, so a reader never
sees half a file. A temporary name is hidden and carries `.tmp` (`.last.tmp.zip`), keeps
the real suffix (so SB3 and NumPy do not append another), never matches a reader's
pattern (`shard_*.npz`, `*.zip`), and is removed when a writer starts again."""

from __future__ import annotations

import json
import os
import pickle
from pathlib import Path

POLICY_FILE = "policy.json"  # next to a checkpoint: what it needs to be evaluated
# The version of the run files (policy.json, the checkpoints and the config beside it) this
# cathsim-dmc writes and reads; policy.json records it. Files without it (run format 0) or
# with another are refused in one line (`read_policy_file`), never read half-right.
RUN_FORMAT = 1
FORMAT_KEY = "format_version"
NORMALIZER_SUFFIX = ".vecnormalize.pkl"  # <checkpoint>.vecnormalize.pkl: its observation normaliser
TEMPORARY_MARK = ".tmp"


def temporary_path(path) -> Path:
    """Where `path` is written before it is renamed into place: `.<stem>.tmp<suffix>`."""
    path = Path(path)
    return path.with_name(f".{path.stem}{TEMPORARY_MARK}{path.suffix}")


def is_temporary(path) -> bool:
    """True for a half-written file (this module's temporary names, and the older
    `<name>.tmp...` ones), which readers skip."""
    return TEMPORARY_MARK in Path(path).name


def write_atomic(path, write) -> Path:
    """Call `write(temporary)` and rename the result to `path`: all of it or none of it."""
    path = Path(path)
    tmp = temporary_path(path)
    write(tmp)
    os.replace(tmp, path)
    return path


def remove_temporaries(folder) -> list:
    """Delete the half-written files a killed writer left in `folder` (not its subfolders)."""
    folder = Path(folder)
    stale = [p for p in folder.iterdir() if p.is_file() and is_temporary(p)] if folder.is_dir() else []
    for path in stale:
        path.unlink(missing_ok=True)
    return stale


def normalizer_path(checkpoint) -> Path:
    """Where the observation normaliser of `checkpoint` (a .zip) is kept: beside it."""
    checkpoint = Path(checkpoint)
    return checkpoint.with_name(checkpoint.stem + NORMALIZER_SUFFIX)


def load_normalizer(path):
    """A saved SB3 VecNormalize (observation statistics), frozen for evaluation."""
    with open(path, "rb") as f:
        normalizer = pickle.load(f)
    normalizer.training = False
    return normalizer


def write_policy_file(folder, info: dict, indent: int | None = None) -> Path:
    """`<folder>/policy.json`: `info` (what evaluating the checkpoint needs) in this
    version's run format (atomic)."""
    record = {FORMAT_KEY: RUN_FORMAT, **info}
    return write_atomic(Path(folder) / POLICY_FILE, lambda tmp: tmp.write_text(json.dumps(record, indent=indent)))


def read_policy_file(path, what=None) -> dict:
    """The policy.json at `path`; ValueError in one line naming `what` (the checkpoint or
    run folder it describes; default: the file) when another version's run format wrote it."""
    info = json.loads(Path(path).read_text())
    found = info.get(FORMAT_KEY, 0) if isinstance(info, dict) else None
    whole = isinstance(found, int) and not isinstance(found, bool)
    if whole and found == RUN_FORMAT:
        return info
    what = path if what is None else what
    if whole and found > RUN_FORMAT:
        raise ValueError(
            f"{what} was written by a newer cathsim-dmc (run format {found}, this version reads {RUN_FORMAT}); "
            f"update cathsim-dmc to use it"
        )
    raise ValueError(
        f"{what} was written by an older cathsim-dmc (run format {found if whole else repr(found)}, "
        f"this version reads {RUN_FORMAT}); train it again"
    )


def check_run_format(run_dir) -> dict:
    """The policy.json of the run folder `run_dir` (`read_policy_file`), before a run is
    continued: FileNotFoundError when it has none, ValueError for another run format."""
    path = Path(run_dir) / POLICY_FILE
    if not path.is_file():
        raise FileNotFoundError(
            f"nothing to resume in {run_dir}: no {POLICY_FILE} (a run writes it before its first checkpoint)"
        )
    return read_policy_file(path, what=run_dir)


class Interrupted(KeyboardInterrupt):
    """Ctrl-C, after the work it stopped kept what was complete; its message says what was
    kept and how to continue. The command-line tools print it as one line (exit status 130)."""


# -- one writer per run folder ---------------------------------------------------------
LOCK_FILE = ".lock"  # in a run folder: the pid of the process writing into it


class FolderInUse(RuntimeError):
    """Another live process writes into the folder (its .lock names it)."""


def check_writable_folder(key: str, folder) -> Path:
    """`folder` (an output folder, new or existing) or a ValueError naming `key=folder` when it
    cannot be written: a file is there, a file stands where a parent folder would go, or the
    nearest existing folder refuses a file (permissions, a read-only file system). Nothing is
    left behind: the test file is anonymous."""
    import tempfile

    folder = Path(folder).expanduser()
    given = f"{key}={str(folder)!r}"
    if folder.exists() and not folder.is_dir():
        raise ValueError(f"{given} is a file; give a folder (new or existing)")
    existing = next(p for p in (folder.absolute(), *folder.absolute().parents) if p.exists())
    if not existing.is_dir():
        raise ValueError(f"{given} cannot be made: {existing} is a file, not a folder")
    try:
        with tempfile.TemporaryFile(dir=existing):
            pass
    except OSError as error:
        what = "written" if existing == folder.absolute() else f"made in {existing}"
        raise ValueError(f"{given} cannot be {what} ({error.strerror or error})") from None
    return folder


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # someone else's process
        return True
    return True


def lock_folder(folder) -> Path:
    """Make `folder` this process's until it exits: its pid in `<folder>/.lock`.

    The lock appears whole or not at all (a hard link of a written file), so two
    processes cannot both take it. A lock whose process is gone (killed) is taken over; a
    live one raises FolderInUse naming its pid. Outputs of two runs then never mix.
    """
    import atexit

    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    lock, pid = folder / LOCK_FILE, os.getpid()
    mine = folder / f".lock.{pid}{TEMPORARY_MARK}"
    mine.write_text(str(pid))
    try:
        for _ in range(3):
            try:
                os.link(mine, lock)
            except FileExistsError:
                try:
                    owner = int(lock.read_text() or 0)
                except (FileNotFoundError, ValueError):
                    owner = 0
                if owner == pid:
                    return lock
                if owner and _alive(owner):
                    raise FolderInUse(
                        f"{folder} is in use by another run (pid {owner}); "
                        f"choose another output folder or wait for that run to end"
                    ) from None
                lock.unlink(missing_ok=True)  # its process is gone
                continue
            atexit.register(unlock_folder, folder)
            return lock
    finally:
        mine.unlink(missing_ok=True)
    raise FolderInUse(f"{folder}: could not take its {LOCK_FILE}")


def unlock_folder(folder) -> None:
    """Remove `folder`'s lock if this process holds it."""
    lock = Path(folder) / LOCK_FILE
    try:
        if int(lock.read_text() or 0) == os.getpid():
            lock.unlink()
    except (FileNotFoundError, ValueError):
        pass
