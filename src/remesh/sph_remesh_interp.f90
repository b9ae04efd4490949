!> Conservative transfer of the fields of old particles onto new particles (thesis sec. 3.2.3,
!> eqs. 3.16-3.18). Serial, no MPI: the caller hands in the old particles with their halo and
!> the new positions. One neighbour search (old x new pairs within the kernel support) serves
!> both halves below.
!>
!> Rules:
!>  - Spacing h: the COARSER of the two spacings (old in refinement, new in coarsening). With
!>    h the finer spacing, refinement of a lattice gives alternating masses (2/3, 1/3 m per
!>    axis); with h the coarser one, the new set is a union of 2^dim lattices of spacing h, on
!>    each of which the B-spline sums to 1 with zero first moment, so every interior new
!>    particle receives exactly m/2^dim.
!>  - Base weights W_ia: the positive cubic B-spline M4 (tensor product, support 2h per axis)
!>    of x_a - x_i (M4' and Lambda2 have negative lobes; they are kept for lattice targets,
!>    sph_interpolation_kernels).
!>  - Extensive quantities (mass m, energy m e, volume m/rho) are handed on by each OLD particle
!>    i with local weights w_ia = W_ia (1 + beta_i . (x_a - x_i)) / norm_i over the new
!>    particles a in its support, where beta_i solves the dim x dim system that makes
!>    sum_a w_ia (x_a - x_i) = 0 and norm_i makes sum_a w_ia = 1. So each old particle hands on
!>    exactly what it carried (mass, energy, volume conserved to round-off) with its centroid
!>    kept in place (centre of mass conserved to round-off). If a corrected weight is negative
!>    or the system singular (too few or one-sided new neighbours: cloud edges, walls), that old
!>    particle falls back to the uncorrected normalised weights W_ia / sum_a W_ia (still
!>    conservative, centroid not kept); such particles are counted (n_mass_fallback). An old
!>    particle with no new particle in its support at all (alone in a void of a developed
!>    flow) hands everything to its nearest new particle within 4 h, also counted as a
!>    fallback.
!>  - Velocity is interpolated, not transferred: at each new particle a, the corrected SPH
!>    (first-order consistent) interpolant of the old velocities with weights
!>    u_ai = W_ia V_i (1 + gamma_a . (x_i - x_a)), V_i = m_i / rho_i, gamma_a such that
!>    sum_i u_ai (x_i - x_a) = 0, normalised to sum 1: a linear field is reproduced to
!>    round-off. Fewer than dim+1 donors or a singular moment matrix: Shepard (zeroth order)
!>    weights, counted (n_velocity_fallback). Then ONE uniform correction
!>    dv = (sum_i m_i v_i - sum_a m_a v_a) / sum_a m_a is added to every new velocity, so total
!>    momentum is conserved exactly. For a linear field v = c + B x the interpolated momentum
!>    is c M_new + B sum_a m_a x_a, and since mass and centre of mass are conserved this equals
!>    the old momentum: dv is round-off and the linear field stays reproduced. When any
!>    particle falls back (old: the centre of mass moves by some delta, dv = B delta; new: its
!>    velocity is only zeroth order) dv is no longer round-off but spreads that edge error
!>    over all particles. Tests: 5 % jitter with the new cloud 3/4 h beyond the old one has no
!>    fallback; the new cloud flush with the old one (or 20 % jitter) has some at the corners.
!>    Kinetic energy is not conserved exactly.
!>  - Energy: e_a = (transferred m e) / m_a, so the total sum m e is conserved.
!>  - Density: rho_a = m_a / (transferred volume), exact (rho_a = rho) for a uniform density.
!>  - Errors: an old particle with no new particle within 4 h (its mass would be lost,
!>    stat = 1), or a new particle with no old particle in its support (it would get no mass,
!>    stat = 2). Without stat, error stop.
module sph_remesh_interp
    use sph_kinds, only: wp
    use sph_cell_list, only: neighbour_list_t, build_neighbour_list
    use sph_interpolation_kernels, only: INTERP_M4, interp_weight, interp_support
    implicit none
    private
    public :: remesh_transfer

