"""The thin kernels of the geometry ops: one element = ``wp.tid() + offset``, load, one call, store.

- so3, SE3 and Sim3 maps over :mod:`.lie`: evaluated in float64 for every array type (loads are
  converted to float64, results rounded to the output's type on store): a float32 op's values and
  gradients are then the float64 ones rounded to float32, for every angle (float32 arithmetic alone
  loses up to ~1e-5 of the gradients' relative accuracy near 0 and pi: sums of large terms that
  cancel). Converting costs little next to the loads and stores.
- the 3D grid generator, the rigid transform and the projection over :mod:`.camera` (pinhole), each
  with its twin through a lens model (:mod:`.lens`) where it has one: ``<name>_lens()``, made on
  first use through the cache (its kernel names the lens models, themselves made on first use),
  which takes the camera as ``K`` (mat33 per batch item), ``dist`` (vec8 per batch
  item, the layout of :mod:`.lens`) and ``model`` (an int, the same for the whole launch).

Arrays are 1-D (one element per batch item, point or pixel); see :mod:`.launch` for the ``offset``
convention and the float32/float64 overloads (:class:`~.core.kinds.FloatKernel`).
"""

from typing import Any

import warp as wp

from ..core.cache import specialise
from ..core.kinds import FloatKernel
from . import camera, lens, lie

# ----------------------------------------------------------------------------- so3, SE3, Sim3

mat34d = wp.types.matrix(shape=(3, 4), dtype=wp.float64)


@wp.func
def _vec3_as(v: Any, x: Any):
    """v as a 3-vector of the float type of the scalar x."""
    return wp.vector(v, length=3, dtype=type(x))


@wp.func
def _mat33_as(M: Any, x: Any):
    """M (3x3) as a matrix of the float type of the scalar x."""
    return wp.matrix(M, shape=(3, 3), dtype=type(x))


@wp.func
def _mat34_as(M: Any, x: Any):
    """M (3x4) as a matrix of the float type of the scalar x."""
    return wp.matrix(M, shape=(3, 4), dtype=type(x))


@wp.kernel
def _so3_exp(offset: int, omega: wp.array(dtype=Any), R: wp.array(dtype=Any)):
    i = wp.tid() + offset
    w = omega[i]
    R[i] = _mat33_as(lie.so3_exp(wp.vec3d(w)), w[0])


@wp.kernel
def _so3_log(offset: int, R: wp.array(dtype=Any), omega: wp.array(dtype=Any)):
    i = wp.tid() + offset
    Ri = R[i]
    omega[i] = _vec3_as(lie.so3_log(wp.mat33d(Ri)), Ri[0, 0])


@wp.kernel
def _quaternion_to_matrix(offset: int, q: wp.array(dtype=Any), R: wp.array(dtype=Any)):
    i = wp.tid() + offset
    qi = q[i]
    R[i] = _mat33_as(lie.quat_wxyz_to_matrix(wp.vec4d(qi)), qi[0])


@wp.kernel
def _euler_to_matrix(
    offset: int, angles: wp.array(dtype=Any), a0: int, a1: int, a2: int, R: wp.array(dtype=Any)
):
    i = wp.tid() + offset
    a = angles[i]
    R[i] = _mat33_as(lie.euler_to_matrix(wp.vec3d(a), a0, a1, a2), a[0])


@wp.kernel
def _se3_to_matrix(offset: int, omega: wp.array(dtype=Any), t: wp.array(dtype=Any), T: wp.array(dtype=Any)):
    i = wp.tid() + offset
    w = omega[i]
    T[i] = _mat34_as(lie.se3_to_pose(wp.vec3d(w), wp.vec3d(t[i])), w[0])


@wp.kernel
def _sim3_to_matrix(
    offset: int,
    omega: wp.array(dtype=Any),
    t: wp.array(dtype=Any),
    sigma: wp.array(dtype=Any),
    T: wp.array(dtype=Any),
):
    i = wp.tid() + offset
    w = omega[i]
    T[i] = _mat34_as(lie.sim3_to_pose(wp.vec3d(w), wp.vec3d(t[i]), wp.float64(sigma[i])), w[0])


@wp.kernel
def _se3_exp(offset: int, omega: wp.array(dtype=Any), u: wp.array(dtype=Any), T: wp.array(dtype=Any)):
    i = wp.tid() + offset
    w = omega[i]
    T[i] = _mat34_as(lie.se3_exp(wp.vec3d(w), wp.vec3d(u[i])), w[0])


