"""Scenario scoring on logged tracks (no simulator): proximity / collisions now; SafeShift scores later."""

from scoring.proximity import PairProximity, any_collision, pair_gaps, pair_proximity, pool_proximity

__all__ = ["PairProximity", "any_collision", "pair_gaps", "pair_proximity", "pool_proximity"]
