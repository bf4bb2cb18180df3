"""Adjustment: the adjuster interface, observations, the bundle engine, priors, RPC bias
compensation."""
