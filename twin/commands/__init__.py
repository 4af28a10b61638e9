"""The ``twin`` commands, one module each: the options the command takes, the workflow of
:mod:`twin.workflows` it calls, and what it prints. :mod:`twin.cli` imports a command's
module only when that command runs (or its help is asked for): ``twin kinds`` does not load
the engine. What several commands share (options, progress bars, number formats) is in
:mod:`twin.commands.common`.
"""
