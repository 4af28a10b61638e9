"""What a run leaves for people and programs: its metrics (:mod:`~twin.outputs.metrics`), files
written as a unit (:mod:`~twin.outputs.rundir`, :mod:`~twin.outputs.report`), figures
(:mod:`~twin.outputs.figure`, drawn in a worker process by :mod:`~twin.outputs.figure_worker`),
the environment it ran in (:mod:`~twin.outputs.fingerprint`) and two runs side by side
(:mod:`~twin.outputs.compare`)."""
