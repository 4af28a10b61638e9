"""Holding runs to account: a scenario's ``[expect]`` bounds (:mod:`~twin.scenarios.expectations`),
``twin check`` (:mod:`~twin.verify.check`), golden trajectories and their tolerances
(:mod:`~twin.outputs.golden`, :mod:`~twin.outputs.tolerances`), and a user's own regression
tests (:mod:`~twin.verify.testing`, the pytest plugin :mod:`~twin.verify.pytest_plugin`)."""
