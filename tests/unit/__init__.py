"""Unit tests: no skel-dpu started. A package, so a test of tests/e2e/ imports the helpers it
shares with the unit tests of the same module as `from unit.test_X import ...`."""
