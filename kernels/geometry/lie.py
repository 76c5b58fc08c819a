"""Rotation and rigid-motion building blocks as generic ``@wp.func`` (no launches here).

Vocabulary (see ``docs/conventions.md``): ``omega`` is an so(3) vector (axis * angle, radians),
``xi = [omega, t]`` an se(3) 6-vector, ``xi = [omega, t, sigma]`` a sim(3) 7-vector with scale
``exp(sigma)``, quaternions are stored ``(w, x, y, z)`` as a plain 4-vector, and a pose is a
3x4 matrix ``[R | t]`` acting as ``p -> R p + t``.

Every function is generic over the float type (``wp.float32`` or ``wp.float64``): constants are
built with ``type(x)(c)`` because Warp does not mix literal and float64 operands.

Numerical care. Closed forms such as ``sin(theta) / theta`` are exact for values but their
derivatives cancel catastrophically near ``theta = 0``, and an expression evaluated on a branch
that is not taken still poisons Warp's adjoint (``0 * inf``). So each function branches on
``theta^2`` *before* taking a square root, and the small-angle branch uses Taylor series in
``theta^2`` only; below ``SMALL_ANGLE_SQ`` the truncation error is under 1e-15 relative.
The threshold is chosen for float64: in float32 the closed forms just above it lose ~1e-5 of
the gradients' relative accuracy (``(1 - A) / theta^2`` and ``D`` cancel), so the kernels of
:mod:`.kernels` evaluate these functions in float64 for float32 arrays too; do the same
(convert with ``wp.vec3d`` / ``wp.mat33d``, round the result) when calling them from float32 code.
"""

from typing import Any

import warp as wp

from ..core.cache import float_overloads
from ..core.compat import func_grad

# theta^2 below which Taylor series replace the closed forms (theta < 1e-2 rad). The first
# omitted term is O(theta^6) ~ 1e-12 / 5040 relative; above it, the closed forms' derivatives
# lose at most eps / theta^2 ~ 1e-12 (float64) of relative precision.
SMALL_ANGLE_SQ = 1.0e-4
# so3_log switches to the symmetric-part (axis) formula when cos(theta) < NEAR_PI_COS
# (theta > ~154 deg), where sin(theta) -> 0 makes theta / sin(theta) ill-conditioned.
NEAR_PI_COS = -0.9
# so3_log takes a matrix as a rotation when |R^T R - I|_F <= ROTATION_TOL and det R > 0 (a
# float32-rounded rotation is ~3e-7 off); any other matrix is first replaced by its nearest rotation.
ROTATION_TOL = 1.0e-5


@wp.func
def hat(w: Any):
    """so(3) vector -> skew-symmetric matrix [w]_x (so that hat(w) @ p = cross(w, p))."""
    return wp.skew(w)


@wp.func
def vee(S: Any):
    """Skew part of a 3x3 matrix -> vector: vee(hat(w)) = w; for any M, vee(M) = axial((M - M^T)/2)."""
    h = type(S[0, 0])(0.5)
    return wp.vector(S[2, 1] - S[1, 2], S[0, 2] - S[2, 0], S[1, 0] - S[0, 1]) * h


@wp.func
def so3_coefficients(t2: Any):
    """Rodrigues coefficients for theta^2 = t2: returns (A, B, C) with
    A = sin(theta)/theta, B = (1 - cos(theta))/theta^2, C = (theta - sin(theta))/theta^3."""
    one = type(t2)(1.0)
    if t2 < type(t2)(SMALL_ANGLE_SQ):
        # Taylor series in theta^2: no square root, exact derivative at 0.
        a = one - t2 / type(t2)(6.0) + t2 * t2 / type(t2)(120.0)
        b = type(t2)(0.5) - t2 / type(t2)(24.0) + t2 * t2 / type(t2)(720.0)
        c = one / type(t2)(6.0) - t2 / type(t2)(120.0) + t2 * t2 / type(t2)(5040.0)
    else:
        theta = wp.sqrt(t2)
        s = wp.sin(theta)
        half_s = wp.sin(theta * type(t2)(0.5))
        a = s / theta
        b = type(t2)(2.0) * half_s * half_s / t2  # 1 - cos without cancellation
        c = (one - a) / t2
    return a, b, c


@wp.func
def so3_exp(w: Any):
    """Exponential map so(3) -> SO(3) (Rodrigues): R = I + A [w]x + B [w]x^2. Exact at w = 0."""
    t2 = wp.dot(w, w)
    a, b, c = so3_coefficients(t2)
    W = wp.skew(w)
    return wp.identity(n=3, dtype=type(t2)) + W * a + (W * W) * b


