"""Synthetic step times for the tests of intervals and ranking: their truth is known."""
import math

import numpy as np


def ar1(rng, n, mean, sd, phi):
    """n correlated step times: an AR(1) series of lag-1 correlation phi and spread sd about mean."""
    e = rng.normal(0.0, sd * math.sqrt(1.0 - phi ** 2), n)
    x = np.empty(n)
    x[0] = rng.normal(0.0, sd)
    for i in range(1, n):
        x[i] = phi * x[i - 1] + e[i]
    return mean + x
