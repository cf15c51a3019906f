"""The project speaks of the simulator and its users, not of how it was built: the word
"session" (a period of work) appears nowhere in the docs, configs, scripts or code.

A result carries a date, a commit, a machine and a command instead. The one sense that
stays is the teleoperation's: `TeleopSession` (one word, so the pattern does not see it)
and the teleoperation modules, where a session is the user's driving run at the keyboard.
"""

import re
from pathlib import Path

SCANNED = ("README.md", "CHANGELOG.md", "docs", "conf", "scripts", "experiments", "cathsim_dmc", "tasks")
TEXT_SUFFIXES = {".md", ".py", ".yaml", ".yml", ".sh", ".c", ".h", ".txt", ".toml", ".cfg", ".json"}
# Where "session" means a teleoperation run (the class, its instance and its docstrings).
TELEOPERATION_MODULES = ("cathsim_dmc/control/teleop.py", "cathsim_dmc/app/cli/teleop.py")
WORD = re.compile(r"\bsessions?\b", re.IGNORECASE)


def text_files(root: Path):
    for name in SCANNED:
        path = root / name
        if path.is_file():
            yield path
        elif path.is_dir():
            yield from (
                p
                for p in sorted(path.rglob("*"))
                if p.is_file() and p.suffix in TEXT_SUFFIXES and "__pycache__" not in p.parts
            )


def work_sense_mentions(root: Path) -> list:
    """'path:line: text' for every "session(s)" outside the teleoperation modules."""
    found = []
    for path in text_files(root):
        relative = path.relative_to(root).as_posix()
        if relative in TELEOPERATION_MODULES:
            continue
        for number, line in enumerate(path.read_text(errors="replace").splitlines(), start=1):
            if WORD.search(line):
                found.append(f"{relative}:{number}: {line.strip()[:100]}")
    return found


def test_the_project_never_speaks_of_work_sessions(repo_root):
    mentions = work_sense_mentions(repo_root)
    assert not mentions, "\n".join(mentions)


def test_the_check_finds_the_word_and_spares_the_teleoperation(tmp_path):
    (tmp_path / "docs").mkdir()
    (tmp_path / "docs" / "page.md").write_text("Measured 2026-11-26.\n## Session 17: results\n")
    (tmp_path / "conf").mkdir()
    (tmp_path / "conf" / "train.yaml").write_text("steps: 8000  # as in earlier sessions\n")
    (tmp_path / "cathsim_dmc" / "app" / "cli").mkdir(parents=True)
    (tmp_path / "cathsim_dmc" / "app" / "cli" / "teleop.py").write_text("session = TeleopSession(env)\n")
    (tmp_path / "cathsim_dmc" / "suite").mkdir()
    (tmp_path / "cathsim_dmc" / "suite" / "gym.py").write_text("class TeleopSession: pass  # a class name is fine\n")
    (tmp_path / "docs" / "figure.png").write_bytes(b"session")  # not text: not read
    mentions = work_sense_mentions(tmp_path)
    assert sorted(mentions) == [
        "conf/train.yaml:1: steps: 8000  # as in earlier sessions",
        "docs/page.md:2: ## Session 17: results",
    ]