@wp.func
def so3_left_jacobian(w: Any):
    """V(w) = I + B [w]x + C [w]x^2, the translation factor of the SE(3) exponential."""
    t2 = wp.dot(w, w)
    a, b, c = so3_coefficients(t2)
    W = wp.skew(w)
    return wp.identity(n=3, dtype=type(t2)) + W * b + (W * W) * c


@wp.func
def so3_left_jacobian_inv(w: Any):
    """V(w)^-1 = I - [w]x / 2 + D [w]x^2 with D = (1 - A / (2B)) / theta^2, for |w| <= pi."""
    t2 = wp.dot(w, w)
    one = type(t2)(1.0)
    if t2 < type(t2)(SMALL_ANGLE_SQ):
        d = one / type(t2)(12.0) + t2 / type(t2)(720.0) + t2 * t2 / type(t2)(30240.0)
    else:
        a, b, c = so3_coefficients(t2)
        d = (one - a / (type(t2)(2.0) * b)) / t2
    W = wp.skew(w)
    return wp.identity(n=3, dtype=type(t2)) - W * type(t2)(0.5) + (W * W) * d


@wp.func
def _max_abs(M: Any):
    """The largest |entry| of a 3x3 matrix."""
    r0 = wp.max(wp.max(wp.abs(M[0, 0]), wp.abs(M[0, 1])), wp.abs(M[0, 2]))
    r1 = wp.max(wp.max(wp.abs(M[1, 0]), wp.abs(M[1, 1])), wp.abs(M[1, 2]))
    r2 = wp.max(wp.max(wp.abs(M[2, 0]), wp.abs(M[2, 1])), wp.abs(M[2, 2]))
    return wp.max(wp.max(r0, r1), r2)


def _nearest_rotation(T):
    """nearest_rotation's float type ``T`` overload (Warp custom adjoints need concrete types)."""
    vec3 = wp.types.vector(3, T)
    mat33 = wp.types.matrix((3, 3), T)

    @wp.func
    def nearest_rotation(M: mat33):
        """The rotation nearest to M in the Frobenius norm (special orthogonal Procrustes): U V^T
        from the SVD M = U diag(s) V^T with U, V rotations and s_3 signed (Warp's svd3). Where
        several rotations are equally near (an orthogonal reflection) it is one of them; for M = 0
        the identity. M is scaled by its largest entry first (same rotation), so no finite M
        overflows.

        The adjoint is that of the polar factor: dR = U W V^T with W_ij = (P_ij - P_ji) / (s_i +
        s_j), P = U^T dM V; terms whose s_i + s_j vanishes (no unique nearest rotation) are left
        out, so gradients stay finite.
        """
        m = _max_abs(M)
        U = mat33()
        s = vec3()
        V = mat33()
        wp.svd3(M / wp.where(m > T(0.0), m, T(1.0)), U, s, V)
        return wp.where(m > T(0.0), U * wp.transpose(V), wp.identity(n=3, dtype=T))

    @func_grad(nearest_rotation)
    def adj_nearest_rotation(M: mat33, adj_ret: mat33):
        m = _max_abs(M)
        scale = wp.where(m > T(0.0), m, T(1.0))
        U = mat33()
        s = vec3()
        V = mat33()
        wp.svd3(M / scale, U, s, V)
        H = wp.transpose(U) * adj_ret * V
        tiny = T(1.0e-12) * wp.abs(s[0])
        zero = T(0.0)
        d01 = s[0] + s[1]
        d02 = s[0] + s[2]
        d12 = s[1] + s[2]
        k01 = wp.where(d01 > tiny, (H[0, 1] - H[1, 0]) / wp.where(d01 > tiny, d01, T(1.0)), zero)
        k02 = wp.where(d02 > tiny, (H[0, 2] - H[2, 0]) / wp.where(d02 > tiny, d02, T(1.0)), zero)
        k12 = wp.where(d12 > tiny, (H[1, 2] - H[2, 1]) / wp.where(d12 > tiny, d12, T(1.0)), zero)
        Kskew = wp.matrix_from_rows(vec3(zero, k01, k02), vec3(-k01, zero, k12), vec3(-k02, -k12, zero))
        wp.adjoint[M] += U * Kskew * wp.transpose(V) / scale

    return nearest_rotation


