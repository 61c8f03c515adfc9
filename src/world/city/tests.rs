//! Unit tests of the city simulation on tiny hand-made plans.
