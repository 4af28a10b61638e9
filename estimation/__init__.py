"""State estimation from simulated sensors (θ, ψ, α with covariance).

The filterpy-based estimator and its baselines arrive with the sensor models; until then
the controllers of :mod:`twin` act on the true state of the analytic model.
"""
