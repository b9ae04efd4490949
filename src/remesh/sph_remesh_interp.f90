!> Conservative transfer of extensive quantities (mass m, momentum m v, energy m e, volume m/rho)
!> from old particles to new particles (thesis sec. 3.2.3, eqs. 3.16-3.18). Serial, no MPI: the
!> caller hands in the old particles with their halo and the new positions.
!>
!> Rules:
!>  - Spacing h: the COARSER of the two spacings (old in refinement, new in coarsening). The
!>    interpolating kernels vanish at nonzero multiples of h; with h the finer spacing the
!>    coarse set's sites sit on those zeros (refinement hands everything to the child at the
!>    parent's site; in coarsening a fine particle between two kept ones hands on nothing).
!>  - Base weights W_ij: the positive cubic B-spline (tensor product) of x_new_i - x_old_j.
!>    M4' and Lambda2 have negative lobes; on disordered targets their per-particle sums can
!>    come close to zero and the correction below diverged with them (prototype), so they are
!>    kept for lattice targets (sph_interpolation_kernels).
!>  - Each old particle j hands on exactly what it carried: sum_i w_ij = 1 (normalised over the
!>    receiving new particles). Totals of m, m v, m e, volume are conserved to round-off.
!>  - Linear consistency: every new particle i receives a mass-weighted centroid at its own
!>    position, sum_j w_ij m_j (x_j - x_i) = 0, so a linear velocity (or energy) field is
!>    reproduced. Both constraints are met together by alternating (iterative proportional
!>    fitting): a first-order (linear) correction factor 1 + mu_i.(x_j - x_i) per new particle,
!>    then the per-old normalisation, until the centroid residual is below tol; the last step is
!>    always the normalisation, so conservation is exact whatever the residual. New particles
!>    with fewer than dim+1 donors or a singular moment matrix (edges) are not corrected.
!>  - New velocity = momentum / mass, new e = (m e) / mass. New density = mass / volume, where
!>    the volume m/rho is transferred with the same weights: consistent with the masses, exact
!>    (rho_new = rho_old) for any uniform density, and V_new ~ (new spacing)^dim.
!>  - An old particle with no new particle within the support is an error (stat = 1).
module sph_remesh_interp
    use sph_kinds, only: wp
    use sph_cell_list, only: neighbour_list_t, build_neighbour_list
    use sph_interpolation_kernels, only: INTERP_M4, interp_weight, interp_support
    implicit none
    private
    public :: remesh_transfer

