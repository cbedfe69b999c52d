"""skel, the host tool, in layers that import only downward:
model < sysfile < theory < live < console, cli (tests/test_layers.py holds them)."""
