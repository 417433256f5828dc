"""Time integration: leapfrog (central difference) translation, symplectic splitting rotation.

Translation (central difference, velocities at half steps):
    v_{n+1/2} = v_{n-1/2} + dt (F_n/m + g),   x_{n+1} = x_n + dt v_{n+1/2}.
Rotation: the world-frame angular momentum takes the torque kick L += dt T, then the orientation
turns as its shape says (dem.shapes: turn; dem.rotation: the free-rotor splitting of an
ellipsoid, the exact exp map of a sphere), through the registry's dispatch (dem.shapes.dispatch),
as do the derived rotation matrix and angular velocity (derive) and a poly-ellipsoid scene's
octant geometry (octant_geometry).
"""
import numpy as np
from numba import njit

from dem.shapes import sphere
from dem.shapes.dispatch import by_shape

turn = by_shape("turn", "p, quat, angmom, inertia, shape, dt", "shape[p]",
                "Orientation (w, x, y, z) of particle p after dt [s] under its angular momentum, as its shape turns.")
derive = by_shape("derive", "p, quat, angmom, inertia, shape, rot, omega, sphere_rot", "shape[p]",
                  "rot[p] [3,3] and omega[p] [3] [rad/s] of particle p, as its shape derives them.")
octant_geometry = by_shape("octant_geometry", "p, pos, rot, axes, shape, poly, orot, oorg, ax6", "shape[p]",
                           "Octant frame, origin and six semi-axes of particle p as a poly-ellipsoid.")


@njit(cache=True, inline="always")
def integrate_particle(p, bodies, gravity, dt, spheres):
    """One leapfrog step of particle p of the bodies group (dem.forces; see module docstring), under
    gravity = (gx, gy, gz [m/s^2], has_gravity); spheres: a literal True where every particle is a
    sphere (the ellipsoid rotation is then compiled out)."""
    pos, vel, quat, angmom, mass, inertia, shape, _, _, _, force, torque, _, _ = bodies
    gx, gy, gz, has_gravity = gravity
    im = 1.0 / mass[p]
    if has_gravity:
        vel[p, 0] += dt * (force[p, 0] * im + gx)
        vel[p, 1] += dt * (force[p, 1] * im + gy)
        vel[p, 2] += dt * (force[p, 2] * im + gz)
    else:
        vel[p, 0] += dt * (force[p, 0] * im)
        vel[p, 1] += dt * (force[p, 1] * im)
        vel[p, 2] += dt * (force[p, 2] * im)
    pos[p, 0] += dt * vel[p, 0]
    pos[p, 1] += dt * vel[p, 1]
    pos[p, 2] += dt * vel[p, 2]
    angmom[p, 0] += dt * torque[p, 0]
    angmom[p, 1] += dt * torque[p, 1]
    angmom[p, 2] += dt * torque[p, 2]
    # the sphere's kernel by name where the scene is spheres only (no dispatch to compile in)
    if spheres:
        w, x, y, z = sphere.turn(p, quat, angmom, inertia, shape, dt)
    else:
        w, x, y, z = turn(p, quat, angmom, inertia, shape, dt)
    quat[p, 0] = w
    quat[p, 1] = x
    quat[p, 2] = y
    quat[p, 3] = z


@njit(cache=True, inline="always")
def derive_particle(p, quat, angmom, inertia, shape, rot, omega, sphere_rot, spheres):
    """Rotation matrix rot[p] [3,3] and world angular velocity omega[p] [3] [rad/s], as its shape
    derives them (derive; a sphere's rot is the identity, written only when sphere_rot:
    dem.shapes.sphere derive); spheres as in integrate_particle."""
    if spheres:
        sphere.derive(p, quat, angmom, inertia, shape, rot, omega, sphere_rot)
    else:
        derive(p, quat, angmom, inertia, shape, rot, omega, sphere_rot)


@njit(cache=True)
def derive_range(lo, hi, quat, angmom, inertia, shape, rot, omega):
    for p in range(lo, hi):
        derive_particle(p, quat, angmom, inertia, shape, rot, omega, True, False)


@njit(cache=True)
def angular_velocity(quat, angmom, inertia, shape, out):
    """World-frame angular velocity out [n, 3] of all particles."""
    rot = np.empty((quat.shape[0], 3, 3))
    derive_range(0, quat.shape[0], quat, angmom, inertia, shape, rot, out)


@njit(cache=True, inline="always")
def derive_poly_geometry(p, pos, rot, axes, shape, poly, orot, oorg, ax6):
    """Contact geometry of particle p in a scene with poly-ellipsoids: every particle as a
    poly-ellipsoid (Peters et al. 2009): octant frame orot[p] [3,3], octant origin oorg[p] [3] [m],
    six semi-axes ax6[p] [6] [m], as its shape gives them (octant_geometry: a poly-ellipsoid's from
    its record, R_oct = R W, o = x + R off; an ellipsoid is its own octant frame with a+ = a-, ...;
    a sphere has the identity frame and six equal radii). rot[p] must be derived first
    (derive_particle)."""
    octant_geometry(p, pos, rot, axes, shape, poly, orot, oorg, ax6)


@njit(cache=True)
def derive_geometry_range(lo, hi, pos, rot, axes, shape, poly, orot, oorg, ax6):
    """derive_poly_geometry of particles lo..hi-1."""
    for p in range(lo, hi):
        derive_poly_geometry(p, pos, rot, axes, shape, poly, orot, oorg, ax6)


@njit(cache=True, _nrt=False)
def derive_all(lo, hi, bodies, polys, poly_scene):
    """Derived quantities of particles lo..hi-1 of the bodies group (dem.forces): rot, omega
    (derive_particle) and, when poly_scene, the octant geometry of polys (derive_poly_geometry)."""
    pos, _, quat, angmom, _, inertia, shape, axes, _, _, _, _, rot, omega = bodies
    poly, oorg, orot, ax6 = polys
    for p in range(lo, hi):
        derive_particle(p, quat, angmom, inertia, shape, rot, omega, True, False)
        if poly_scene:
            derive_poly_geometry(p, pos, rot, axes, shape, poly, orot, oorg, ax6)
