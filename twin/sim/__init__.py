"""The engine of a run: its specification (:mod:`twin.sim.spec`), the closed loop and the
driver that turns a specification into a logged run (:mod:`twin.sim.simulate`).

    Scenario ──run_spec()──▶ RunSpec ──simulate()──▶ ClosedLoop(plant → sensors → estimator
                                                      → controller → actuators) ──▶ Recorder ──▶ Run
"""
