"""The engine of a run: its specification (:mod:`~twin.sim.spec`), the closed loop
(:mod:`~twin.sim.loop`), the driver that turns a specification into a logged run
(:mod:`~twin.sim.simulate`), the recorder (:mod:`~twin.sim.recorder`) and the run's log
(:mod:`~twin.sim.runs`); :mod:`~twin.sim.bullet_loop` and :mod:`~twin.sim.analytic_loop`
keep the keyword-argument forms of 0.1 (``simulate_twin``, ``analytic_loop.simulate``).

    Scenario ──run_spec()──▶ RunSpec ──simulate()──▶ ClosedLoop(plant → sensors → estimator
                                                      → controller → actuators) ──▶ Recorder ──▶ Run
"""
