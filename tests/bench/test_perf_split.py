"""`bench perf --what split`: the measurement behind the thread schemes' cost model (the shapes' costs)."""
from tests.helpers import bench


def test_split_study_counts_and_orders_the_costs():
    """On the mixed crystal (scene header): at skin 0.1 the spheres' rows hold the 3910 touching
    sphere pairs of a 40 x 50 lattice (39 x 50 + 40 x 49) and the ellipsoids' rows as many ellipsoid
    pairs, each with bounding spheres overlapping; a wider skin only adds pairs whose bounding
    spheres are apart. An ellipsoid pair needs the iterative solve, so the ellipsoids' rows take
    longer than the spheres' (5.6x measured), and an ellipsoid's per-particle pass with its floor
    contact longer than a sphere's (4x). The report carries the registered shapes' costs (the
    ones modes.parallel cuts by) beside the measured weights."""
    from bench.studies.perf_split import measure
    from modes import parallel
    rep = measure(1, lambda msg: None, calls=3)
    sph, ell = rep["pairs"]["sphere"]["rows"], rep["pairs"]["ellipsoid"]["rows"]
    assert [r["near"] for r in sph] == [3910, 3910] and [r["near"] for r in ell] == [3910, 3910]
    assert sph[1]["apart"] > sph[0]["apart"] and ell[1]["apart"] > ell[0]["apart"]
    assert ell[0]["seconds"] > sph[0]["seconds"]
    assert rep["finish"]["ellipsoid_us"] + rep["finish"]["ellipsoid_wall_us"] > \
        rep["finish"]["sphere_us"] + rep["finish"]["sphere_wall_us"]
    assert rep["constants"]["ellipsoid.contact_cost"] == parallel.CONTACT_COST[1] == 40.0
    assert rep["constants"]["sphere.wall_cost"] == parallel.WALL_COST[0] == 0.15
    assert set(rep["measured_weights"]) == set(rep["constants"])


def test_split_study_bad_repeats():
    """A bad --repeats: one line naming the option, exit 2."""
    res = bench("perf", "--what", "split", "--repeats", "0")
    assert res.returncode == 2 and res.stderr.strip().splitlines() == [res.stderr.strip()]
    assert "--repeats" in res.stderr
