"""The ``twin`` command line: the process a command runs in, and the commands by name.

Every user error ends with a one-line ``error: …`` on stderr and exit status 2; SIGINT and
SIGTERM end a command with one line saying what was kept, and exit status 130 or 143. Each
command is a module of :mod:`twin.commands` (its options, the workflow it calls, what it
prints), imported when that command runs: ``twin kinds`` does not load the engine.
"""
from __future__ import annotations

import atexit
import importlib
import os
import sys
import threading

# One OpenBLAS thread unless the user says otherwise, set before NumPy loads: the twin's
# matrices are 12 × 12 at most, which OpenBLAS computes on one thread anyway (the same
# numbers), while starting its thread pool cost every command 60 ms of its start-up on the
# project's 2-core machine; sweeps run one process per CPU already
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")


def _the_process() -> bool:
    """True when this module is the process's command (the ``twin`` script, ``python -m
    twin``, ``python -m twin.cli``), not imported by a program or a test that calls :func:`main` in its own process
    (click's CliRunner): the command then owns the process's signals from its start, and its end."""
    m = sys.modules.get("__main__")
    spec = getattr(m, "__spec__", None)
    if spec is not None and getattr(spec, "name", None) in ("twin.cli", "twin.__main__"):  # python -m twin(.cli)
        return True
    return os.path.basename(getattr(m, "__file__", None) or "") in ("twin", "twin-script.py", "twin.exe")


from twin.outputs import rundir  # noqa: E402 -- after the thread setting above

if _the_process():  # from here (before the heavy imports below) a signal is noted, and raised once main() runs
    rundir.hold_from_start()
    if sys.argv[1:2] == ["run"]:  # the figure's worker, started before the imports below (see twin.commands.run)
        from twin.outputs import figure_worker  # only for twin run: it starts matplotlib's process

        figure_worker.start_early()


import click  # noqa: E402

from twin.errors import TwinError  # noqa: E402

# every command, by name: the module that holds it and its name there (twin.commands)
COMMANDS = {
    "cache": "twin.commands.cache:cache", "calibrate": "twin.commands.calibrate:calibrate_command",
    "check": "twin.commands.check:check_command", "compare": "twin.commands.compare:compare_command",
    "design": "twin.commands.design:design", "export": "twin.commands.export:export_command", "kinds": "twin.commands.listing:kinds_command",
    "linearize": "twin.commands.linearize:linearize", "pil": "twin.commands.pil:pil_command",
    "replay": "twin.commands.replay:replay_command", "robots": "twin.commands.listing:robots_command",
    "run": "twin.commands.run:run",
    "scenarios": "twin.commands.listing:scenarios_command", "surface": "twin.commands.surface:surface",
    "sweep": "twin.commands.sweep:sweep",
    # gave way to twin run: hidden, each says what replaced it
    "analytic": "twin.commands.gone:analytic", "physics": "twin.commands.gone:physics",
}




class _Group(click.Group):
    """Turns usage errors, TwinError and file errors into one line and exit status 2, and
    SIGINT and SIGTERM into one line saying what was kept and exit status 130 or 143. Its
    commands are :data:`COMMANDS`, each imported when asked for (click's lazy group)."""

    def list_commands(self, ctx):
        return sorted(COMMANDS)

    def get_command(self, ctx, name):
        where = COMMANDS.get(name)
        if where is None:
            return None
        module, _, attribute = where.partition(":")
        return getattr(importlib.import_module(module), attribute)

    def main(self, args=None, prog_name=None, **extra):
        # SIGTERM (a CI runner's timeout, a container stopping, kill) otherwise ends the
        # process where it stands: no clean-up, no message; SIGINT's KeyboardInterrupt became
        # "error: aborted" and exit status 1, a failed bound's. Both now raise Interrupted,
        # which every command's clean-up sees, and end here with 128 + the signal's number.
        # Every way out goes through _leave: from the moment the exit status is decided, a
        # signal is noted, not raised (no traceback, no second line while the command ends).
        with rundir.interrupts_raise():
            try:
                try:
                    rundir.started()  # a signal that came while the command line loaded: raised here
                    rv = super().main(args=args, prog_name=prog_name, standalone_mode=False, **extra)
                    status = rv if isinstance(rv, int) else 0
                except click.UsageError as exc:
                    rundir.leaving()
                    hint = f" (see 'twin {exc.ctx.info_name if exc.ctx and exc.ctx.parent else ''} --help')".replace("  ", " ")
                    click.echo(f"error: {' '.join(exc.format_message().split())}{hint}", err=True)
                    status = 2
                except click.ClickException as exc:
                    rundir.leaving()
                    click.echo(f"error: {exc.format_message()}", err=True)
                    status = exc.exit_code
                except click.Abort as exc:
                    cause = exc.__cause__ or exc.__context__
                    if isinstance(cause, KeyboardInterrupt):  # while click parsed the arguments
                        status = _interrupted(cause)
                    else:
                        rundir.leaving()
                        click.echo("error: aborted", err=True)
                        status = 1
            except KeyboardInterrupt as exc:  # after click's own handling (while it prints), or in the clauses above
                status = _interrupted(exc)
            except SystemExit as exc:  # an error's or an interrupt's in invoke, or a command's own exit
                status = _exit_code(exc)
            except BaseException as exc:  # noqa: BLE001 -- what a library made of an interrupt (a Rust panic, say)
                if rundir.signal_received() is None:
                    raise  # a bug: its traceback
                status = _interrupted(exc)
            _leave(status)

    def invoke(self, ctx):
        try:
            rv = super().invoke(ctx)
        except KeyboardInterrupt as exc:
            sys.exit(_interrupted(exc))
        except TwinError as exc:
            rundir.leaving()
            click.echo(f"error: {_with_kept(str(exc), exc)}", err=True)
            sys.exit(2)
        except OSError as exc:
            rundir.leaving()
            text = f"{exc.strerror or exc}: {exc.filename or ''}".rstrip(": ")
            click.echo(f"error: {_with_kept(text, exc)}", err=True)
            sys.exit(2)
        if not rundir.kept_so_far():  # a signal from here on finds the command's work done
            rundir.keep_so_far("the command had finished: its outputs are complete")
        return rv


