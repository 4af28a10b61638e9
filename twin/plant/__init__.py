"""The plant: the analytic model of equation (1) and its IT2 Takagi–Sugeno approximation."""
