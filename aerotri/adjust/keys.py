"""The symbols (gtsam keys) of the adjustment's unknowns: ``x`` camera poses, ``p`` object points, ``a``
GNSS antenna positions, ``s``/``d`` per-strip GNSS shift and drift, ``k`` the Cal3DS2 calibration, ``l``
the lever arm."""

from __future__ import annotations

import gtsam

X = lambda i: gtsam.symbol("x", int(i))  # noqa: E731
P = lambda j: gtsam.symbol("p", int(j))  # noqa: E731
A = lambda i: gtsam.symbol("a", int(i))  # noqa: E731
S = lambda s: gtsam.symbol("s", int(s))  # noqa: E731
D = lambda s: gtsam.symbol("d", int(s))  # noqa: E731
K_KEY = gtsam.symbol("k", 0)
L_KEY = gtsam.symbol("l", 0)
