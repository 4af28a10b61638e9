"""``twin compare``: two results (run directories or golden trajectories) side by side
(:mod:`twin.outputs.compare`), with the figure written where asked."""
from __future__ import annotations

from pathlib import Path

from twin.errors import TwinError
from twin.outputs import compare as cmp, rundir
from twin.outputs.report import write_json


def compare(a: Path, b: Path, tolerances, figure_path: Path | None = None, out: Path | None = None,
            say=None) -> tuple[object, str | None]:
    """Compare ``b`` with the reference ``a`` under ``tolerances``; ``say(text)`` is given the
    report as soon as it is made. With ``out``, comparison.json and comparison.png are written
    there as a unit; with ``figure_path``, the figure alone. Returns (the comparison, what was
    written: a line, or None)."""
    if figure_path is not None and out is not None:
        raise TwinError("--figure PATH and --out DIR both say where the figure goes; give one of them")
    target = rundir.StagedDirectory(out, "twin compare", "comparison") if out is not None else None
    try:
        result = cmp.compare(cmp.load(a), cmp.load(b), tolerances)
        if say is not None:
            say(cmp.report(result))
        if target is not None:  # written as a unit, with its manifest: a directory of twin compare's
            with rundir.written_whole(out, "twin compare") as path:
                write_json(cmp.as_json(result), path / "comparison.json")
                cmp.figure(result, path / "comparison.png")
            return result, f"wrote {out}/: comparison.json, comparison.png, {rundir.MANIFEST}"
        if figure_path is not None:
            return result, f"wrote {cmp.figure(result, figure_path)}"
        return result, None
    finally:
        if target is not None:
            target.close()


__all__ = ["compare"]
