!> Interpolation (remeshing) kernels of thesis sec. 3.2.3, as pure elemental functions of
!> s = |x|/h (1D) and their tensor products (2D, 3D). On a regular lattice of spacing h, an
!> old particle at x handing W(x_j - x) to each node x_j conserves these moments:
!>  - Lambda2 (eq. 3.15, second branch on 1/2 <= s < 3/2 as in the errata): moments 0, 1, 2
!>    (quadratic Lagrange interpolation through the three nearest nodes);
!>  - M4' (eq. 3.19, as printed): moments 0, 1, 2 (reproduces quadratics), C1 and interpolating;
!>  - the wall-biased weights (eq. 3.20 as corrected in the errata): moments 0, 1, 2 on the three
!>    nodes next to the wall, so they reproduce quadratics using fluid-side nodes only;
!>  - the cubic B-spline M4 (not in the thesis): moments 0, 1 only, but positive everywhere; the
!>    transfer onto disordered particles (sph_remesh_interp) builds on it, see there why.
!> None of them conserves the third moment.
module sph_interpolation_kernels
    use sph_kinds, only: wp
    implicit none
    private
    public :: INTERP_LAMBDA2, INTERP_M4PRIME, INTERP_M4
    public :: lambda2, m4prime, m4_bspline, wall_lambda2, interp_1d, interp_weight
    public :: interp_support, wall_stencil

    integer, parameter :: INTERP_LAMBDA2 = 1
    integer, parameter :: INTERP_M4PRIME = 2
    integer, parameter :: INTERP_M4 = 3

