"""Algorithms over the contract's types: kinematics, estimation, smoothing, guard, clouds.
Pure objects over numpy arrays and msgspec Structs: no I/O, no clocks, no globals."""
