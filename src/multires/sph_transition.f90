!> Virtual particles of a transition zone (thesis sec. 3.3, Figure 1-4): where two
!> resolution levels meet, each level's real particles near the interface need neighbours of
!> their own level on the other side. Those are virtual particles, made every step from the
!> other level's particles by the remeshing rules, so they keep the flow's disorder:
!>  - fine virtuals from coarse particles: sph_refine's construction (old sites, edge
!>    midpoints, face and cube centres: 2^dim per coarse particle), translated by half a fine
!>    spacing along every axis. The construction alone yields the lattice {k dx_f} from a
!>    coarse lattice at (i + 1/2) dx, while the fine real particles sit at (k + 1/2) dx_f (both
!>    lattices start half a spacing from the box, as sph_initial makes them): untranslated,
!>    the virtual and real fine rows would be half a spacing out of step at the interface (a
!>    gap of 1.5 dx_f on one side, a clump on the other). The translation moves the whole set
!>    rigidly, so every relative position (the disorder) is kept.
!>  - coarse virtuals from fine particles: sph_coarsen's selection (the lattice-parity
!>    sublattice, one in 2^dim), translated by half a fine spacing along every axis: the parity
!>    rule keeps the fine sites at (2 j + 1/2) dx_f, a quarter coarse spacing from the coarse
!>    lattice (j + 1/2) dx.
!> The driver hands in the source level's particles around the zone (real ones and the
!> previous step's virtual ones, so the construction is complete across the interface) and
!> keeps the new positions that lie in the zone.
!> Fields: gathered from the source level's particles with the moment properties of M4'
!> (thesis eq. 3.19): on a lattice, M4' interpolation reproduces every polynomial up to
!> degree two (its second moment vanishes). On the disordered sources of a transition zone
!> its weights lose that property, and they cannot serve as least-squares weights (the
!> vanishing second moment makes the moment matrix singular). So the weights are built on
!> the actual arrangement to have it: quadratic moving least squares with the positive M4
!> B-spline (tensor product, h = the source spacing) as weight, phi_k = W_k q(d_k)^T M^-1
!> q(0), q = (1, d, d d^T). A quadratic field (Poiseuille's profile) is reproduced to
!> round-off on any arrangement with enough sources. Where the moment matrix is not safely
!> invertible (one-sided or sparse sources) the linear form is used, and where that fails
!> too, the Shepard (normalised) mean; fallbacks are counted.
!> Virtual particles have negative ids: -(1 + hash of what made them, 62 bits), so they never
!> collide with a real particle's id; a virtual that turns real gets a fresh global id.
!> Serial, no MPI.
module sph_transition
    use sph_kinds, only: wp, i8
    use sph_refine, only: refine_positions
    use sph_coarsen, only: coarsen_select, id_hash
    use sph_cell_list, only: neighbour_list_t, build_neighbour_list
    use sph_interpolation_kernels, only: INTERP_M4, interp_weight, interp_support
    implicit none
    private
    public :: fine_virtual_positions, coarse_virtual_positions, interpolate_fields
    public :: virtual_id, image_source_id

contains

    !> Id of a virtual particle of `level` made from the key (k1, k2): negative, 62 bits of
    !> hash, the same on any rank count (keys derive from the source particles' ids).
    pure integer(i8) function virtual_id(level, k1, k2)
        integer, intent(in) :: level
        integer(i8), intent(in) :: k1, k2
        integer(i8) :: z
        z = id_hash(ieor(id_hash(k1), id_hash(k2 + int(level, i8))))
        virtual_id = -(1_i8 + iand(z, huge(1_i8) / 2_i8))
    end function virtual_id

    !> Source id for the remeshing rules, which need distinct ids below 2^61: a real id (below
    !> 2^55) as it is, a virtual one (negative) as 2^55 + its hash bits modulo 2^55; a periodic
    !> image (a ghost outside the box) gets its image's code (1..27, from which side of the box
    !> it lies on along each axis) in bits 56-60. Images are recognised by position only, so
    !> every rank count sees the same ids. Two virtual particles of one source set may (rarely:
    !> about n^2 / 2^56) share an id; the caller drops such duplicates.
    pure integer(i8) function image_source_id(id, x, box_lo, box_hi, dim)
        integer(i8), intent(in) :: id
        real(wp), intent(in) :: x(3), box_lo(3), box_hi(3)
        integer, intent(in) :: dim
        integer :: a, code, side
        code = 0
        do a = dim, 1, -1
            side = 1
            if (x(a) < box_lo(a)) side = 0
            if (x(a) >= box_hi(a)) side = 2
            code = 3 * code + side
        end do
        ! 13 = (1, 1, 1): inside on every axis
        if (dim == 2) code = code + 9
        image_source_id = id
        if (id < 0) image_source_id = ibset(iand(-id, ishft(1_i8, 55) - 1_i8), 55)
        if (code /= 13) image_source_id = image_source_id + shiftl(int(code, i8) + 1_i8, 56)
    end function image_source_id

    !> Fine virtual positions (spacing dx/2) from particles x(:, 1:n) of spacing dx: the
    !> refinement construction translated by dx/4 per axis (see the header). vid: their ids.
    subroutine fine_virtual_positions(dim, level, n, x, ids, dx, n_new, x_new, vid, stat, &
            errmsg)
        integer, intent(in) :: dim, level, n
        real(wp), intent(in) :: x(:, :), dx
        integer(i8), intent(in) :: ids(:)
        integer, intent(out) :: n_new
        real(wp), allocatable, intent(out) :: x_new(:, :)
        integer(i8), allocatable, intent(out) :: vid(:)
        integer, intent(out) :: stat
        character(len=*), intent(out) :: errmsg
        integer(i8), allocatable :: key(:, :)
        integer :: k
        call refine_positions(dim, n, x, ids, dx, n_new, x_new, key, stat, errmsg)
        allocate(vid(max(n_new, 0)))
        if (stat /= 0) then
            n_new = 0
            return
        end if
        do k = 1, n_new
            x_new(1:dim, k) = x_new(1:dim, k) + 0.25_wp * dx
            vid(k) = virtual_id(level, key(1, k), key(2, k))
        end do
    end subroutine fine_virtual_positions

    !> Coarse virtual positions (spacing 2 dx) from particles x(:, 1:n) of spacing dx: the
    !> coarsening selection (lattice parity measured from `origin`, the box's lower corner)
    !> translated by dx/2 per axis (see the header). vid: their ids.
    subroutine coarse_virtual_positions(dim, level, n, x, ids, dx, origin, n_new, x_new, vid, &
            stat, errmsg)
        integer, intent(in) :: dim, level, n
        real(wp), intent(in) :: x(:, :), dx, origin(3)
        integer(i8), intent(in) :: ids(:)
        integer, intent(out) :: n_new
        real(wp), allocatable, intent(out) :: x_new(:, :)
        integer(i8), allocatable, intent(out) :: vid(:)
        integer, intent(out) :: stat
        character(len=*), intent(out) :: errmsg
        real(wp), allocatable :: x_rel(:, :)
        integer, allocatable :: kept(:), tag(:)
        integer :: k, a
        allocate(x_rel(3, max(n, 1)))
        do k = 1, n
            x_rel(:, k) = x(:, k) - origin
        end do
        call coarsen_select(dim, n, x_rel, ids, dx, n_new, kept, tag, stat, errmsg)
        if (stat /= 0) n_new = 0
        allocate(x_new(3, max(n_new, 1)), vid(max(n_new, 0)))
        do k = 1, n_new
            x_new(:, k) = x(:, kept(k))
            do a = 1, dim
                x_new(a, k) = x_new(a, k) + 0.5_wp * dx
            end do
            vid(k) = virtual_id(level, ids(kept(k)), 0_i8)
        end do
    end subroutine coarse_virtual_positions

    !> f_dst(:, a) = the interpolant at x_dst(:, a) of the source values f_src(:, 1:n_src)
    !> (see the header: M4', linear MLS correction, h the source spacing). A target with no
    !> source in reach keeps f_dst = 0 and is counted in n_empty; n_fallback counts targets
    !> that needed the M4 or Shepard fallback.
    subroutine interpolate_fields(dim, h, n_src, x_src, f_src, n_dst, x_dst, f_dst, &
            n_fallback, n_empty)
        integer, intent(in) :: dim, n_src, n_dst
        real(wp), intent(in) :: h, x_src(:, :), f_src(:, :), x_dst(:, :)
        real(wp), intent(out) :: f_dst(:, :)
        integer, intent(out) :: n_fallback, n_empty
        real(wp), allocatable :: x_all(:, :)
        type(neighbour_list_t) :: nl
        integer :: a, k, j, nf
        integer, allocatable :: near(:)
        real(wp), allocatable :: dn(:, :)
        real(wp) :: phi_weights(64 * 27)
        integer :: n_near
        logical :: ok

        nf = size(f_src, 1)
        n_fallback = 0
        n_empty = 0
        if (n_dst <= 0) return
        f_dst(:, 1:n_dst) = 0.0_wp
        allocate(x_all(3, n_dst + n_src))
        x_all(:, 1:n_dst) = x_dst(:, 1:n_dst)
        x_all(:, n_dst + 1:) = x_src(:, 1:n_src)
        ! the tensor kernel's support is a cube of half-width 2 h: its corners are in reach
        call build_neighbour_list(x_all, n_dst + n_src, n_dst, dim, &
            interp_support(INTERP_M4) * h * sqrt(real(dim, wp)) * (1.0_wp + 1.0e-12_wp), nl)
        allocate(near(size(phi_weights)), dn(3, size(phi_weights)))
        do a = 1, n_dst
            n_near = 0
            do k = nl%start(a), nl%start(a + 1) - 1
                j = nl%index(k)
                if (j <= n_dst) cycle
                if (n_near == size(near)) exit
                n_near = n_near + 1
                near(n_near) = j - n_dst
                dn(:, n_near) = (x_src(:, j - n_dst) - x_dst(:, a)) / h
            end do
            if (n_near == 0) then
                n_empty = n_empty + 1
                cycle
            end if
            call mls_weights(2, dim, n_near, dn, phi_weights, ok)
            if (.not. ok) then
                n_fallback = n_fallback + 1
                call mls_weights(1, dim, n_near, dn, phi_weights, ok)
                if (.not. ok) call shepard_weights(dim, n_near, dn, phi_weights, ok)
                if (.not. ok) then
                    n_empty = n_empty + 1
                    cycle
                end if
            end if
            do k = 1, n_near
                f_dst(1:nf, a) = f_dst(1:nf, a) + phi_weights(k) * f_src(1:nf, near(k))
            end do
        end do
    end subroutine interpolate_fields

    !> Moving-least-squares weights of the given degree (1 or 2), M4 B-spline weight W at the
    !> offsets d_k (in units of h): phi_k = W_k q(d_k)^T c with M c = q(0), so that the
    !> weights reproduce every polynomial of that degree. ok = .false. when the moment matrix
    !> is not safely invertible (relative pivot below 1e-8).
    pure subroutine mls_weights(degree, dim, n, d, phi, ok)
        integer, intent(in) :: degree, dim, n
        real(wp), intent(in) :: d(:, :)
        real(wp), intent(out) :: phi(:)
        logical, intent(out) :: ok
        real(wp) :: m(10, 10), rhs(10), w, q(10)
        integer :: k, r, nb
        nb = basis_size(degree, dim)
        m = 0.0_wp
        do k = 1, n
            w = interp_weight(INTERP_M4, dim, d(:, k), 1.0_wp)
            phi(k) = w
            if (w == 0.0_wp) cycle
            q = basis(degree, dim, d(:, k))
            do r = 1, nb
                m(1:nb, r) = m(1:nb, r) + w * q(1:nb) * q(r)
            end do
        end do
        rhs = 0.0_wp
        rhs(1) = 1.0_wp
        call solve_small(nb, m, rhs, ok)
        if (.not. ok) return
        do k = 1, n
            if (phi(k) == 0.0_wp) cycle
            q = basis(degree, dim, d(:, k))
            phi(k) = phi(k) * dot_product(rhs(1:nb), q(1:nb))
        end do
    end subroutine mls_weights

    pure integer function basis_size(degree, dim)
        integer, intent(in) :: degree, dim
        basis_size = 1 + dim
        if (degree >= 2) basis_size = basis_size + dim * (dim + 1) / 2
    end function basis_size

    !> The polynomial basis (1, d_a, d_a d_b for a <= b) at offset d.
    pure function basis(degree, dim, d) result(q)
        integer, intent(in) :: degree, dim
        real(wp), intent(in) :: d(:)
        real(wp) :: q(10)
        integer :: a, b, k
        q = 0.0_wp
        q(1) = 1.0_wp
        q(2:dim + 1) = d(1:dim)
        if (degree < 2) return
        k = dim + 1
        do a = 1, dim
            do b = a, dim
                k = k + 1
                q(k) = d(a) * d(b)
            end do
        end do
    end function basis

    !> Normalised M4 B-spline weights (zeroth order).
    pure subroutine shepard_weights(dim, n, d, phi, ok)
        integer, intent(in) :: dim, n
        real(wp), intent(in) :: d(:, :)
        real(wp), intent(out) :: phi(:)
        logical, intent(out) :: ok
        integer :: k
        real(wp) :: total
        do k = 1, n
            phi(k) = interp_weight(INTERP_M4, dim, d(:, k), 1.0_wp)
        end do
        total = sum(phi(1:n))
        ok = total > 0.0_wp
        if (ok) phi(1:n) = phi(1:n) / total
    end subroutine shepard_weights

    !> Solve m(1:n, 1:n) y = b in place (b becomes y) by Gaussian elimination with partial
    !> pivoting; ok = .false. if a pivot falls below 1e-8 of the largest entry.
    pure subroutine solve_small(n, m, b, ok)
        integer, intent(in) :: n
        real(wp), intent(inout) :: m(10, 10), b(10)
        logical, intent(out) :: ok
        integer :: i, k, piv
        real(wp) :: f, scale, row(10), t
        scale = maxval(abs(m(1:n, 1:n)))
        ok = scale > 0.0_wp
        if (.not. ok) return
        do k = 1, n
            piv = k - 1 + maxloc(abs(m(k:n, k)), 1)
            if (abs(m(piv, k)) < 1.0e-8_wp * scale) then
                ok = .false.
                return
            end if
            if (piv /= k) then
                row = m(k, :); m(k, :) = m(piv, :); m(piv, :) = row
                t = b(k); b(k) = b(piv); b(piv) = t
            end if
            do i = k + 1, n
                f = m(i, k) / m(k, k)
                m(i, k:n) = m(i, k:n) - f * m(k, k:n)
                b(i) = b(i) - f * b(k)
            end do
        end do
        do k = n, 1, -1
            b(k) = (b(k) - dot_product(m(k, k + 1:n), b(k + 1:n))) / m(k, k)
        end do
    end subroutine solve_small
end module sph_transition