def _with_kept(text: str, exc: BaseException) -> str:
    kept = rundir.kept_text(exc)
    return f"{text}; {kept}" if kept else text


def _interrupted(exc: BaseException) -> int:
    """One line on stderr, the signal and what was kept; the exit status, 130 (SIGINT) or 143
    (SIGTERM). Signals are noted, not raised, from here on (rundir.leaving)."""
    rundir.leaving()
    kept = rundir.kept_text(exc) or rundir.kept_so_far()
    click.echo(f"interrupted: {rundir.signal_name(exc)}" + (f"; {kept}" if kept else ""), err=True)
    return rundir.exit_status_of(exc)


def _exit_code(exc: SystemExit) -> int:
    """The exit status ``sys.exit(code)`` asks for, as Python would make it (a text is said, and is 1)."""
    code = exc.code
    if code is None:
        return 0
    if isinstance(code, int):
        return code
    rundir.leaving()
    click.echo(str(code), err=True)
    return 1


def _late(status: int) -> int:
    """``status``, or 130 / 143 with its one line if a signal came to a command ending well (one
    noted as it ended, or one a library swallowed): a signal is never an exit status of 0."""
    got = rundir.signal_received() if status == 0 else None
    if got is None:
        return status
    exc = rundir.Interrupted(got)
    kept = rundir.kept_so_far()
    click.echo(f"interrupted: {exc.name}" + (f"; {kept}" if kept else ""), err=True)
    return 128 + got


def _leave(status: int):
    """End the command with ``status`` (SIGINT and SIGTERM noted from now on: rundir.leaving).

    As the process's command, without the interpreter's teardown: the atexit functions run,
    the output is flushed and the process ends (os._exit). Python's teardown takes 50-60 ms
    after a run (numpy, matplotlib, PyBullet), and puts the default handlers back while it
    runs: a SIGTERM there ended the process with no word (exit status -15), a SIGINT with a
    KeyboardInterrupt, and an extension module half made by an interrupt could crash it
    (abort, -6). Imported by a program or a test, main() ends with SystemExit as before."""
    rundir.leaving()
    status = _late(status)
    others = [t for t in threading.enumerate() if t is not threading.main_thread() and not t.daemon and t.is_alive()]
    if not _the_process() or others:  # threads to wait for: Python's own exit does that
        sys.exit(status)
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):  # a closed pipe, say: Python's own exit says so, as before
        sys.exit(status)
    atexit._run_exitfuncs()
    status = _late(status)  # one that came meanwhile
    try:
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):
        pass
    os._exit(status)




@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(None, "-V", "--version", package_name="mtwip-twin")
def main():
    """Digital twin of a mobile two-wheeled inverted pendulum under IT2 fuzzy control.

    \b
    Examples:
      twin design --decay-rate 3 --out gains.json
      twin run paper-exp3
      twin run paper-exp3 --set plant.model=analytic --set plant.scale={} --set sensors.sensing=ideal
      twin run paper-exp1 --controller it2,t1,lqr --set plant.scale={}
      twin sweep paper-exp3 --samples 50 --workers 2
      twin run paper-exp3 --log-sensors --no-video --out runs/exp3
      twin replay runs/exp3/sensor-logs/it2 --estimator ekf,complementary
      twin calibrate runs/exp3/sensor-logs/it2 --out runs/calibration
      twin scenarios
      twin robots
      twin kinds
      twin surface position --out runs/surfaces
      twin compare runs/before runs/after
    """



if __name__ == "__main__":  # pragma: no cover
    main()