contains

    !> Hand the fields of the old particles on to the new positions (module header): masses,
    !> energies and volumes conservatively, velocities by a corrected interpolant.
    subroutine remesh_transfer(dim, h, n_old, x_old, m_old, v_old, rho_old, e_old, &
            n_new, x_new, m_new, v_new, rho_new, e_new, stat, errmsg, n_mass_fallback, &
            n_velocity_fallback)
        integer, intent(in) :: dim, n_old, n_new
        real(wp), intent(in) :: h
        real(wp), intent(in) :: x_old(:, :), m_old(:), v_old(:, :), rho_old(:), e_old(:)
        real(wp), intent(in) :: x_new(:, :)
        real(wp), intent(out) :: m_new(:), v_new(:, :), rho_new(:), e_new(:)
        integer, intent(out), optional :: stat
        character(len=*), intent(out), optional :: errmsg
        integer, intent(out), optional :: n_mass_fallback, n_velocity_fallback
        real(wp), allocatable :: x_all(:, :), wb(:), w(:), s0(:), s1(:, :), s2(:, :, :)
        real(wp), allocatable :: gam(:, :), en(:), vol(:)
        integer, allocatable :: pold(:), pnew(:)
        logical, allocatable :: first_order(:)
        type(neighbour_list_t) :: nl
        integer :: i, j, k, p, np, lost, empty, n_mfb, n_vfb, r, q, n_isolated
        real(wp) :: d(3), f, beta(3), mom_old(3), mom_new(3), mass_new, dv(3)
        logical :: ok
        character(len=120) :: msg

        if (present(stat)) stat = 0
        m_new(1:n_new) = 0.0_wp; v_new(:, 1:n_new) = 0.0_wp
        rho_new(1:n_new) = 0.0_wp; e_new(1:n_new) = 0.0_wp
        allocate(x_all(3, n_old + n_new))
        x_all(:, 1:n_old) = x_old(:, 1:n_old)
        x_all(:, n_old + 1:) = x_new(:, 1:n_new)
        x_all(dim + 1:, :) = 0.0_wp
        call build_neighbour_list(x_all, n_old + n_new, n_old, dim, &
            interp_support(INTERP_M4) * h * sqrt(real(dim, wp)), nl)

        ! old-new pairs with W > 0, grouped by old particle
        np = 0
        do p = 1, nl%n_pairs
            if (nl%index(p) > n_old) np = np + 1
        end do
        allocate(wb(np), w(np), pold(np), pnew(np))
        np = 0
        do j = 1, n_old
            do p = nl%start(j), nl%start(j + 1) - 1
                k = nl%index(p)
                if (k <= n_old) cycle
                d = x_all(:, k) - x_all(:, j)
                f = interp_weight(INTERP_M4, dim, d, h)
                if (f <= 0.0_wp) cycle
                np = np + 1
                wb(np) = f
                pold(np) = j
                pnew(np) = k - n_old
            end do
        end do

        call hand_isolated_to_nearest()

        ! moments per old particle (d = (x_a - x_i)/h)
        allocate(s0(n_old), s1(3, n_old), s2(3, 3, n_old))
        call moments(n_old, pold, 1.0_wp, s0, s1, s2)
        lost = count(s0 <= 0.0_wp)
        if (lost > 0) then
            write(msg, '(a, i0, a)') 'remesh_transfer: ', lost, &
                ' old particle(s) have no new particle within the support'
            call fail(1)
            return
        end if

        ! local first-order corrected weights per old particle, fallback: normalised W
        n_mfb = n_isolated
        p = 1
        do j = 1, n_old
            q = p
            do while (q <= np)
                if (pold(q) /= j) exit
                q = q + 1
            end do
            ! pairs p .. q-1 belong to old particle j
            call solve_small(dim, s2(:, :, j), -s1(:, j), beta, ok)
            if (ok) then
                do r = p, q - 1
                    d = (x_new(:, pnew(r)) - x_old(:, j)) / h
                    w(r) = wb(r) * (1.0_wp + dot_product(beta(1:dim), d(1:dim)))
                end do
                ok = all(w(p:q - 1) >= 0.0_wp) .and. sum(w(p:q - 1)) > 0.0_wp
            end if
            if (.not. ok) then
                n_mfb = n_mfb + 1
                w(p:q - 1) = wb(p:q - 1)
            end if
            w(p:q - 1) = w(p:q - 1) / sum(w(p:q - 1))
            p = q
        end do

        allocate(en(n_new), vol(n_new))
        en = 0.0_wp; vol = 0.0_wp
        do p = 1, np
            i = pnew(p); j = pold(p)
            m_new(i) = m_new(i) + w(p) * m_old(j)
            en(i) = en(i) + w(p) * m_old(j) * e_old(j)
            vol(i) = vol(i) + w(p) * m_old(j) / rho_old(j)
        end do
        empty = count(m_new(1:n_new) <= 0.0_wp .or. vol <= 0.0_wp)
        if (empty > 0) then
            write(msg, '(a, i0, a)') 'remesh_transfer: ', empty, &
                ' new particle(s) receive no mass (no old particle within the support)'
            call fail(2)
            return
        end if
        e_new(1:n_new) = en / m_new(1:n_new)
        rho_new(1:n_new) = m_new(1:n_new) / vol

        ! velocity: first-order corrected interpolation at each new particle, u = W V
        deallocate(s0, s1, s2)
        allocate(s0(n_new), s1(3, n_new), s2(3, 3, n_new), gam(3, n_new), first_order(n_new))
        do p = 1, np
            wb(p) = wb(p) * m_old(pold(p)) / rho_old(pold(p))
        end do
        call moments(n_new, pnew, -1.0_wp, s0, s1, s2)
        n_vfb = 0
        do i = 1, n_new
            call solve_small(dim, s2(:, :, i), -s1(:, i), gam(:, i), first_order(i))
            if (first_order(i)) first_order(i) = &
                s0(i) + dot_product(gam(1:dim, i), s1(1:dim, i)) > 1.0e-12_wp * s0(i)
            if (.not. first_order(i)) then
                n_vfb = n_vfb + 1
                gam(:, i) = 0.0_wp
            end if
            s0(i) = s0(i) + dot_product(gam(1:dim, i), s1(1:dim, i))
        end do
        do p = 1, np
            i = pnew(p); j = pold(p)
            d = (x_old(:, j) - x_new(:, i)) / h
            f = wb(p) * (1.0_wp + dot_product(gam(1:dim, i), d(1:dim))) / s0(i)
            v_new(1:dim, i) = v_new(1:dim, i) + f * v_old(1:dim, j)
        end do

        ! one uniform correction: total momentum as before
        mom_old = 0.0_wp; mom_new = 0.0_wp
        do j = 1, n_old
            mom_old(1:dim) = mom_old(1:dim) + m_old(j) * v_old(1:dim, j)
        end do
        do i = 1, n_new
            mom_new(1:dim) = mom_new(1:dim) + m_new(i) * v_new(1:dim, i)
        end do
        mass_new = sum(m_new(1:n_new))
        dv = (mom_old - mom_new) / mass_new
        do i = 1, n_new
            v_new(1:dim, i) = v_new(1:dim, i) + dv(1:dim)
        end do
        if (present(n_mass_fallback)) n_mass_fallback = n_mfb
        if (present(n_velocity_fallback)) n_velocity_fallback = n_vfb

    contains

        !> An old particle with no new particle within its support (alone in a void of a
        !> developed flow, next to a body whose first row the new set keeps off the surface)
        !> hands everything to its nearest new particle: one pair of negligible weight
        !> ISOLATED_WEIGHT (so it does not bias that particle's velocity interpolation) is
        !> inserted in its place in the pairs, grouped by old particle. Counted as a mass
        !> fallback. Only within ISOLATED_REACH h: farther, the sets do not match (a caller's
        !> error) and the particle stays lost (stat 1). Brute force over the new particles:
        !> such particles are rare.
        subroutine hand_isolated_to_nearest()
            real(wp), parameter :: ISOLATED_WEIGHT = 1.0e-30_wp, ISOLATED_REACH = 4.0_wp
            logical, allocatable :: paired(:)
            real(wp), allocatable :: wb2(:)
            integer, allocatable :: po2(:), pn2(:)
            integer :: t, c, a, best
            real(wp) :: dd(3), d2, best_d2
            allocate(paired(n_old))
            paired = .false.
            paired(pold(1:np)) = .true.
            n_isolated = count(.not. paired)
            if (n_isolated == 0 .or. n_new == 0) then
                n_isolated = 0
                return
            end if
            allocate(wb2(np + n_isolated), po2(np + n_isolated), pn2(np + n_isolated))
            c = 0
            t = 1
            do j = 1, n_old
                do while (t <= np)
                    if (pold(t) /= j) exit
                    c = c + 1
                    wb2(c) = wb(t); po2(c) = pold(t); pn2(c) = pnew(t)
                    t = t + 1
                end do
                if (paired(j)) cycle
                best = 0
                best_d2 = huge(1.0_wp)
                do a = 1, n_new
                    dd = x_new(:, a) - x_old(:, j)
                    dd(dim + 1:) = 0.0_wp
                    d2 = sum(dd * dd)
                    if (d2 < best_d2 .and. d2 <= (ISOLATED_REACH * h)**2) then
                        best_d2 = d2
                        best = a
                    end if
                end do
                if (best == 0) cycle
                c = c + 1
                wb2(c) = ISOLATED_WEIGHT; po2(c) = j; pn2(c) = best
            end do
            n_isolated = c - np
            np = c
            call move_alloc(wb2, wb)
            call move_alloc(po2, pold)
            call move_alloc(pn2, pnew)
            deallocate(w)
            allocate(w(np))
        end subroutine hand_isolated_to_nearest

        !> Zeroth, first and second moments of the current pair weights wb, gathered on the side
        !> given by owner (pold or pnew); d = sgn (x_new - x_old) / h, i.e. measured from the
        !> owner towards its partners.
        subroutine moments(n, owner, sgn, m0, m1, m2)
            integer, intent(in) :: n, owner(:)
            real(wp), intent(in) :: sgn
            real(wp), intent(out) :: m0(:), m1(:, :), m2(:, :, :)
            integer :: t, o, c
            real(wp) :: dd(3)
            m0(1:n) = 0.0_wp; m1(:, 1:n) = 0.0_wp; m2(:, :, 1:n) = 0.0_wp
            do t = 1, np
                o = owner(t)
                dd = sgn * (x_new(:, pnew(t)) - x_old(:, pold(t))) / h
                dd(dim + 1:) = 0.0_wp
                m0(o) = m0(o) + wb(t)
                m1(:, o) = m1(:, o) + wb(t) * dd
                do c = 1, 3
                    m2(:, c, o) = m2(:, c, o) + wb(t) * dd * dd(c)
                end do
            end do
        end subroutine moments

        subroutine fail(code)
            integer, intent(in) :: code
            m_new(1:n_new) = 0.0_wp
            if (present(errmsg)) errmsg = msg
            if (present(stat)) then
                stat = code
                return
            end if
            error stop 'remesh_transfer: particles without partner within the kernel support'
        end subroutine fail
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
            if (abs(g(piv, c)) <= 1.0e-10_wp * scale) then
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
