"""``twin calibrate``: a robot's physical parameters (and the twin that runs it) fitted to its
sensor logs (:mod:`twin.calibrate`), into a directory written as a unit: report.json,
robot.toml (the fitted robot, complete: :mod:`twin.calibrate.robot_file`), calibration.toml,
figure.png and the manifest."""
from __future__ import annotations

import tomllib
from dataclasses import dataclass
from pathlib import Path

from twin.calibrate import identify, output, robot_file
from twin.calibrate.parameters import parse_names
from twin.calibrate.robot import same_geometry, to_twin, validate_physical
from twin.calibrate.run import TURN_RATE, calibrate as fit_logs, model_for
from twin.calibrate.validate import same_robot, validate
from twin.errors import TwinError
from twin.logs.format import read_log
from twin.outputs import report, rundir


@dataclass
class Calibration:
    """What a calibration found: ``cal`` (the fit, :mod:`twin.calibrate.run`), ``params`` (each
    parameter's value, 95 % interval, unit and whether the logs identify it), ``warnings``,
    ``validation`` (per held-out log, or None), ``twin`` (the twin's parameters that reproduce
    a robot fitted by its physical equations, or None), ``doc`` (report.json), ``toml``
    (calibration.toml's text) and ``robot`` (robot.toml's: the fitted robot)."""

    cal: object
    params: dict
    warnings: list
    validation: list | None
    twin: dict | None
    doc: dict
    toml: str
    robot: str | None  # None: the fitted figures make no robot the twin can run (a warning says why)

    @property
    def twin_why(self) -> str | None:
        """Why the twin cannot run this robot (calibration.toml records it, without [plant]), or None."""
        return tomllib.loads(self.toml)["calibration"].get("twin_why")


def calibrate(logs, parameters: str | None = None, held_out=(), seed: int = 0, model_kind: str = "auto",
              out: Path = Path("runs/calibration"), say=None) -> Calibration:
    """Fit the robot of ``logs`` (several logs of one robot together): ``parameters`` the names
    to fit (comma-separated; None: the default set), ``held_out`` logs to validate on,
    ``seed`` the bootstrap's, ``model_kind`` "physical", "twin" or "auto"; ``say(line)`` is
    told what is read and how the fit advances. Writes ``out``."""
    say = say or (lambda line: None)
    names = parse_names(parameters) if parameters is not None else None
    if not logs:
        raise TwinError("twin calibrate needs a LOG (a sensor log's directory); 'twin calibrate --list' names the "
                        "parameters")
    seen = {}
    for p in logs:  # one log twice would count its information twice
        key = Path(p).resolve()
        if key in seen:
            raise TwinError(f"twin calibrate: the log {p} is given twice (as {seen[key]}); give each log once")
        seen[key] = p
    read = [read_log(p) for p in logs]
    log = read[0]
    for other in read[1:]:
        same_geometry(log, other)
    kind = model_for(read, model_kind)
    held = [read_log(p) for p in held_out]
    for h in held:
        same_robot(log, h) if kind == "twin" else same_geometry(log, h)
    with rundir.written_whole(out, "twin calibrate") as path:
        for lg in read:
            say(f"{lg.path}: {lg.duration:g} s at {lg.control_rate:g} Hz")
        cal = fit_logs(read, names, seed=seed, progress=lambda m: say(f"  {m}"), model=kind)
        params, warnings, corr = identify.assess(cal, TURN_RATE)
        twin = None
        if kind == "physical":
            twin = to_twin(cal, params)
            val = validate_physical(cal, held, progress=lambda m: say(f"  {m}")) if held else None
        else:
            val = validate(cal, held) if held else None
        doc = output.report_doc(cal, params, warnings, corr, output.strip_private(val), seed, twin)
        report.write_json(doc, path / "report.json")
        toml_text = output.calibration_toml(cal, params, twin, geometry=(read[0].model.r, read[0].model.b))
        (path / "calibration.toml").write_text(toml_text, encoding="utf-8")
        try:
            robot_text = robot_file.robot_text(robot_file.input_robot(log), params, [str(p) for p in logs], kind)
        except robot_file.UnfitRobot as exc:  # the calibration stands: said, and in report.json
            robot_text = None
            warnings.append(str(exc))
            doc["warnings"] = list(doc.get("warnings", [])) + [str(exc)]
            report.write_json(doc, path / "report.json")
        else:
            (path / "robot.toml").write_text(robot_text, encoding="utf-8")
        output.write_figure(cal, params, val, path / "figure.png")
    return Calibration(cal, params, warnings, val, twin, doc, toml_text, robot_text)


__all__ = ["Calibration", "calibrate"]
