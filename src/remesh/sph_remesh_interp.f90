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
!> Stages (for a caller that spreads the particles over ranks): every quantity above is a
!> sum over old particles, accumulated per new particle in one column of transfer_rows(dim)
!> values (transfer_accumulate); the fields follow from a column (transfer_finish). A rank
!> can therefore accumulate from the old particles it owns into its new particles and their
!> ghosts, add the ghosts' columns to their owners' (a reverse halo sum), finish its own new
!> particles and correct momentum with global sums. remesh_transfer is the three in one.
module sph_remesh_interp
    use sph_kinds, only: wp
    use sph_cell_list, only: cell_grid_t, bin_particles, cell_candidates
    use sph_interpolation_kernels, only: INTERP_M4, interp_support
    implicit none
    private
    public :: remesh_transfer, transfer_accumulate, transfer_finish, transfer_rows

    !> The first rows of a column (transfer_accumulate): mass, m e and volume handed on, the
    !> velocity interpolant's s0; then s1 (dim), va (dim), s2 (dim^2), vb (dim^2).
    integer, parameter :: A_M = 1, A_E = 2, A_VOL = 3, A_S0 = 4, A_S1 = 5

contains

    !> Hand the fields of the old particles on to the new positions (module header): masses,
    !> energies and volumes conservatively, velocities by a corrected interpolant; total
    !> momentum kept by one uniform correction.
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
        real(wp), allocatable :: acc(:, :)
        real(wp) :: mom_old(3), mom_new(3), dv(3)
        integer :: i, j, st, n_mfb, n_vfb
        character(len=120) :: msg

        allocate(acc(transfer_rows(dim), max(n_new, 1)))
        call transfer_accumulate(dim, h, n_old, x_old, m_old, v_old, rho_old, e_old, n_new, &
            x_new, acc, st, msg, n_mfb)
        if (st == 0) call transfer_finish(dim, n_new, acc, m_new, v_new, rho_new, e_new, st, &
            msg, n_vfb)
        if (st /= 0) then
            m_new(1:n_new) = 0.0_wp
            if (present(errmsg)) errmsg = msg
            if (present(stat)) then
                stat = st
                return
            end if
            error stop 'remesh_transfer: particles without partner within the kernel support'
        end if
        if (present(stat)) stat = 0
        ! one uniform correction: total momentum as before
        mom_old = 0.0_wp; mom_new = 0.0_wp
        do j = 1, n_old
            mom_old(1:dim) = mom_old(1:dim) + m_old(j) * v_old(1:dim, j)
        end do
        do i = 1, n_new
            mom_new(1:dim) = mom_new(1:dim) + m_new(i) * v_new(1:dim, i)
        end do
        dv = (mom_old - mom_new) / sum(m_new(1:n_new))
        do i = 1, n_new
            v_new(1:dim, i) = v_new(1:dim, i) + dv(1:dim)
        end do
        if (present(n_mass_fallback)) n_mass_fallback = n_mfb
        if (present(n_velocity_fallback)) n_velocity_fallback = n_vfb
    end subroutine remesh_transfer

    !> Values per new particle in transfer_accumulate's columns: 16 in 2D, 28 in 3D.
    pure integer function transfer_rows(dim)
        integer, intent(in) :: dim
        transfer_rows = A_S1 + 2 * dim + 2 * dim * dim - 1
    end function transfer_rows

    !> The sums of the old particles x_old(:, 1:n_old) (each its mass, m e and volume handed on
    !> with its own normalised, centroid-keeping weights; the velocity moments) added into
    !> acc(:, 1:n_new), one column per new particle x_new(:, k) (zeroed first). n_mass_fallback:
    !> old particles that fell back to lower order. stat 1: an old particle has no new
    !> particle within 4 h.
    subroutine transfer_accumulate(dim, h, n_old, x_old, m_old, v_old, rho_old, e_old, &
            n_new, x_new, acc, stat, errmsg, n_mass_fallback)
        integer, intent(in) :: dim, n_old, n_new
        real(wp), intent(in) :: h
        real(wp), intent(in) :: x_old(:, :), m_old(:), v_old(:, :), rho_old(:), e_old(:)
        real(wp), intent(in) :: x_new(:, :)
        real(wp), intent(out) :: acc(:, :)
        integer, intent(out) :: stat
        character(len=*), intent(out) :: errmsg
        integer, intent(out) :: n_mass_fallback
        !> an isolated old particle's one pair: negligible in its target's velocity moments
        real(wp), parameter :: ISOLATED_WEIGHT = 1.0e-30_wp, ISOLATED_REACH = 4.0_wp
        ! the columns (per new particle, packed: a pair's updates touch four cache lines of
        ! one column instead of eight arrays): mass, m e and volume handed on, the velocity
        ! interpolant's moments (s0, s1, s2) and the sums sum u v (va) and sum u d v^T (vb)
        ! that give the corrected interpolant in one pass
        integer :: a_va, a_s2, a_vb
        ! per old particle: the new particles in its cells, and its pairs (offset / h, base
        ! weight, new particle)
        real(wp), allocatable :: dl(:, :), wl(:), cw(:)
        integer, allocatable :: al(:), cand(:)
        type(cell_grid_t) :: grid
        integer :: i, j, k, p, c, q, nloc, lost, n_cand
        real(wp) :: d(3), f, beta(3), t0(3), t1(3, 3), u, vj, xj(3), inv_h
        logical :: ok

        stat = 0
        errmsg = ''
        acc(:, 1:n_new) = 0.0_wp
        ! old-new pairs: the new particles binned in cells of M4's support half-width 2 h,
        ! each old particle's candidates filtered by the weight itself (zero outside the
        ! cube), no pair list stored
        call bin_particles(x_new, n_new, dim, interp_support(INTERP_M4) * h, grid)
        allocate(cand(64), dl(3, 64), wl(64), cw(64), al(64))
        a_va = A_S1 + dim
        a_s2 = a_va + dim
        a_vb = a_s2 + dim * dim
        inv_h = 1.0_wp / h
        lost = 0
        n_mass_fallback = 0
        do j = 1, n_old
            xj = 0.0_wp
            xj(1:dim) = x_old(1:dim, j)
            call cell_candidates(grid, xj, cand, n_cand)
            if (n_cand > size(wl)) then
                deallocate(dl, wl, cw, al)
                allocate(dl(3, n_cand), wl(n_cand), cw(n_cand), al(n_cand))
            end if
            ! components written out and the weight without branches: most candidates lie
            ! outside the cube, and the tests per axis were most of this loop's time
            nloc = 0
            do p = 1, n_cand
                k = cand(p)
                d(1) = (x_new(1, k) - xj(1)) * inv_h
                d(2) = 0.0_wp
                d(3) = 0.0_wp
                if (dim > 1) d(2) = (x_new(2, k) - xj(2)) * inv_h
                if (dim > 2) d(3) = (x_new(3, k) - xj(3)) * inv_h
                f = m4_weight(d(1)) * m4_weight(d(2))
                if (dim > 2) f = f * m4_weight(d(3))
                if (dim == 1) f = m4_weight(d(1))
                if (f <= 0.0_wp) cycle
                nloc = nloc + 1
                dl(:, nloc) = d
                wl(nloc) = f
                al(nloc) = k
            end do
            if (nloc == 0) then
                ! alone in a void: everything to the nearest new particle (a fallback)
                call nearest_new(j, al(1), ok)
                if (.not. ok) then
                    lost = lost + 1
                    cycle
                end if
                nloc = 1
                dl(:, 1) = 0.0_wp
                dl(1:dim, 1) = (x_new(1:dim, al(1)) - x_old(1:dim, j)) / h
                wl(1) = ISOLATED_WEIGHT
                cw(1) = 1.0_wp
                n_mass_fallback = n_mass_fallback + 1
            else
                ! first-order corrected weights: the centroid kept (module header)
                t0 = 0.0_wp
                t1 = 0.0_wp
                do p = 1, nloc
                    t0 = t0 + wl(p) * dl(:, p)
                    do c = 1, dim
                        t1(1:dim, c) = t1(1:dim, c) + wl(p) * dl(1:dim, p) * dl(c, p)
                    end do
                end do
                call solve_small(dim, t1, -t0, beta, ok)
                if (ok) then
                    do p = 1, nloc
                        cw(p) = wl(p) * (1.0_wp + dot_product(beta(1:dim), dl(1:dim, p)))
                    end do
                    ok = all(cw(1:nloc) >= 0.0_wp) .and. sum(cw(1:nloc)) > 0.0_wp
                end if
                if (.not. ok) then
                    n_mass_fallback = n_mass_fallback + 1
                    cw(1:nloc) = wl(1:nloc)
                end if
                cw(1:nloc) = cw(1:nloc) / sum(cw(1:nloc))
            end if
            vj = m_old(j) / rho_old(j)
            do p = 1, nloc
                i = al(p)
                ! extensive quantities handed on
                acc(A_M, i) = acc(A_M, i) + cw(p) * m_old(j)
                acc(A_E, i) = acc(A_E, i) + cw(p) * m_old(j) * e_old(j)
                acc(A_VOL, i) = acc(A_VOL, i) + cw(p) * vj
                ! velocity moments at the new particle, offsets from it (-d) and u = W V
                u = wl(p) * vj
                d = -dl(:, p)
                acc(A_S0, i) = acc(A_S0, i) + u
                acc(A_S1:A_S1 + dim - 1, i) = acc(A_S1:A_S1 + dim - 1, i) + u * d(1:dim)
                acc(a_va:a_va + dim - 1, i) = acc(a_va:a_va + dim - 1, i) + u * v_old(1:dim, j)
                do c = 1, dim
                    q = dim * (c - 1)
                    acc(a_s2 + q:a_s2 + q + dim - 1, i) = acc(a_s2 + q:a_s2 + q + dim - 1, i) &
                        + u * d(1:dim) * d(c)
                    acc(a_vb + q:a_vb + q + dim - 1, i) = acc(a_vb + q:a_vb + q + dim - 1, i) &
                        + u * d(c) * v_old(1:dim, j)
                end do
            end do
        end do
        if (lost > 0) then
            write(errmsg, '(a, i0, a)') 'remesh_transfer: ', lost, &
                ' old particle(s) have no new particle within the support'
            stat = 1
        end if

    contains

        !> The nearest new particle within ISOLATED_REACH h of old particle jj (an old particle
        !> with no new particle in its support: alone in a void of a developed flow, or next to
        !> a body whose first row the new set keeps off the surface). Farther, the sets do not
        !> match (a caller's error) and the particle is lost (stat 1). Brute force: such
        !> particles are rare.
        subroutine nearest_new(jj, best, found)
            integer, intent(in) :: jj
            integer, intent(out) :: best
            logical, intent(out) :: found
            integer :: a
            real(wp) :: dd(3), d2, best_d2
            best = 0
            best_d2 = (ISOLATED_REACH * h)**2
            do a = 1, n_new
                dd = 0.0_wp
                dd(1:dim) = x_new(1:dim, a) - x_old(1:dim, jj)
                d2 = sum(dd * dd)
                ! the first strictly nearer one, or the first one within reach
                if (d2 < best_d2 .or. (best == 0 .and. d2 <= best_d2)) then
                    best_d2 = d2
                    best = a
                end if
            end do
            found = best /= 0
        end subroutine nearest_new
    end subroutine transfer_accumulate

    !> Mass, energy, density and the corrected velocity interpolant of the new particles
    !> 1..n from their columns acc(:, 1:n) (transfer_accumulate, every old particle's sums
    !> in). n_velocity_fallback: new particles whose interpolant fell back to Shepard's.
    !> stat 2: a new particle received no mass.
    subroutine transfer_finish(dim, n, acc, m_new, v_new, rho_new, e_new, stat, errmsg, &
            n_velocity_fallback)
        integer, intent(in) :: dim, n
        real(wp), intent(in) :: acc(:, :)
        real(wp), intent(out) :: m_new(:), v_new(:, :), rho_new(:), e_new(:)
        integer, intent(out) :: stat
        character(len=*), intent(out) :: errmsg
        integer, intent(out) :: n_velocity_fallback
        integer :: a_va, a_s2, a_vb, i, c, q, empty
        real(wp) :: s0, s1(3), s2(3, 3), gam(3), f, d(3)
        logical :: ok

        stat = 0
        errmsg = ''
        n_velocity_fallback = 0
        a_va = A_S1 + dim
        a_s2 = a_va + dim
        a_vb = a_s2 + dim * dim
        v_new(:, 1:n) = 0.0_wp
        m_new(1:n) = acc(A_M, 1:n)
        empty = count(m_new(1:n) <= 0.0_wp .or. acc(A_VOL, 1:n) <= 0.0_wp)
        if (empty > 0) then
            write(errmsg, '(a, i0, a)') 'remesh_transfer: ', empty, &
                ' new particle(s) receive no mass (no old particle within the support)'
            stat = 2
            return
        end if
        e_new(1:n) = acc(A_E, 1:n) / m_new(1:n)
        rho_new(1:n) = m_new(1:n) / acc(A_VOL, 1:n)
        ! velocity: the first-order corrected interpolant,
        ! v_a = sum_j u_aj (1 + gam . d_j) v_j / (s0 + gam . s1) = (va + vb gam) / (s0 + gam . s1)
        do i = 1, n
            s2 = 0.0_wp
            s2(1:dim, 1:dim) = reshape(acc(a_s2:a_s2 + dim * dim - 1, i), [dim, dim])
            s1 = 0.0_wp
            s1(1:dim) = acc(A_S1:A_S1 + dim - 1, i)
            s0 = acc(A_S0, i)
            call solve_small(dim, s2, -s1, gam, ok)
            if (ok) ok = s0 + dot_product(gam(1:dim), s1(1:dim)) > 1.0e-12_wp * s0
            if (.not. ok) then
                n_velocity_fallback = n_velocity_fallback + 1
                gam = 0.0_wp
            end if
            f = s0 + dot_product(gam(1:dim), s1(1:dim))
            d = 0.0_wp
            do c = 1, dim
                q = a_vb + dim * (c - 1)
                d(1:dim) = d(1:dim) + gam(c) * acc(q:q + dim - 1, i)
            end do
            v_new(1:dim, i) = (acc(a_va:a_va + dim - 1, i) + d(1:dim)) / f
        end do
    end subroutine transfer_finish

    !> The cubic B-spline M4 (sph_interpolation_kernels' m4_bspline), here so that the
    !> transfer's pair loop inlines it: 2/3 - s^2 + |s|^3/2 (|s| < 1), (2 - |s|)^3/6 (< 2).
    !> (Both pieces evaluated and one chosen, no branch; beyond |s| = 2 the second is 0.)
    pure real(wp) function m4_weight(s) result(w)
        real(wp), intent(in) :: s
        real(wp) :: a, b
        a = abs(s)
        b = max(2.0_wp - a, 0.0_wp)
        w = merge(2.0_wp / 3.0_wp - a * a + 0.5_wp * a * a * a, b * b * b / 6.0_wp, a < 1.0_wp)
    end function m4_weight

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
