"""The mesh import's time budget: every import answers, with an asset or one line, in bounded time.

The import runs as named steps (`ImportClock.step`); the whole import has `IMPORT_BUDGET_S`, and a
step may have a budget of its own (each meshing attempt of the fold remedies: `REMEDY_BUDGET_S`).
When a budget is spent the step is interrupted (a SIGALRM timer, in the main thread; elsewhere the
budget is checked as each step starts) and the import stops with one line naming the step, how
long it ran and what it was meshing at (`MeshImportError`).

The budgets are for the 2-core machine the project is built and tested on. Measured there on
2026-12-02 at commit e12e788 (`python experiments/import_close_ostia.py --options "" --options sdf_mm=0.4 --options
"edge_mm=1.5 sdf_mm=0.4"`, with other jobs sharing the cores): the ~7k-triangle close-ostia meshes
import with the defaults in 81-82 s (54-55 CPU s); with edge_mm=1.5 sdf_mm=0.4 `close_ostia` took
177 s and `shared_trunk` was stopped in the validation of its 71,752 wall pieces at 270 s (the
budget then), 180 CPU s.
"""

from __future__ import annotations

import contextlib
import signal
import threading
import time
from typing import Optional

from cathsim_dmc.anatomy.import_error import MeshImportError

# The whole import, validation included: an answer within 5 minutes, with room for the process's start
# and for a C call the timer cannot interrupt (a MuJoCo compile of 70k pieces, a distance transform).
IMPORT_BUDGET_S = 240.0
REMEDY_BUDGET_S = 100.0  # one meshing attempt (the first, or a fold remedy's)


class _OutOfTime(BaseException):
    """Raised by the timer inside the running step (a BaseException: no `except Exception` eats it)."""


class ImportClock:
    """Where an import is and how long it may still run (see the module docstring)."""

    def __init__(self, path, budget_s: float = IMPORT_BUDGET_S, started: Optional[float] = None):
        self.path = path
        self.budget_s = float(budget_s)
        self.t0 = time.perf_counter() if started is None else started
        self.name = "reading the mesh"
        self.step_t0 = self.t0
        self.step_budget: Optional[float] = None
        self._armed = False

    def elapsed(self) -> float:
        return time.perf_counter() - self.t0

    def remaining(self) -> float:
        return self.budget_s - self.elapsed()

    def _limit(self) -> float:
        left = self.remaining()
        if self.step_budget is not None:
            left = min(left, self.step_budget - (time.perf_counter() - self.step_t0))
        return left

    def _arm(self) -> None:
        if threading.current_thread() is not threading.main_thread():
            return
        signal.setitimer(signal.ITIMER_REAL, max(self._limit(), 1e-3))
        self._armed = True

    def begin(self, name: str, budget_s: Optional[float] = None) -> None:
        """Start step `name` (with its own `budget_s`, or only the import's)."""
        self.name, self.step_t0, self.step_budget = name, time.perf_counter(), budget_s
        if self._limit() <= 0:
            raise _OutOfTime()
        self._arm()

    @contextlib.contextmanager
    def step(self, name: str, budget_s: Optional[float] = None):
        """Run a block as step `name`; afterwards the import's own budget applies again."""
        outer = (self.name, self.step_t0, self.step_budget)
        self.begin(name, budget_s)
        try:
            yield
        finally:
            self.name, self.step_t0, self.step_budget = outer
            if self._armed:
                self._arm()

    def message(self) -> str:
        ran = time.perf_counter() - self.step_t0
        own = self.step_budget is not None and ran >= self.step_budget - 1e-3
        budget = (
            f"its {self.step_budget:.0f} s budget"
            if own
            else f"the import's {self.budget_s:.0f} s budget ({self.elapsed():.0f} s in all)"
        )
        return f"{self.path}: stopped: {self.name} ran {ran:.0f} s and spent {budget}"


@contextlib.contextmanager
def import_budget(clock: ImportClock):
    """Run an import under `clock`: a spent budget becomes one MeshImportError line."""
    main = threading.current_thread() is threading.main_thread()
    previous = None
    if main:

        def on_alarm(signum, frame):
            raise _OutOfTime()

        previous = signal.signal(signal.SIGALRM, on_alarm)
    try:
        clock._arm()
        yield clock
    except _OutOfTime:
        raise MeshImportError(clock.message()) from None
    finally:
        if main:
            signal.setitimer(signal.ITIMER_REAL, 0.0)
            signal.signal(signal.SIGALRM, previous)
