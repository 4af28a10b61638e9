"""The in-process half of tests/test_fuzz.py, in a child process so that a hang is caught
by the parent's timeout (and named: each case is announced before it starts).

Reads a JSON list of cases from the file named by argv[1]; for each prints one JSON line
``{"i": i, "start": true}`` before it and one with the outcome after it:

- ``ok``: loaded (and, for a case with ``"run": true``, ran) without an error;
- ``error``: a :class:`twin.errors.TwinError`, which the command line prints as one line
  ``error: ...`` with exit status 2 (its message is in ``message``);
- ``crash``: anything else, which the command line would print as a traceback
  (``traceback`` holds it).

A case is ``{"scenario": NAME or null, "text": TOML or null, "name": file name, "overrides":
[...], "run": bool}``: it does what ``twin run SCENARIO --set ... --no-video --controller
lqr`` does before and while it runs (load and check the scenario, build the controllers
and the estimator, run), without writing files.

Usage: python tests/fuzz_child.py CASES.json WORK_DIR
"""
from __future__ import annotations

import json
import os
import sys
import time
import traceback
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def run_case(case: dict, work: Path) -> dict:
    from twin.errors import TwinError
    from twin.scenarios import load_scenario
    from twin.workflows.run import run_scenario

    try:
        if case["text"] is not None:
            path = work / case["name"]
            path.write_bytes(case["text"].encode("utf-8", "surrogatepass"))
            target = str(path)
        else:
            target = case["scenario"]
        sc = load_scenario(target, case["overrides"])
        context = sc.build_context()
        for kind in sc.controllers:  # as twin run does (twin.scenarios.planning.plan): every controller built once
            sc.build_controller(kind, context)
        sc.build_estimator(context)
        if case["run"]:
            run_scenario(sc, ("lqr",), out=None, video=False)
        return {"outcome": "ok"}
    except TwinError as exc:
        return {"outcome": "error", "type": type(exc).__name__, "message": str(exc)}
    except BaseException:  # noqa: BLE001 -- what the command line would show as a traceback
        return {"outcome": "crash", "traceback": traceback.format_exc()}


def main() -> None:
    cases = json.loads(Path(sys.argv[1]).read_text(encoding="utf-8"))
    work = Path(sys.argv[2])
    work.mkdir(parents=True, exist_ok=True)
    os.chdir(work)  # whatever a case would write (nothing, if all is well) stays here
    for i, case in enumerate(cases):
        print(json.dumps({"i": i, "start": True}), flush=True)
        t0 = time.perf_counter()
        result = run_case(case, work)
        result.update(i=i, seconds=time.perf_counter() - t0)
        print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
