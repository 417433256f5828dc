"""`bench contacts`: the contacts of a configuration, as JSON-ready dicts, resolved by the same
pair dispatch as the step (dem.forces.pair_geometry)."""
import numpy as np

from dem.forces import EXACT, pair_contacts
from dem.integrate import derive_geometry_range, derive_range
from dem.neighbor import PairBuffer, candidate_pairs


def scene_contacts(scene):
    """List of {"i", "j", "depth", "point", "normal"}: i < j file-order indices, normal from i to j.
    A pair with a poly-ellipsoid is resolved by the octant active-set solver on the octant geometry;
    ellipsoids by the exact method, without warm start."""
    s = scene.state
    n = s.n
    pi, pj = candidate_pairs("allpairs", s.pos, s.rbound, s.gid, s.n_owned, PairBuffer(1024))
    rot = np.zeros((n, 3, 3))
    derive_range(0, n, s.quat, s.angmom, s.inertia, s.shape, rot, np.zeros((n, 3)))
    g = n if s.has_poly else 0
    oorg, orot, ax6 = np.zeros((g, 3)), np.zeros((g, 3, 3)), np.zeros((g, 6))
    if s.has_poly:
        derive_geometry_range(0, n, s.pos, rot, s.axes, s.shape, s.poly, orot, oorg, ax6)
    # file order = gid order here (a freshly loaded scene): pairs sorted by (i, j)
    pairs = sorted(zip(s.gid[pi].tolist(), s.gid[pj].tolist()))
    a = np.array([p[0] for p in pairs], dtype=np.int64)
    b = np.array([p[1] for p in pairs], dtype=np.int64)
    rows = np.zeros((len(pairs), 8))
    pair_contacts(a, b, s.pos, rot, s.axes, s.shape, EXACT, (s.poly, oorg, orot, ax6), rows)
    return [{"i": int(i), "j": int(j), "depth": float(r[1]), "point": [float(v) for v in r[5:8]],
             "normal": [float(v) for v in r[2:5]]} for (i, j), r in zip(pairs, rows) if r[0]]