nearest_rotation = float_overloads(_nearest_rotation)


def _is_rotation(T):
    """is_rotation's float type ``T`` overload, with an empty adjoint (a test has no gradient,
    and Warp would otherwise differentiate it too, at a cost, and get 0 * inf = NaN where the
    squares overflow)."""
    mat33 = wp.types.matrix((3, 3), T)

    @wp.func
    def is_rotation(R: mat33):
        """|R^T R - I|_F <= ROTATION_TOL and det R > 0 (False for NaN entries)."""
        c0 = wp.vector(R[0, 0], R[1, 0], R[2, 0])
        c1 = wp.vector(R[0, 1], R[1, 1], R[2, 1])
        c2 = wp.vector(R[0, 2], R[1, 2], R[2, 2])
        d0 = wp.dot(c0, c0) - T(1.0)
        d1 = wp.dot(c1, c1) - T(1.0)
        d2 = wp.dot(c2, c2) - T(1.0)
        o01 = wp.dot(c0, c1)
        o02 = wp.dot(c0, c2)
        o12 = wp.dot(c1, c2)
        e2 = d0 * d0 + d1 * d1 + d2 * d2 + T(2.0) * (o01 * o01 + o02 * o02 + o12 * o12)
        tol = T(ROTATION_TOL)
        return e2 <= tol * tol and wp.dot(c0, wp.cross(c1, c2)) > T(0.0)

    @func_grad(is_rotation)
    def adj_is_rotation(R: mat33, adj_ret: bool):
        pass

    return is_rotation


is_rotation = float_overloads(_is_rotation)


@wp.func
def so3_log(R: Any):
    """Logarithm SO(3) -> so(3), angle in [0, pi]; inverse of so3_exp.

    Written from the antisymmetric part v = sin(theta) axis and c = cos(theta) = (tr R - 1)/2,
    so it is defined (and smooth) for any 3x3 matrix near SO(3) (:func:`is_rotation`), which
    finite differences need. Three regimes: small angle (Taylor of asin(s)/s), generic (atan2),
    near pi (the axis from the symmetric part R + R^T = 2 cos I + 2 (1 - cos) a a^T, signed by v).
    Any other finite matrix (scaled, sheared, a reflection, 0) gives the log of its
    :func:`nearest_rotation`, never NaN.
    """
    if not is_rotation(R):
        R = nearest_rotation(R)
    return _so3_log_near(R)


@wp.func
def _so3_log_near(R: Any):
    """so3_log of a matrix near SO(3)."""
    one = type(R[0, 0])(1.0)
    half = type(R[0, 0])(0.5)
    v = vee(R)
    c = (wp.trace(R) - one) * half
    s2 = wp.dot(v, v)
    if c > type(c)(NEAR_PI_COS):
        if s2 < type(c)(SMALL_ANGLE_SQ) and c > type(c)(0.0):
            # theta = asin(s): asin(s)/s = 1 + s^2/6 + 3 s^4/40 + O(s^6)
            k = one + s2 / type(c)(6.0) + type(c)(3.0) * s2 * s2 / type(c)(40.0)
        else:
            s = wp.sqrt(s2)  # s^2 >= 1e-4 here (or c <= 0, where s^2 >= 1 - 0.81)
            k = wp.atan2(s, c) / s
        w = v * k
    else:
        B = ((R + wp.transpose(R)) * half - wp.identity(n=3, dtype=type(c)) * c) / (one - c)
        # B ~ a a^T: take the column with the largest diagonal (>= 1/3 for a rotation).
        if B[0, 0] >= B[1, 1] and B[0, 0] >= B[2, 2]:
            col = wp.vector(B[0, 0], B[1, 0], B[2, 0])
            dk = B[0, 0]
        elif B[1, 1] >= B[2, 2]:
            col = wp.vector(B[0, 1], B[1, 1], B[2, 1])
            dk = B[1, 1]
        else:
            col = wp.vector(B[0, 2], B[1, 2], B[2, 2])
            dk = B[2, 2]
        axis = col / wp.sqrt(wp.max(dk, type(c)(1.0e-12)))
        sign = wp.where(wp.dot(axis, v) < type(c)(0.0), -one, one)
        axis = axis * sign
        # sin(theta) = a . v keeps theta differentiable even at exactly pi (where v = 0).
        w = axis * wp.atan2(wp.dot(axis, v), c)
    return w


