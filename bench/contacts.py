"""`bench contacts`: the contacts of a configuration, as JSON-ready dicts."""
import numpy as np

from dem.contact.ellipsoid import (ellipsoid_contact, OUT_LEN, OUT_DEPTH, OUT_NX, OUT_XCX)
from dem.contact.sphere import sphere_contact
from dem.neighbor import PairBuffer, candidate_pairs
from dem.quaternion import quat_to_matrix
from dem.state import SPHERE


def scene_contacts(scene):
    """List of {"i", "j", "depth", "point", "normal"}: i < j file-order indices, normal from i to j."""
    s = scene.state
    pi, pj = candidate_pairs("allpairs", s.pos, s.rbound, s.gid, s.n_owned, PairBuffer(1024))
    out = np.zeros(OUT_LEN)
    r1 = np.zeros((3, 3))
    r2 = np.zeros((3, 3))
    rows = []
    for i, j in sorted(zip(s.gid[pi].tolist(), s.gid[pj].tolist())):
        if s.shape[i] == SPHERE and s.shape[j] == SPHERE:
            hit, depth, nx, ny, nz, x, y, z, _ = sphere_contact(*s.pos[i], s.axes[i, 0], *s.pos[j], s.axes[j, 0])
            if not hit:
                continue
            normal, point = [nx, ny, nz], [x, y, z]
        else:
            quat_to_matrix(s.quat[i], r1)
            quat_to_matrix(s.quat[j], r2)
            if not ellipsoid_contact(s.pos[i], r1, s.axes[i], s.pos[j], r2, s.axes[j], -1.0, np.zeros(3), out):
                continue
            depth = out[OUT_DEPTH]
            normal = out[OUT_NX:OUT_NX + 3].tolist()
            point = out[OUT_XCX:OUT_XCX + 3].tolist()
        rows.append({"i": int(i), "j": int(j), "depth": float(depth), "point": [float(v) for v in point],
                     "normal": [float(v) for v in normal]})
    return rows
