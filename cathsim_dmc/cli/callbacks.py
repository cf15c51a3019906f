"""Hydra callbacks shared by the command-line tools."""

from __future__ import annotations

from hydra.experimental.callback import Callback


class CombineMetrics(Callback):
    """After a multirun, write one metrics table (metrics.md, metrics.json) for all its jobs."""

    def on_multirun_end(self, config, **kwargs) -> None:
        from cathsim_dmc.evaluation import combine_reports

        table = combine_reports(config.hydra.sweep.dir)
        if table:
            print(table, end="")
            print(f"combined table in {config.hydra.sweep.dir}/metrics.md")
