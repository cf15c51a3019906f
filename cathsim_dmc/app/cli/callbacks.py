"""Hydra callbacks shared by the command-line tools."""

from __future__ import annotations

from hydra.experimental.callback import Callback


class CombineMetrics(Callback):
    """After a multirun, write one metrics table (metrics.md, metrics.json) for all its jobs."""

    def on_multirun_end(self, config, **kwargs) -> None:
        from cathsim_dmc.evaluation.rollouts import combine_reports

        table = combine_reports(config.hydra.sweep.dir)
        if table:
            print(table, end="")
            print(f"combined table in {config.hydra.sweep.dir}/metrics.md")


class CheckConfig(Callback):
    """Before Hydra makes a run's folder, every value it could not check itself
    (`cathsim_dmc.app.cli._common.check_config`): the first bad one stops the run with one
    line and exit status 2, and no folder is left behind. Listed before RunFolderLock, which
    makes the folder. A sweep's jobs are checked as each starts; its folder here."""

    def on_run_start(self, config, **kwargs) -> None:
        from cathsim_dmc.app.cli._common import check_before_the_run

        check_before_the_run(config)

    def on_multirun_start(self, config, **kwargs) -> None:
        from cathsim_dmc.app.cli._common import fail
        from cathsim_dmc.core.run_files import check_writable_folder

        try:
            check_writable_folder("hydra.sweep.dir", config.hydra.sweep.dir)
        except ValueError as error:
            fail(str(error))


class RunFolderLock(Callback):
    """Before Hydra writes anything into a run's folder, take the folder's lock
    (`cathsim_dmc.core.run_files.lock_folder`): a second run aimed at a folder a live run holds
    stops with one line and exit status 2, and the first run's outputs stay its own."""

    def on_run_start(self, config, **kwargs) -> None:
        from cathsim_dmc.app.cli._common import fail
        from cathsim_dmc.core.run_files import FolderInUse, lock_folder

        # The same config object gives Hydra its folder: `now` is resolved once and cached.
        try:
            lock_folder(config.hydra.run.dir)
        except FolderInUse as error:
            fail(str(error))