@wp.kernel
def _se3_log(offset: int, T: wp.array(dtype=Any), omega: wp.array(dtype=Any), u: wp.array(dtype=Any)):
    i = wp.tid() + offset
    Tf = T[i]
    Ti = mat34d(Tf)
    w = lie.se3_log_omega(Ti)
    omega[i] = _vec3_as(w, Tf[0, 0])
    u[i] = _vec3_as(lie.se3_log_u(Ti, w), Tf[0, 0])


# Every element reads and writes only its own batch item: any split is exact.
so3_exp = FloatKernel(_so3_exp, omega="vec3", R="mat33").set_parallel(scopes={"omega": "element"})
so3_log = FloatKernel(_so3_log, R="mat33", omega="vec3").set_parallel(scopes={"R": "element"})
quaternion_to_matrix = FloatKernel(_quaternion_to_matrix, q="vec4", R="mat33").set_parallel(scopes={"q": "element"})
euler_to_matrix = FloatKernel(_euler_to_matrix, angles="vec3", R="mat33").set_parallel(scopes={"angles": "element"})
se3_to_matrix = FloatKernel(_se3_to_matrix, omega="vec3", t="vec3", T="mat34").set_parallel(
    scopes={"omega": "element", "t": "element"}
)
sim3_to_matrix = FloatKernel(_sim3_to_matrix, omega="vec3", t="vec3", sigma="scalar", T="mat34").set_parallel(
    scopes={"omega": "element", "t": "element", "sigma": "element"}
)
se3_exp = FloatKernel(_se3_exp, omega="vec3", u="vec3", T="mat34").set_parallel(
    scopes={"omega": "element", "u": "element"}
)
se3_log = FloatKernel(_se3_log, T="mat34", omega="vec3", u="vec3").set_parallel(scopes={"T": "element"})


# ----------------------------------------------------------------------------- points and pixels
# Adjoint scopes (see :meth:`.launch.FloatKernel.set_parallel`): per-point inputs are written back
# only at the element's own point; a batch item's K or T gathers the gradients of all its points
# ("any": cut into fixed pieces with partial buffers. They are also "segment" with segments of P
# or H*W points; declaring so would split batches more freely, but would change the rounding of
# large launches with several batch items, which this refactor keeps bitwise as it was).
# The lens twins' K and dist gather the gradients of all a batch item's points too ("any").


@wp.kernel
def _depth_to_points(
    offset: int,
    depth: wp.array(dtype=Any),
    K: wp.array(dtype=Any),
    H: int,
    W: int,
    points: wp.array(dtype=Any),
):
    i = wp.tid() + offset  # flat (b, y, x)
    b = i // (H * W)
    r = i - b * (H * W)
    y = r // W
    x = r - y * W
    d = depth[i]
    points[i] = camera.unproject(K[b], type(d)(x), type(d)(y), d)


depth_to_points = FloatKernel(_depth_to_points, depth="scalar", K="mat33", points="vec3").set_parallel(
    scopes={"depth": "element", "K": "any"}
)


@specialise("geometry.depth_to_points_lens")
def depth_to_points_lens() -> FloatKernel:
    """The 3D grid generator through a lens model (+ ``dist``, ``model``; also ``valid``: the
    pixel's undistortion converged in the model's domain), made on first use."""

    @wp.kernel(module="unique")
    def _depth_to_points(
        offset: int,
        depth: wp.array(dtype=Any),
        K: wp.array(dtype=Any),
        dist: wp.array(dtype=Any),
        H: int,
        W: int,
        model: int,
        points: wp.array(dtype=Any),
        valid: wp.array(dtype=bool),
    ):
        i = wp.tid() + offset  # flat (b, y, x)
        b = i // (H * W)
        r = i - b * (H * W)
        y = r // W
        x = r - y * W
        d = depth[i]
        p, ok = lens.unproject(model, K[b], dist[b], type(d)(x), type(d)(y), d)
        points[i] = p
        valid[i] = ok

    return FloatKernel(
        _depth_to_points, depth="scalar", K="mat33", dist="vec8", points="vec3", valid="bool"
    ).set_parallel(scopes={"depth": "element", "K": "any", "dist": "any"})


