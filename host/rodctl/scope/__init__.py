"""The scope: a live matplotlib window on one session with a board (`rodctl scope`).

    from rodctl.scope.loop import close_scope, open_scope, run_window   # imports matplotlib.pyplot
    from rodctl.scope.window import Scope                              # on any figure (Agg in the tests)

window.py is the window (the rod, the time series, keys and buttons, recording); loop.py opens it on a
session, redraws it every 100 ms until it ends, and closes it. Nothing here imports matplotlib until
asked: the command line starts without a display.
"""
