"""``twin replay``: estimators replayed on sensor logs (:mod:`twin.logs.replay`), into a
directory written as a unit: replay.json, estimates.csv, one figure per log and the manifest."""
from __future__ import annotations

from pathlib import Path

from twin.errors import TwinError
from twin.logs.replay import figure_name, replay_logs_contained, write_estimates_csv, write_figure
from twin.outputs import report, rundir
from twin.registry import check_kinds


def estimator_kinds(text: str) -> tuple[str, ...]:
    """--estimator's comma-separated kinds, checked; the ``ideal`` one (it reads the truth) refused."""
    kinds = check_kinds("estimator", [k.strip() for k in text.split(",") if k.strip()], "--estimator")
    if "ideal" in kinds:
        raise TwinError("--estimator: 'ideal' reads the truth, which a log's readings are not; allowed: ekf, "
                        "complementary, kalman2 or package.module:attribute")
    return kinds


def replay(logs, kinds, noise: str, out: Path) -> tuple[dict, list[str]]:
    """Replay estimator ``kinds`` on each of ``logs`` (a plugin estimator in a worker process) with
    the IMU noise figures ``noise`` says; write ``out``. Returns (replay.json's document, the
    figures' file names)."""
    with rundir.written_whole(out, "twin replay") as path:
        doc, replays = replay_logs_contained(logs, kinds, noise)
        report.write_json(doc, path / "replay.json")
        write_estimates_csv(replays, path / "estimates.csv")
        figures = [figure_name(k) for k in range(len(doc["logs"]))]
        for k, name in enumerate(figures):  # one per log: figure.png, figure-2.png, ...
            write_figure(doc, replays, path / name, which=k)
    return doc, figures


__all__ = ["estimator_kinds", "replay"]
