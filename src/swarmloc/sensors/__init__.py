"""Measurement models: relative pose, range-bearing, range, bearing (Cartesian with Jacobians)."""
