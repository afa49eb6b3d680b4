"""rodgains: rod model, linearization, sampled-loop gain design and C header generation.

    import rodgains
    p = rodgains.load_params("my_rod.toml", ["rod.length=0.14"])   # SI units, validated
    d = rodgains.design(p)            # a Design: K (1, 2N), L (2N, 1), Ad, Bd, ... (see help(rodgains.Design))
    ol, ol_sampled, cl = d.to_statespace()                          # python-control StateSpace models

Angles are absolute edge angles [rad], 0 hanging and pi upright; the design's state is the
deviation from upright, z = [theta_1..theta_N, dtheta_1..dtheta_N] - x_upright.
"""

from .design import Design, StateSpaces, design
from .errors import DesignRefused, UserError
from .params import Params, load_params

__all__ = ["Design", "DesignRefused", "Params", "StateSpaces", "UserError", "design", "load_params"]
