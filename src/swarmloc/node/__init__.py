"""The parts a node is made of (below the estimators that use them)."""
