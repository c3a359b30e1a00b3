"""Harness code shared by the tests and the benches (scenes, rigs, runs); not tests."""