contains

    !> Lambda2, eq. 3.15: 1 - s^2 (s < 1/2), (1 - s)(2 - s)/2 (1/2 <= s < 3/2), 0 beyond.
    pure elemental real(wp) function lambda2(s) result(w)
        real(wp), intent(in) :: s
        real(wp) :: a
        a = abs(s)
        if (a < 0.5_wp) then
            w = 1.0_wp - a * a
        else if (a < 1.5_wp) then
            w = 0.5_wp * (1.0_wp - a) * (2.0_wp - a)
        else
            w = 0.0_wp
        end if
    end function lambda2

    !> Lambda2 of a signed offset u (node minus target, or target minus node: one sign for
    !> all the nodes of a target), its branches half-open on one side: 1 - u^2 on
    !> [-1/2, 1/2), (1 - |u|)(2 - |u|)/2 on [-3/2, -1/2) and [1/2, 3/2). Lambda2 jumps at
    !> |u| = 1/2 and 3/2, so a target midway between two nodes (a refinement's midpoints on
    !> a lattice) met both nodes at |u| = 1/2 on the second branch: weights summing to 0.75
    !> (fz50). Half-open, it takes the three nodes of one side, the quadratic through them.
    !> A target a rounding off the middle still meets whatever the roundings of its nodes'
    !> offsets say (unused by the remeshing, which takes M4).
    pure elemental real(wp) function lambda2_signed(u) result(w)
        real(wp), intent(in) :: u
        if (u >= -0.5_wp .and. u < 0.5_wp) then
            w = 1.0_wp - u * u
        else if (u >= -1.5_wp .and. u < 1.5_wp) then
            w = 0.5_wp * (1.0_wp - abs(u)) * (2.0_wp - abs(u))
        else
            w = 0.0_wp
        end if
    end function lambda2_signed

    !> M4', eq. 3.19: 1 - 5s^2/2 + 3s^3/2 (s < 1), (1 - s)(2 - s)^2/2 (1 <= s < 2), 0 beyond.
    pure elemental real(wp) function m4prime(s) result(w)
        real(wp), intent(in) :: s
        real(wp) :: a
        a = abs(s)
        if (a < 1.0_wp) then
            w = 1.0_wp - 2.5_wp * a * a + 1.5_wp * a * a * a
        else if (a < 2.0_wp) then
            w = 0.5_wp * (1.0_wp - a) * (2.0_wp - a)**2
        else
            w = 0.0_wp
        end if
    end function m4prime

    !> Cubic B-spline M4 normalised for a lattice of spacing h: 2/3 - s^2 + s^3/2 (s < 1),
    !> (2 - s)^3/6 (1 <= s < 2), 0 beyond. Positive; moments 0 and 1 only.
    pure elemental real(wp) function m4_bspline(s) result(w)
        real(wp), intent(in) :: s
        real(wp) :: a
        a = abs(s)
        if (a < 1.0_wp) then
            w = 2.0_wp / 3.0_wp - a * a + 0.5_wp * a * a * a
        else if (a < 2.0_wp) then
            w = (2.0_wp - a)**3 / 6.0_wp
        else
            w = 0.0_wp
        end if
    end function m4_bspline

    !> One-sided wall-biased weights, eq. 3.20 corrected: the quadratic Lagrange weights of the
    !> three nodes next to the wall, cell = 1 (first node from the wall), 2, 3, for a target at
    !> s = (distance from the first node towards the fluid) / h; s may be negative (target
    !> between the wall and the first node). 1 - 3s/2 + s^2/2, s(2 - s), s(s - 1)/2.
    pure elemental real(wp) function wall_lambda2(cell, s) result(w)
        integer, intent(in) :: cell
        real(wp), intent(in) :: s
        select case (cell)
        case (1)
            w = 1.0_wp - 1.5_wp * s + 0.5_wp * s * s
        case (2)
            w = s * (2.0_wp - s)
        case (3)
            w = 0.5_wp * s * (s - 1.0_wp)
        case default
            w = 0.0_wp
        end select
    end function wall_lambda2

    !> Support of a kernel in units of h (W = 0 for s >= support).
    pure elemental real(wp) function interp_support(kernel) result(r)
        integer, intent(in) :: kernel
        select case (kernel)
        case (INTERP_LAMBDA2)
            r = 1.5_wp
        case default
            r = 2.0_wp
        end select
    end function interp_support

    !> 1D kernel chosen at run time, of a signed offset s (Lambda2's ties: lambda2_signed).
    pure elemental real(wp) function interp_1d(kernel, s) result(w)
        integer, intent(in) :: kernel
        real(wp), intent(in) :: s
        select case (kernel)
        case (INTERP_LAMBDA2)
            w = lambda2_signed(s)
        case (INTERP_M4PRIME)
            w = m4prime(s)
        case (INTERP_M4)
            w = m4_bspline(s)
        case default
            w = 0.0_wp
        end select
    end function interp_1d

    !> Tensor product W(d, h) = prod_{a <= dim} W1(d_a / h), the 2D/3D form of eq. 3.17.
    pure real(wp) function interp_weight(kernel, dim, d, h) result(w)
        integer, intent(in) :: kernel, dim
        real(wp), intent(in) :: d(:), h
        integer :: a
        w = 1.0_wp
        do a = 1, dim
            w = w * interp_1d(kernel, d(a) / h)
        end do
    end function interp_weight

    !> The 1D stencil of a target at position t (in units of h, measured from the first fluid
    !> node towards the fluid; nodes at t = 0, 1, 2, ...; the wall lies behind node 0). Returns
    !> the node numbers and weights: the interior kernel where its support holds only nodes
    !> >= 0, the wall-biased weights of nodes 0, 1, 2 otherwise. No node behind the wall is used.
    pure subroutine wall_stencil(kernel, t, node, w, n)
        integer, intent(in) :: kernel
        real(wp), intent(in) :: t
        integer, intent(out) :: node(4)
        real(wp), intent(out) :: w(4)
        integer, intent(out) :: n
        integer :: first, last, k
        real(wp) :: r
        r = interp_support(kernel)
        first = ceiling(t - r)
        last = floor(t + r)
        node = 0
        w = 0.0_wp
        n = 0
        if (t < 0.0_wp .or. (first < 0 .and. abs(interp_1d(kernel, t - first)) > 0.0_wp)) then
            n = 3
            node(1:3) = [0, 1, 2]
            w(1:3) = wall_lambda2([1, 2, 3], t)
            return
        end if
        do k = max(first, 0), last
            if (n == 4) exit
            n = n + 1
            node(n) = k
            w(n) = interp_1d(kernel, t - k)
        end do
    end subroutine wall_stencil
end module sph_interpolation_kernels
