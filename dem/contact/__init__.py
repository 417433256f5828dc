"""Contact geometry and laws: spheres (closed form), ellipsoids (Perram-Wertheim + Newton),
poly-ellipsoids (octant active set), the Hertz factor and the Hertz-Mindlin law.

CONTACT_METHODS names the ellipsoid contact geometries, in the order of the code the kernels
take (dem.forces): exact (PW + Newton on S^2), pw (Perram-Wertheim depth), sextic (Yan 2010);
DEFAULT_CONTACT_METHOD is the one a run takes when none is given. Plain names, importable before
numba starts.
"""
CONTACT_METHODS = ("exact", "pw", "sextic")
EXACT, PW, SEXTIC = 0, 1, 2   # the codes of CONTACT_METHODS (the kernels' `method` argument)
DEFAULT_CONTACT_METHOD = "exact"
