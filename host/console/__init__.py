"""`skel console`: the operator's web page (the paper's "operator interface for graphic
visualization ... and improved user reconfiguration control"). It shows what the layers
below compute and computes nothing of its own: the system and its prediction as `skel check`
gives them, pushes and runs as `skel push` and `skel run` make them, live tables as
`skel watch` keeps them, comparisons as `skel diff` prints them.

Beside cli/ at the top of host/ (tests/architecture/test_layers.py): it serves what the
command line's views compute (check's summary, watch's incremental tables), and the command
line starts it (`skel console`).
"""