@wp.func
def quat_wxyz_to_matrix(q: Any):
    """Quaternion (w, x, y, z), any non-zero norm, -> rotation matrix of q / |q|.

    Uses s = 2 / |q|^2 instead of normalising first (same matrix, one division). A zero
    quaternion (|q|^2 < 1e-30) gives the identity with zero gradient.
    """
    n2 = wp.dot(q, q)
    one = type(n2)(1.0)
    s = wp.where(n2 > type(n2)(1.0e-30), type(n2)(2.0) / wp.max(n2, type(n2)(1.0e-30)), type(n2)(0.0))
    w = q[0]
    x = q[1]
    y = q[2]
    z = q[3]
    return wp.matrix_from_rows(
        wp.vector(one - s * (y * y + z * z), s * (x * y - w * z), s * (x * z + w * y)),
        wp.vector(s * (x * y + w * z), one - s * (x * x + z * z), s * (y * z - w * x)),
        wp.vector(s * (x * z - w * y), s * (y * z + w * x), one - s * (x * x + y * y)),
    )


@wp.func
def axis_rotation(axis: int, angle: Any):
    """Right-handed rotation by ``angle`` about axis 0 (X), 1 (Y) or 2 (Z)."""
    c = wp.cos(angle)
    s = wp.sin(angle)
    one = type(angle)(1.0)
    zero = type(angle)(0.0)
    if axis == 0:
        m = wp.matrix_from_rows(wp.vector(one, zero, zero), wp.vector(zero, c, -s), wp.vector(zero, s, c))
    elif axis == 1:
        m = wp.matrix_from_rows(wp.vector(c, zero, s), wp.vector(zero, one, zero), wp.vector(-s, zero, c))
    else:
        m = wp.matrix_from_rows(wp.vector(c, -s, zero), wp.vector(s, c, zero), wp.vector(zero, zero, one))
    return m


@wp.func
def euler_to_matrix(angles: Any, a0: int, a1: int, a2: int):
    """R = R_a0(angles[0]) R_a1(angles[1]) R_a2(angles[2]) (intrinsic order a0, a1, a2)."""
    return axis_rotation(a0, angles[0]) * axis_rotation(a1, angles[1]) * axis_rotation(a2, angles[2])


@wp.func
def pose_from_rt(R: Any, t: Any):
    """[R | t] as a 3x4 matrix."""
    return wp.matrix_from_rows(
        wp.vector(R[0, 0], R[0, 1], R[0, 2], t[0]),
        wp.vector(R[1, 0], R[1, 1], R[1, 2], t[1]),
        wp.vector(R[2, 0], R[2, 1], R[2, 2], t[2]),
    )


@wp.func
def pose_rotation(T: Any):
    """The left 3x3 block of a 3x4 pose."""
    return wp.matrix_from_rows(
        wp.vector(T[0, 0], T[0, 1], T[0, 2]),
        wp.vector(T[1, 0], T[1, 1], T[1, 2]),
        wp.vector(T[2, 0], T[2, 1], T[2, 2]),
    )


@wp.func
def pose_translation(T: Any):
    """The last column of a 3x4 pose."""
    return wp.vector(T[0, 3], T[1, 3], T[2, 3])


@wp.func
def transform_point(T: Any, p: Any):
    """T p = R p + t for a 3x4 pose T."""
    return pose_rotation(T) * p + pose_translation(T)


@wp.func
def se3_to_pose(omega: Any, t: Any):
    """gvnn's SE3 layer: [so3_exp(omega) | t] (t is used as is, not V t)."""
    return pose_from_rt(so3_exp(omega), t)


@wp.func
def sim3_to_pose(omega: Any, t: Any, sigma: Any):
    """gvnn's Sim3 layer: [exp(sigma) so3_exp(omega) | t]."""
    return pose_from_rt(so3_exp(omega) * wp.exp(sigma), t)


@wp.func
def se3_exp(omega: Any, u: Any):
    """Lie-group exponential of xi = [omega, u]: [so3_exp(omega) | V(omega) u]."""
    return pose_from_rt(so3_exp(omega), so3_left_jacobian(omega) * u)


@wp.func
def se3_log_omega(T: Any):
    """Rotation part of the SE(3) logarithm."""
    return so3_log(pose_rotation(T))


@wp.func
def se3_log_u(T: Any, omega: Any):
    """Translation part of the SE(3) logarithm, u = V(omega)^-1 t, given omega = so3_log(R)."""
    return so3_left_jacobian_inv(omega) * pose_translation(T)