contains

    subroutine remesh_transfer(dim, h, n_old, x_old, m_old, v_old, rho_old, e_old, &
            n_new, x_new, m_new, v_new, rho_new, e_new, stat, errmsg, iterations, residual)
        integer, intent(in) :: dim, n_old, n_new
        real(wp), intent(in) :: h
        real(wp), intent(in) :: x_old(:, :), m_old(:), v_old(:, :), rho_old(:), e_old(:)
        real(wp), intent(in) :: x_new(:, :)
        real(wp), intent(out) :: m_new(:), v_new(:, :), rho_new(:), e_new(:)
        integer, intent(out), optional :: stat
        character(len=*), intent(out), optional :: errmsg
        integer, intent(out), optional :: iterations
        real(wp), intent(out), optional :: residual
        integer, parameter :: max_iter = 300
        real(wp), parameter :: tol = 1.0e-14_wp
        real(wp), allocatable :: x_all(:, :), w(:), b(:, :), a(:, :, :), mu(:, :), colsum(:)
        real(wp), allocatable :: mom(:, :), en(:), vol(:)
        integer, allocatable :: pold(:), pnew(:), donors(:)
        logical, allocatable :: fix(:)
        type(neighbour_list_t) :: nl
        integer :: i, j, k, p, np, it, lost
        real(wp) :: d(3), res, f
        character(len=120) :: msg

        if (present(stat)) stat = 0
        allocate(x_all(3, n_old + n_new))
        x_all(:, 1:n_old) = x_old(:, 1:n_old)
        x_all(:, n_old + 1:) = x_new(:, 1:n_new)
        x_all(dim + 1:, :) = 0.0_wp
        call build_neighbour_list(x_all, n_old + n_new, n_old, dim, &
            interp_support(INTERP_M4) * h * sqrt(real(dim, wp)), nl)
        np = 0
        do p = 1, nl%n_pairs
            if (nl%index(p) > n_old) np = np + 1
        end do
        allocate(w(np), pold(np), pnew(np), colsum(n_old), donors(n_new))
        np = 0
        colsum = 0.0_wp
        donors = 0
        do j = 1, n_old
            do p = nl%start(j), nl%start(j + 1) - 1
                k = nl%index(p)
                if (k <= n_old) cycle
                d = x_all(:, k) - x_all(:, j)
                f = interp_weight(INTERP_M4, dim, d, h)
                if (f <= 0.0_wp) cycle
                np = np + 1
                w(np) = f
                pold(np) = j
                pnew(np) = k - n_old
                colsum(j) = colsum(j) + f
                donors(k - n_old) = donors(k - n_old) + 1
            end do
        end do
        lost = count(colsum <= 0.0_wp)
        if (lost > 0) then
            write(msg, '(a, i0, a)') 'remesh_transfer: ', lost, &
                ' old particle(s) have no new particle within the support'
            if (present(errmsg)) errmsg = msg
            if (present(stat)) then
                stat = 1
                m_new(1:n_new) = 0.0_wp; v_new(:, 1:n_new) = 0.0_wp
                rho_new(1:n_new) = 0.0_wp; e_new(1:n_new) = 0.0_wp
                return
            end if
            error stop 'remesh_transfer: an old particle has no new particle within the support'
        end if
        call normalise()

        allocate(b(3, n_new), a(3, 3, n_new), mu(3, n_new), fix(n_new))
        res = 0.0_wp
        do it = 1, max_iter
            call centroid_moments(res)
            if (res < tol) exit
            ! first-order correction per new particle: solve A mu = -b
            do i = 1, n_new
                fix(i) = donors(i) > dim
                if (fix(i)) call solve_small(dim, a(:, :, i), -b(:, i), mu(:, i), fix(i))
            end do
            do p = 1, np
                i = pnew(p)
                if (.not. fix(i)) cycle
                d = x_old(:, pold(p)) - x_new(:, i)
                if (abs(dot_product(mu(1:dim, i), d(1:dim))) > 0.5_wp) fix(i) = .false.
            end do
            do p = 1, np
                i = pnew(p)
                if (.not. fix(i)) cycle
                d = x_old(:, pold(p)) - x_new(:, i)
                w(p) = w(p) * (1.0_wp + dot_product(mu(1:dim, i), d(1:dim)))
            end do
            colsum = 0.0_wp
            do p = 1, np
                colsum(pold(p)) = colsum(pold(p)) + w(p)
            end do
            call normalise()
        end do
        if (present(iterations)) iterations = it
        call centroid_moments(res)
        if (present(residual)) residual = res

        allocate(mom(3, n_new), en(n_new), vol(n_new))
        m_new(1:n_new) = 0.0_wp
        mom = 0.0_wp; en = 0.0_wp; vol = 0.0_wp
        do p = 1, np
            i = pnew(p); j = pold(p)
            m_new(i) = m_new(i) + w(p) * m_old(j)
            mom(:, i) = mom(:, i) + w(p) * m_old(j) * v_old(:, j)
            en(i) = en(i) + w(p) * m_old(j) * e_old(j)
            vol(i) = vol(i) + w(p) * m_old(j) / rho_old(j)
        end do
        do i = 1, n_new
            if (m_new(i) > 0.0_wp .and. vol(i) > 0.0_wp) then
                v_new(:, i) = mom(:, i) / m_new(i)
                e_new(i) = en(i) / m_new(i)
                rho_new(i) = m_new(i) / vol(i)
            else
                v_new(:, i) = 0.0_wp; e_new(i) = 0.0_wp; rho_new(i) = 0.0_wp
            end if
        end do

    contains

        subroutine normalise()
            integer :: q
            do q = 1, np
                w(q) = w(q) / colsum(pold(q))
            end do
        end subroutine normalise

        !> b_i = sum_j w m_j (x_j - x_i), A_i = sum_j w m_j d d^T; worst |b_i| / (M_i h).
        subroutine centroid_moments(worst)
            real(wp), intent(out) :: worst
            integer :: q, ii, r
            real(wp) :: dd(3), wm, mass(n_new)
            b = 0.0_wp; a = 0.0_wp; mass = 0.0_wp
            do q = 1, np
                ii = pnew(q)
                dd = x_old(:, pold(q)) - x_new(:, ii)
                dd(dim + 1:) = 0.0_wp
                wm = w(q) * m_old(pold(q))
                mass(ii) = mass(ii) + wm
                b(:, ii) = b(:, ii) + wm * dd
                do r = 1, 3
                    a(:, r, ii) = a(:, r, ii) + wm * dd * dd(r)
                end do
            end do
            worst = 0.0_wp
            do ii = 1, n_new
                if (donors(ii) > dim .and. mass(ii) > 0.0_wp) &
                    worst = max(worst, maxval(abs(b(:, ii))) / (mass(ii) * h))
            end do
        end subroutine centroid_moments
    end subroutine remesh_transfer

    !> Solve the dim x dim system m x = r by Gaussian elimination with partial pivoting;
    !> ok = .false. when m is (nearly) singular.
    pure subroutine solve_small(dim, m, r, x, ok)
        integer, intent(in) :: dim
        real(wp), intent(in) :: m(3, 3), r(3)
        real(wp), intent(out) :: x(3)
        logical, intent(out) :: ok
        real(wp) :: g(3, 4), row(4), scale
        integer :: c, piv, q
        g(:, 1:3) = m
        g(:, 4) = r
        x = 0.0_wp
        scale = maxval(abs(m(1:dim, 1:dim)))
        ok = scale > 0.0_wp
        if (.not. ok) return
        do c = 1, dim
            piv = c - 1 + maxloc(abs(g(c:dim, c)), dim=1)
            if (abs(g(piv, c)) <= 1.0e-12_wp * scale) then
                ok = .false.
                return
            end if
            row = g(c, :); g(c, :) = g(piv, :); g(piv, :) = row
            do q = c + 1, dim
                g(q, :) = g(q, :) - g(q, c) / g(c, c) * g(c, :)
            end do
        end do
        do c = dim, 1, -1
            x(c) = (g(c, 4) - dot_product(g(c, c + 1:dim), x(c + 1:dim))) / g(c, c)
        end do
    end subroutine solve_small
end module sph_remesh_interp
