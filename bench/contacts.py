"""`bench contacts`: the contacts of a configuration, as JSON-ready dicts."""
import numpy as np

from dem.contact.ellipsoid import OUT_DEPTH, OUT_LEN, OUT_NX, OUT_XCX, ellipsoid_contact
from dem.contact.polyellipsoid import polyellipsoid_contact
from dem.contact.sphere import sphere_contact
from dem.integrate import derive_geometry_range, derive_range
from dem.neighbor import PairBuffer, candidate_pairs
from dem.state import POLY, SPHERE


def scene_contacts(scene):
    """List of {"i", "j", "depth", "point", "normal"}: i < j file-order indices, normal from i to j.
    A pair with a poly-ellipsoid is resolved by the octant active-set solver on the octant geometry."""
    s = scene.state
    n = s.n
    pi, pj = candidate_pairs("allpairs", s.pos, s.rbound, s.gid, s.n_owned, PairBuffer(1024))
    rot = np.zeros((n, 3, 3))
    derive_range(0, n, s.quat, s.angmom, s.inertia, s.shape, rot, np.zeros((n, 3)))
    g = n if s.has_poly else 0
    oorg, orot, ax6 = np.zeros((g, 3)), np.zeros((g, 3, 3)), np.zeros((g, 6))
    if s.has_poly:
        derive_geometry_range(0, n, s.pos, rot, s.axes, s.shape, s.poly, orot, oorg, ax6)
    out = np.zeros(OUT_LEN)
    rows = []
    for i, j in sorted(zip(s.gid[pi].tolist(), s.gid[pj].tolist())):
        if s.shape[i] == SPHERE and s.shape[j] == SPHERE:
            hit, depth, nx, ny, nz, x, y, z, _ = sphere_contact(*s.pos[i], s.axes[i, 0], *s.pos[j], s.axes[j, 0])
            if not hit:
                continue
            normal, point = [nx, ny, nz], [x, y, z]
        else:
            if s.shape[i] == POLY or s.shape[j] == POLY:
                hit = polyellipsoid_contact(oorg[i], orot[i], ax6[i], oorg[j], orot[j], ax6[j], np.zeros(3), out)
            else:
                hit = ellipsoid_contact(s.pos[i], rot[i], s.axes[i], s.pos[j], rot[j], s.axes[j], -1.0,
                                        np.zeros(3), out)
            if not hit:
                continue
            depth = out[OUT_DEPTH]
            normal = out[OUT_NX:OUT_NX + 3].tolist()
            point = out[OUT_XCX:OUT_XCX + 3].tolist()
        rows.append({"i": int(i), "j": int(j), "depth": float(depth), "point": [float(v) for v in point],
                     "normal": [float(v) for v in normal]})
    return rows