@wp.kernel
def _transform_points(
    offset: int, T: wp.array(dtype=Any), points: wp.array(dtype=Any), P: int, out: wp.array(dtype=Any)
):
    i = wp.tid() + offset  # flat (b, point)
    out[i] = lie.transform_point(T[i // P], points[i])


transform_points = FloatKernel(_transform_points, T="mat34", points="vec3", out="vec3").set_parallel(
    scopes={"T": "any", "points": "element"}
)


@wp.kernel
def _project_points(
    offset: int,
    points: wp.array(dtype=Any),
    K: wp.array(dtype=Any),
    P: int,
    min_depth: float,
    pixels: wp.array(dtype=Any),
):
    i = wp.tid() + offset  # flat (b, point)
    p = points[i]
    pixels[i] = camera.project_point(K[i // P], p, type(p[0])(min_depth))


project_points = FloatKernel(_project_points, points="vec3", K="mat33", pixels="vec2").set_parallel(
    scopes={"points": "element", "K": "any"}
)


@specialise("geometry.project_points_lens")
def project_points_lens() -> FloatKernel:
    """The projection through a lens model (+ ``dist``, ``model``; also ``valid``: in front and
    in the model's domain), made on first use."""

    @wp.kernel(module="unique")
    def _project_points(
        offset: int,
        points: wp.array(dtype=Any),
        K: wp.array(dtype=Any),
        dist: wp.array(dtype=Any),
        P: int,
        min_depth: float,
        model: int,
        pixels: wp.array(dtype=Any),
        valid: wp.array(dtype=bool),
    ):
        i = wp.tid() + offset  # flat (b, point)
        b = i // P
        p = points[i]
        uv, ok = lens.project(model, K[b], dist[b], p, type(p[0])(min_depth))
        pixels[i] = uv
        valid[i] = ok

    return FloatKernel(
        _project_points, points="vec3", K="mat33", dist="vec8", pixels="vec2", valid="bool"
    ).set_parallel(scopes={"points": "element", "K": "any", "dist": "any"})


@specialise("geometry.unproject_points_lens")
def unproject_points_lens() -> FloatKernel:
    """The points at the given depths seen at the given pixels through a lens model, made on
    first use."""

    @wp.kernel(module="unique")
    def _unproject_points(
        offset: int,
        pixels: wp.array(dtype=Any),
        depth: wp.array(dtype=Any),
        K: wp.array(dtype=Any),
        dist: wp.array(dtype=Any),
        P: int,
        model: int,
        points: wp.array(dtype=Any),
        valid: wp.array(dtype=bool),
    ):
        i = wp.tid() + offset  # flat (b, point)
        b = i // P
        uv = pixels[i]
        p, ok = lens.unproject(model, K[b], dist[b], uv[0], uv[1], depth[i])
        points[i] = p
        valid[i] = ok

    return FloatKernel(
        _unproject_points, pixels="vec2", depth="scalar", K="mat33", dist="vec8", points="vec3", valid="bool"
    ).set_parallel(scopes={"pixels": "element", "depth": "element", "K": "any", "dist": "any"})


@specialise("geometry.distort_pixels_lens")
def distort_pixels_lens() -> FloatKernel:
    """Ideal pixel -> the distorted image's pixel (``lens.distort_pixel``), made on first use."""

    @wp.kernel(module="unique")
    def _distort_pixels(
        offset: int,
        pixels: wp.array(dtype=Any),
        K: wp.array(dtype=Any),
        dist: wp.array(dtype=Any),
        P: int,
        model: int,
        out: wp.array(dtype=Any),
        valid: wp.array(dtype=bool),
    ):
        i = wp.tid() + offset  # flat (b, point): ideal pixel -> distorted-image pixel
        b = i // P
        uv, ok = lens.distort_pixel(model, K[b], dist[b], pixels[i])
        out[i] = uv
        valid[i] = ok

    return FloatKernel(
        _distort_pixels, pixels="vec2", K="mat33", dist="vec8", out="vec2", valid="bool"
    ).set_parallel(scopes={"pixels": "element", "K": "any", "dist": "any"})


@specialise("geometry.undistort_pixels_lens")
def undistort_pixels_lens() -> FloatKernel:
    """Distorted-image pixel -> the ideal pixel (``lens.undistort_pixel``), made on first use."""

    @wp.kernel(module="unique")
    def _undistort_pixels(
        offset: int,
        pixels: wp.array(dtype=Any),
        K: wp.array(dtype=Any),
        dist: wp.array(dtype=Any),
        P: int,
        model: int,
        out: wp.array(dtype=Any),
        valid: wp.array(dtype=bool),
    ):
        i = wp.tid() + offset  # flat (b, point): distorted-image pixel -> ideal pixel
        b = i // P
        uv, ok = lens.undistort_pixel(model, K[b], dist[b], pixels[i])
        out[i] = uv
        valid[i] = ok

    return FloatKernel(
        _undistort_pixels, pixels="vec2", K="mat33", dist="vec8", out="vec2", valid="bool"
    ).set_parallel(scopes={"pixels": "element", "K": "any", "dist": "any"})
