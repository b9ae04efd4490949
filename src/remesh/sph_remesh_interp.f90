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
!>  - Density is interpolated as the velocity is (first-order corrected, so a linear field is
!>    reproduced), with base weights of DENSITY_SUPPORT = 0.6 of the velocity's support
!>    (M4 of the offset / (0.6 h)): a weakly compressible flow carries its pressure in the
!>    density, sharply peaked where it meets a body, and the velocity's weights, twice as
!>    wide as the spacing, smoothed those peaks away at every remesh. A same-level remesh of
!>    a creeping channel flow with three bodies that left the positions as they were (only
!>    the transfer) narrowed its density range from 986-1015 to 994-1007 kg/m^3 and, done
!>    every 20 steps, ran the flow 12 % faster (with the old densities kept: as unremeshed);
!>    with the narrow interpolant the remeshed flow runs 5.32 / 4.97 / 4.97 against 5.56 /
!>    5.26 / 4.99 (1e-6 m/s; remeshed every 20 / 200 / 1000 steps; unremeshed 4.70, at half
!>    the spacing 4.44). Narrower still (0.5) the correction failed at nearly every new
!>    particle (too few donors), and Shepard's weights of that support, or M4' weights
!>    (interpolating, with negative lobes: densities 857-1131 kg/m^3 within 0.5 s), did no
!>    better. Where the correction is singular or would take the weights' sum below half of
!>    theirs (extrapolation from a few one-sided donors), Shepard's of the same support; with
!>    no old particle within it, m_a over the transferred volume (the rule before), which is
!>    exact for a uniform density too. Both counted (n_density_fallback).
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
    use sph_kinds, only: wp, i8
    use sph_cell_list, only: cell_grid_t, bin_particles, cell_runs
    use sph_interpolation_kernels, only: INTERP_M4, interp_support
    implicit none
    private
    public :: remesh_transfer, transfer_accumulate, transfer_finish, transfer_rows
    public :: transfer_unreached

    !> The first rows of a column (transfer_accumulate): mass, m e and volume handed on, the
    !> velocity interpolant's s0; then s1 (dim), va (dim), s2 (dim^2), vb (dim^2); then the
    !> density interpolant's s0, s1 (dim), s2 (dim^2), ra (1) and rb (dim).
    integer, parameter :: A_M = 1, A_E = 2, A_VOL = 3, A_S0 = 4, A_S1 = 5
    !> the density interpolant's support, as a fraction of the velocity's (module header)
    real(wp), parameter :: DENSITY_SUPPORT = 0.6_wp

contains

    !> Hand the fields of the old particles on to the new positions (module header): masses,
    !> energies and volumes conservatively, velocities by a corrected interpolant; total
    !> momentum kept by one uniform correction.
    subroutine remesh_transfer(dim, h, n_old, x_old, m_old, v_old, rho_old, e_old, &
            n_new, x_new, m_new, v_new, rho_new, e_new, stat, errmsg, n_mass_fallback, &
            n_velocity_fallback, n_density_fallback)
        integer, intent(in) :: dim, n_old, n_new
        real(wp), intent(in) :: h
        real(wp), intent(in) :: x_old(:, :), m_old(:), v_old(:, :), rho_old(:), e_old(:)
        real(wp), intent(in) :: x_new(:, :)
        real(wp), intent(out) :: m_new(:), v_new(:, :), rho_new(:), e_new(:)
        integer, intent(out), optional :: stat
        character(len=*), intent(out), optional :: errmsg
        integer, intent(out), optional :: n_mass_fallback, n_velocity_fallback
        integer, intent(out), optional :: n_density_fallback
        real(wp), allocatable :: acc(:, :)
        real(wp) :: mom_old(3), mom_new(3), dv(3)
        integer :: i, j, st, n_mfb, n_vfb, n_rfb
        character(len=400) :: msg

        allocate(acc(transfer_rows(dim), max(n_new, 1)))
        call transfer_accumulate(dim, h, n_old, x_old, m_old, v_old, rho_old, e_old, n_new, &
            x_new, acc, st, msg, n_mfb)
        n_rfb = 0
        if (st == 0) call transfer_finish(dim, n_new, acc, m_new, v_new, rho_new, e_new, st, &
            msg, n_vfb, n_rfb)
        if (present(n_density_fallback)) n_density_fallback = n_rfb
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
        transfer_rows = A_S1 + 2 * dim + 2 * dim * dim - 1 + 2 + 2 * dim + dim * dim
    end function transfer_rows

    !> The sums of the old particles x_old(:, 1:n_old) (each its mass, m e and volume handed on
    !> with its own normalised, centroid-keeping weights; the velocity moments) added into
    !> acc(:, 1:n_new), one column per new particle x_new(:, k) (zeroed first). n_mass_fallback:
    !> old particles that fell back to lower order. stat 1: an old particle has no new
    !> particle within 4 h. id_new (optional): the new particles' global ids, which break an
    !> exact tie of an isolated old particle's nearest new ones (else the first in storage
    !> order, which depends on the rank count).
    subroutine transfer_accumulate(dim, h, n_old, x_old, m_old, v_old, rho_old, e_old, &
            n_new, x_new, acc, stat, errmsg, n_mass_fallback, n_isolated, id_new)
        integer, intent(in) :: dim, n_old, n_new
        real(wp), intent(in) :: h
        real(wp), intent(in) :: x_old(:, :), m_old(:), v_old(:, :), rho_old(:), e_old(:)
        real(wp), intent(in) :: x_new(:, :)
        real(wp), intent(out) :: acc(:, :)
        integer, intent(out) :: stat
        character(len=*), intent(out) :: errmsg
        integer, intent(out) :: n_mass_fallback
        !> old particles with no new particle in their support (handed to the nearest one)
        integer, intent(out), optional :: n_isolated
        integer(i8), intent(in), optional :: id_new(:)
        !> an isolated old particle's one pair: negligible in its target's velocity moments
        real(wp), parameter :: ISOLATED_WEIGHT = 1.0e-30_wp, ISOLATED_REACH = 4.0_wp
        ! the columns (per new particle, packed: a pair's updates touch a few cache lines of
        ! one column instead of many arrays): mass, m e and volume handed on, the velocity
        ! interpolant's moments (s0, s1, s2) and the sums sum u v (va) and sum u d v^T (vb)
        ! that give the corrected interpolant in one pass
        ! per old particle: the candidates (new particles in its cells) with their offsets / h
        ! and base weights (cd, cwt), then its pairs (those of positive weight: dl, wl, al)
        real(wp), allocatable :: dl(:, :), wl(:), cw(:), ys(:, :), cd(:, :), cwt(:)
        integer, allocatable :: al(:), first(:), last(:)
        type(cell_grid_t) :: grid
        integer :: j, q, r, p, nloc, lost, n_cand, n_runs
        real(wp) :: t0(3), t1(3, 3), beta(3), xj(3), inv_h, total, lowest
        logical :: ok

        stat = 0
        errmsg = ''
        acc(:, 1:n_new) = 0.0_wp
        if (dim /= 2 .and. dim /= 3) error stop 'transfer_accumulate: dim must be 2 or 3'
        ! the scatters address the columns at fixed offsets (explicit shape)
        if (size(acc, 1) /= transfer_rows(dim)) &
            error stop 'transfer_accumulate: acc needs transfer_rows(dim) rows'
        ! old-new pairs: the new particles binned in cells of half M4's support half-width
        ! 2 h, each old particle's candidates in the 5^dim cells around it filtered by the
        ! weight itself (zero outside the cube), no pair list stored. The new positions are
        ! copied in the cell order, one array per axis: a run of candidates is then read
        ! contiguously and its loops vectorise. (The columns stay in the caller's order: a
        ! copy in the cell order, added back at the end, cost more in allocation than its
        ! locality saved for new particles that come about in space order, as in id order.)
        call bin_particles(x_new, n_new, dim, 0.5_wp * interp_support(INTERP_M4) * h, grid)
        allocate(ys(max(n_new, 1), 3))
        ys = 0.0_wp
        do q = 1, n_new
            ys(q, 1:dim) = x_new(1:dim, grid%sorted(q))
        end do
        allocate(first(25), last(25), dl(3, 256), wl(256), cw(256), al(256), cd(256, 3), &
            cwt(256))
        inv_h = 1.0_wp / h
        lost = 0
        n_mass_fallback = 0
        if (present(n_isolated)) n_isolated = 0
        do j = 1, n_old
            xj = 0.0_wp
            xj(1:dim) = x_old(1:dim, j)
            call cell_runs(grid, xj, 2, first, last, n_runs)
            n_cand = sum(last(1:n_runs) - first(1:n_runs) + 1)
            if (n_cand > size(wl)) then
                deallocate(dl, wl, cw, al, cd, cwt)
                allocate(dl(3, n_cand), wl(n_cand), cw(n_cand), al(n_cand), cd(n_cand, 3), &
                    cwt(n_cand))
            end if
            ! every candidate's offsets and weight without branches over contiguous runs (the
            ! compiler vectorises the runs; most candidates lie outside the cube), then the
            ! pairs (positive weight) compacted
            p = 0
            do r = 1, n_runs
                if (dim == 2) then
                    do q = first(r), last(r)
                        cd(p + q - first(r) + 1, 1) = (ys(q, 1) - xj(1)) * inv_h
                        cd(p + q - first(r) + 1, 2) = (ys(q, 2) - xj(2)) * inv_h
                        cwt(p + q - first(r) + 1) = m4_weight(cd(p + q - first(r) + 1, 1)) * &
                            m4_weight(cd(p + q - first(r) + 1, 2))
                    end do
                else
                    do q = first(r), last(r)
                        cd(p + q - first(r) + 1, 1) = (ys(q, 1) - xj(1)) * inv_h
                        cd(p + q - first(r) + 1, 2) = (ys(q, 2) - xj(2)) * inv_h
                        cd(p + q - first(r) + 1, 3) = (ys(q, 3) - xj(3)) * inv_h
                        cwt(p + q - first(r) + 1) = m4_weight(cd(p + q - first(r) + 1, 1)) * &
                            m4_weight(cd(p + q - first(r) + 1, 2)) * &
                            m4_weight(cd(p + q - first(r) + 1, 3))
                    end do
                end if
                p = p + last(r) - first(r) + 1
            end do
            nloc = 0
            p = 0
            if (dim == 2) then
                ! (no third offsets: the 2D moments, weights and scatter_2d never read them)
                do r = 1, n_runs
                    do q = first(r), last(r)
                        p = p + 1
                        dl(1, nloc + 1) = cd(p, 1)
                        dl(2, nloc + 1) = cd(p, 2)
                        wl(nloc + 1) = cwt(p)
                        al(nloc + 1) = grid%sorted(q)
                        nloc = nloc + merge(1, 0, cwt(p) > 0.0_wp)
                    end do
                end do
            else
                do r = 1, n_runs
                    do q = first(r), last(r)
                        p = p + 1
                        dl(1, nloc + 1) = cd(p, 1)
                        dl(2, nloc + 1) = cd(p, 2)
                        dl(3, nloc + 1) = cd(p, 3)
                        wl(nloc + 1) = cwt(p)
                        al(nloc + 1) = grid%sorted(q)
                        nloc = nloc + merge(1, 0, cwt(p) > 0.0_wp)
                    end do
                end do
            end if
            if (nloc == 0) then
                ! alone in a void: everything to the nearest new particle (a fallback)
                if (present(n_isolated)) n_isolated = n_isolated + 1
                call nearest_new(j, q, ok)
                if (.not. ok) then
                    lost = lost + 1
                    cycle
                end if
                al(1) = q
                nloc = 1
                dl(:, 1) = 0.0_wp
                dl(1:dim, 1) = (x_new(1:dim, q) - x_old(1:dim, j)) / h
                wl(1) = ISOLATED_WEIGHT
                cw(1) = 1.0_wp
                n_mass_fallback = n_mass_fallback + 1
            else
                ! first-order corrected weights: the centroid kept (module header)
                lowest = 0.0_wp
                total = 0.0_wp
                if (dim == 2) then
                    ! (the general solve's loops and sections were a tenth of a coarsening's
                    ! transfer; the third axis' zeros a tenth of the rest)
                    call weight_moments_2d(nloc, wl, dl, t0, t1)
                    call solve_2x2(t1(1, 1), t1(1, 2), t1(2, 1), t1(2, 2), -t0(1), -t0(2), &
                        beta(1), beta(2), ok)
                    if (ok) then
                        do p = 1, nloc
                            cw(p) = wl(p) * (1.0_wp + beta(1) * dl(1, p) + beta(2) * dl(2, p))
                            lowest = min(lowest, cw(p))
                            total = total + cw(p)
                        end do
                    end if
                else
                    call weight_moments(dim, nloc, wl, dl, t0, t1)
                    call solve_small(dim, t1, -t0, beta, ok)
                    if (ok) then
                        do p = 1, nloc
                            cw(p) = wl(p) * (1.0_wp + beta(1) * dl(1, p) + beta(2) * dl(2, p) &
                                + beta(3) * dl(3, p))
                            lowest = min(lowest, cw(p))
                            total = total + cw(p)
                        end do
                    end if
                end if
                if (ok) ok = lowest >= 0.0_wp .and. total > 0.0_wp
                if (.not. ok) then
                    n_mass_fallback = n_mass_fallback + 1
                    cw(1:nloc) = wl(1:nloc)
                    total = sum(cw(1:nloc))
                end if
                cw(1:nloc) = cw(1:nloc) * (1.0_wp / total)
            end if
            if (dim == 2) then
                call scatter_2d(nloc, al, cw, wl, dl, m_old(j), e_old(j), rho_old(j), &
                    v_old(1:2, j), acc)
            else
                call scatter_3d(nloc, al, cw, wl, dl, m_old(j), e_old(j), rho_old(j), &
                    v_old(1:3, j), acc)
            end if
        end do
        if (lost > 0) then
            ! (what a user can act on: the geometry, not the transfer's internals; a slot
            ! one fine spacing wide along a closed box's walls, coarsened, fz31)
            write(errmsg, '(i0, a, es10.3, a)') lost, &
                ' old particle(s) have no new particle within the support, nor within ', &
                ISOLATED_REACH * h, ' m: they lie where the new spacing leaves no room for ' // &
                'a particle (a slot or gap between solids narrower than about one new ' // &
                'spacing), so their mass has nowhere to go: the geometry cannot be ' // &
                'remeshed to the new spacing (keep the present one, or widen the gap)'
            stat = 1
        end if

    contains

        !> The nearest new particle within ISOLATED_REACH h of old particle jj (an old particle
        !> with no new particle in its support: alone in a void of a developed flow, or next to
        !> a body whose first row the new set keeps off the surface). Farther, the sets do not
        !> match (a caller's error) and the particle is lost (stat 1). Brute force: such
        !> particles are rare. Of equally near ones, the one with the lowest id (id_new).
        subroutine nearest_new(jj, best, found)
            integer, intent(in) :: jj
            integer, intent(out) :: best
            logical, intent(out) :: found
            integer :: a
            real(wp) :: dd(3), d2, best_d2
            logical :: tie
            best = 0
            best_d2 = (ISOLATED_REACH * h)**2
            do a = 1, n_new
                dd = 0.0_wp
                dd(1:dim) = x_new(1:dim, a) - x_old(1:dim, jj)
                d2 = sum(dd * dd)
                tie = .false.
                if (best /= 0 .and. present(id_new)) &
                    tie = abs(d2 - best_d2) <= 0.0_wp .and. id_new(a) < id_new(best)
                ! the first strictly nearer one, or the first one within reach
                if (d2 < best_d2 .or. (best == 0 .and. d2 <= best_d2) .or. tie) then
                    best_d2 = d2
                    best = a
                end if
            end do
            found = best /= 0
        end subroutine nearest_new
    end subroutine transfer_accumulate

    !> The new particles 1..n whose columns acc(:, 1:n) received nothing: no old particle or
    !> mirror has them within its support. The construction can put a point at the mouth of
    !> a slot that holds no fluid, and the relaxation push it deeper; every pair hands on a
    !> positive mass and volume (non-negative weights), so such a column is exactly zero and
    !> dropping its particle changes no total. (A negative or NaN column is not unreached:
    !> transfer_finish refuses it.)
    pure function transfer_unreached(n, acc) result(unreached)
        integer, intent(in) :: n
        real(wp), intent(in) :: acc(:, :)
        logical :: unreached(n)
        unreached = abs(acc(A_M, 1:n)) <= 0.0_wp .and. abs(acc(A_VOL, 1:n)) <= 0.0_wp
    end function transfer_unreached

    !> Mass, energy, density and the corrected velocity interpolant of the new particles
    !> 1..n from their columns acc(:, 1:n) (transfer_accumulate, every old particle's sums
    !> in). n_velocity_fallback: new particles whose interpolant fell back to Shepard's.
    !> stat 2: a new particle received no mass.
    subroutine transfer_finish(dim, n, acc, m_new, v_new, rho_new, e_new, stat, errmsg, &
            n_velocity_fallback, n_density_fallback)
        integer, intent(in) :: dim, n
        real(wp), intent(in) :: acc(:, :)
        real(wp), intent(out) :: m_new(:), v_new(:, :), rho_new(:), e_new(:)
        integer, intent(out) :: stat
        character(len=*), intent(out) :: errmsg
        integer, intent(out) :: n_velocity_fallback
        !> new particles whose density interpolant fell back (module header)
        integer, intent(out), optional :: n_density_fallback
        integer :: a_va, a_s2, a_vb, i, c, q, empty, n_rho_fallback
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
            write(errmsg, '(i0, a)') empty, &
                ' new particle(s) receive no mass (no old particle within the support)'
            stat = 2
            return
        end if
        e_new(1:n) = acc(A_E, 1:n) / m_new(1:n)
        call finish_density()
        if (present(n_density_fallback)) n_density_fallback = n_rho_fallback
        ! velocity: the first-order corrected interpolant,
        ! v_a = sum_j u_aj (1 + gam . d_j) v_j / (s0 + gam . s1) = (va + vb gam) / (s0 + gam . s1)
        if (dim == 2) then
            ! written out (rows as transfer_rows; solve_2x2 does solve_small's arithmetic):
            ! the general loop's array sections and reshape were a tenth of a refinement
            do i = 1, n
                call solve_2x2(acc(9, i), acc(11, i), acc(10, i), acc(12, i), -acc(5, i), &
                    -acc(6, i), gam(1), gam(2), ok)
                s0 = acc(A_S0, i)
                if (ok) ok = s0 + (gam(1) * acc(5, i) + gam(2) * acc(6, i)) > 1.0e-12_wp * s0
                if (.not. ok) then
                    n_velocity_fallback = n_velocity_fallback + 1
                    gam(1:2) = 0.0_wp
                end if
                f = s0 + (gam(1) * acc(5, i) + gam(2) * acc(6, i))
                v_new(1, i) = (acc(7, i) + (gam(1) * acc(13, i) + gam(2) * acc(15, i))) / f
                v_new(2, i) = (acc(8, i) + (gam(1) * acc(14, i) + gam(2) * acc(16, i))) / f
            end do
            return
        end if
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

    contains

        !> The density: the first-order corrected interpolant of narrow support (the rows
        !> after vb), as the velocity's; Shepard's of that support where the correction is
        !> singular or extrapolates; the handed mass over the handed volume where no old
        !> particle lies within the narrow support.
        subroutine finish_density()
            integer :: r0, j
            real(wp) :: t0, t1(3), t2(3, 3), g(3), ff
            logical :: good
            r0 = a_vb + dim * dim
            n_rho_fallback = 0
            if (dim == 2) then
                ! written out, as the velocity's (rows 17-26)
                do j = 1, n
                    t0 = acc(17, j)
                    if (.not. t0 > 0.0_wp) then
                        n_rho_fallback = n_rho_fallback + 1
                        rho_new(j) = m_new(j) / acc(A_VOL, j)
                        cycle
                    end if
                    call solve_2x2(acc(20, j), acc(22, j), acc(21, j), acc(23, j), &
                        -acc(18, j), -acc(19, j), g(1), g(2), good)
                    if (good) good = t0 + (g(1) * acc(18, j) + g(2) * acc(19, j)) > 0.5_wp * t0
                    if (.not. good) then
                        n_rho_fallback = n_rho_fallback + 1
                        g(1:2) = 0.0_wp
                    end if
                    ff = t0 + (g(1) * acc(18, j) + g(2) * acc(19, j))
                    rho_new(j) = (acc(24, j) + (g(1) * acc(25, j) + g(2) * acc(26, j))) / ff
                end do
                return
            end if
            do j = 1, n
                t0 = acc(r0, j)
                if (.not. t0 > 0.0_wp) then
                    n_rho_fallback = n_rho_fallback + 1
                    rho_new(j) = m_new(j) / acc(A_VOL, j)
                    cycle
                end if
                t1 = 0.0_wp
                t1(1:dim) = acc(r0 + 1:r0 + dim, j)
                t2 = 0.0_wp
                t2(1:dim, 1:dim) = reshape(acc(r0 + dim + 1:r0 + dim + dim * dim, j), &
                    [dim, dim])
                g = 0.0_wp
                call solve_small(dim, t2, -t1, g, good)
                if (good) good = t0 + dot_product(g(1:dim), t1(1:dim)) > 0.5_wp * t0
                if (.not. good) then
                    n_rho_fallback = n_rho_fallback + 1
                    g = 0.0_wp
                end if
                ff = t0 + dot_product(g(1:dim), t1(1:dim))
                rho_new(j) = (acc(r0 + dim + dim * dim + 1, j) + dot_product(g(1:dim), &
                    acc(r0 + dim + dim * dim + 2:r0 + 2 * dim + dim * dim + 1, j))) / ff
            end do
        end subroutine finish_density
    end subroutine transfer_finish

    !> The moments of one old particle's base weights over its pairs: t0 = sum w d,
    !> t1 = sum w d d^T (offsets d / h; the third component is zero in 2D).
    pure subroutine weight_moments(dim, n, w, d, t0, t1)
        integer, intent(in) :: dim, n
        real(wp), intent(in) :: w(:), d(:, :)
        real(wp), intent(out) :: t0(3), t1(3, 3)
        integer :: p
        real(wp) :: a1, a2, a3
        t0 = 0.0_wp
        t1 = 0.0_wp
        do p = 1, n
            a1 = w(p) * d(1, p)
            a2 = w(p) * d(2, p)
            a3 = w(p) * d(3, p)
            t0(1) = t0(1) + a1
            t0(2) = t0(2) + a2
            t0(3) = t0(3) + a3
            t1(1, 1) = t1(1, 1) + a1 * d(1, p)
            t1(2, 1) = t1(2, 1) + a2 * d(1, p)
            t1(3, 1) = t1(3, 1) + a3 * d(1, p)
            t1(2, 2) = t1(2, 2) + a2 * d(2, p)
            t1(3, 2) = t1(3, 2) + a3 * d(2, p)
            t1(3, 3) = t1(3, 3) + a3 * d(3, p)
        end do
        t1(1, 2) = t1(2, 1)
        t1(1, 3) = t1(3, 1)
        t1(2, 3) = t1(3, 2)
        if (dim == 2) then
            t0(3) = 0.0_wp
            t1(3, :) = 0.0_wp
            t1(:, 3) = 0.0_wp
        end if
    end subroutine weight_moments

    !> weight_moments in 2D: t0(1:2), t1(1:2, 1:2), the same sums in the same order; the
    !> third row and column zero.
    pure subroutine weight_moments_2d(n, w, d, t0, t1)
        integer, intent(in) :: n
        real(wp), intent(in) :: w(:), d(:, :)
        real(wp), intent(out) :: t0(3), t1(3, 3)
        integer :: p
        real(wp) :: a1, a2
        t0 = 0.0_wp
        t1 = 0.0_wp
        do p = 1, n
            a1 = w(p) * d(1, p)
            a2 = w(p) * d(2, p)
            t0(1) = t0(1) + a1
            t0(2) = t0(2) + a2
            t1(1, 1) = t1(1, 1) + a1 * d(1, p)
            t1(2, 1) = t1(2, 1) + a2 * d(1, p)
            t1(2, 2) = t1(2, 2) + a2 * d(2, p)
        end do
        t1(1, 2) = t1(2, 1)
    end subroutine weight_moments_2d

    !> One old particle's sums (mass m, energy e, density rho, velocity v) added into the
    !> 2D columns of its pairs al(1:n): the extensive quantities with the normalised weights
    !> cw, the velocity moments with u = w V at the new particle (offset -d from it). Rows as
    !> transfer_rows: M, E, VOL, S0, S1 (2), va (2), s2 (2 x 2), vb (2 x 2), written out (acc
    !> of explicit shape: the rows at fixed offsets).
    pure subroutine scatter_2d(n, al, cw, w, d, m, e, rho, v, acc)
        integer, intent(in) :: n, al(:)
        real(wp), intent(in) :: cw(:), w(:), d(:, :), m, e, rho, v(2)
        real(wp), intent(inout) :: acc(26, *)
        integer :: p, i
        real(wp) :: vol, me, u, ex, ey, ux, uy
        vol = m / rho
        me = m * e
        do p = 1, n
            i = al(p)
            u = w(p) * vol
            ex = -d(1, p)
            ey = -d(2, p)
            ux = u * ex
            uy = u * ey
            acc(1, i) = acc(1, i) + cw(p) * m
            acc(2, i) = acc(2, i) + cw(p) * me
            acc(3, i) = acc(3, i) + cw(p) * vol
            acc(4, i) = acc(4, i) + u
            acc(5, i) = acc(5, i) + ux
            acc(6, i) = acc(6, i) + uy
            acc(7, i) = acc(7, i) + u * v(1)
            acc(8, i) = acc(8, i) + u * v(2)
            acc(9, i) = acc(9, i) + ux * ex
            acc(10, i) = acc(10, i) + uy * ex
            acc(11, i) = acc(11, i) + ux * ey
            acc(12, i) = acc(12, i) + uy * ey
            acc(13, i) = acc(13, i) + ux * v(1)
            acc(14, i) = acc(14, i) + ux * v(2)
            acc(15, i) = acc(15, i) + uy * v(1)
            acc(16, i) = acc(16, i) + uy * v(2)
            ! the density interpolant's narrow weights (zero beyond DENSITY_SUPPORT of the
            ! velocity's support: most pairs)
            if (abs(d(1, p)) >= 2.0_wp * DENSITY_SUPPORT .or. &
                abs(d(2, p)) >= 2.0_wp * DENSITY_SUPPORT) cycle
            u = m4_weight(d(1, p) * (1.0_wp / DENSITY_SUPPORT)) * &
                m4_weight(d(2, p) * (1.0_wp / DENSITY_SUPPORT)) * vol
            ux = u * ex
            uy = u * ey
            acc(17, i) = acc(17, i) + u
            acc(18, i) = acc(18, i) + ux
            acc(19, i) = acc(19, i) + uy
            acc(20, i) = acc(20, i) + ux * ex
            acc(21, i) = acc(21, i) + uy * ex
            acc(22, i) = acc(22, i) + ux * ey
            acc(23, i) = acc(23, i) + uy * ey
            acc(24, i) = acc(24, i) + u * rho
            acc(25, i) = acc(25, i) + ux * rho
            acc(26, i) = acc(26, i) + uy * rho
        end do
    end subroutine scatter_2d

    !> scatter_2d in 3D: M, E, VOL, S0, S1 (3), va (3), s2 (3 x 3), vb (3 x 3).
    pure subroutine scatter_3d(n, al, cw, w, d, m, e, rho, v, acc)
        integer, intent(in) :: n, al(:)
        real(wp), intent(in) :: cw(:), w(:), d(:, :), m, e, rho, v(3)
        real(wp), intent(inout) :: acc(45, *)
        integer :: p, i, c
        real(wp) :: vol, me, u, ud(3)
        vol = m / rho
        me = m * e
        do p = 1, n
            i = al(p)
            u = w(p) * vol
            ud = -u * d(:, p)
            acc(1, i) = acc(1, i) + cw(p) * m
            acc(2, i) = acc(2, i) + cw(p) * me
            acc(3, i) = acc(3, i) + cw(p) * vol
            acc(4, i) = acc(4, i) + u
            acc(5:7, i) = acc(5:7, i) + ud
            acc(8:10, i) = acc(8:10, i) + u * v
            do c = 1, 3
                acc(8 + 3 * c:10 + 3 * c, i) = acc(8 + 3 * c:10 + 3 * c, i) - ud * d(c, p)
                acc(17 + 3 * c:19 + 3 * c, i) = acc(17 + 3 * c:19 + 3 * c, i) - d(c, p) * u * v
            end do
            ! the density interpolant's narrow weights (as scatter_2d)
            if (any(abs(d(:, p)) >= 2.0_wp * DENSITY_SUPPORT)) cycle
            u = m4_weight(d(1, p) * (1.0_wp / DENSITY_SUPPORT)) * &
                m4_weight(d(2, p) * (1.0_wp / DENSITY_SUPPORT)) * &
                m4_weight(d(3, p) * (1.0_wp / DENSITY_SUPPORT)) * vol
            ud = -u * d(:, p)
            acc(29, i) = acc(29, i) + u
            acc(30:32, i) = acc(30:32, i) + ud
            do c = 1, 3
                acc(30 + 3 * c:32 + 3 * c, i) = acc(30 + 3 * c:32 + 3 * c, i) - ud * d(c, p)
            end do
            acc(42, i) = acc(42, i) + u * rho
            acc(43:45, i) = acc(43:45, i) + ud * rho
        end do
    end subroutine scatter_3d

    !> The cubic B-spline M4 (sph_interpolation_kernels' m4_bspline), here so that the
    !> transfer's pair loop inlines it: 2/3 - s^2 + |s|^3/2 (|s| < 1), (2 - |s|)^3/6 (< 2),
    !> in the truncated-power form ((2 - |s|)_+^3 - 4 (1 - |s|)_+^3) / 6: no branch, so the
    !> candidates' loop vectorises.
    pure elemental real(wp) function m4_weight(s) result(w)
        real(wp), intent(in) :: s
        real(wp) :: a, b, c
        a = abs(s)
        b = max(2.0_wp - a, 0.0_wp)
        c = max(1.0_wp - a, 0.0_wp)
        w = (b * b * b - 4.0_wp * c * c * c) * (1.0_wp / 6.0_wp)
    end function m4_weight

    !> solve_small for dim = 2, the same operations in the same order (so the same result to
    !> the last bit): [m11 m12; m21 m22] (x1, x2) = (r1, r2).
    pure subroutine solve_2x2(m11, m12, m21, m22, r1, r2, x1, x2, ok)
        real(wp), intent(in) :: m11, m12, m21, m22, r1, r2
        real(wp), intent(out) :: x1, x2
        logical, intent(out) :: ok
        real(wp) :: a11, a12, a21, a22, b1, b2, scale
        x1 = 0.0_wp
        x2 = 0.0_wp
        scale = max(abs(m11), abs(m21), abs(m12), abs(m22))
        ok = scale > 0.0_wp
        if (.not. ok) return
        if (abs(m21) > abs(m11)) then
            a11 = m21; a12 = m22; b1 = r2
            a21 = m11; a22 = m12; b2 = r1
        else
            a11 = m11; a12 = m12; b1 = r1
            a21 = m21; a22 = m22; b2 = r2
        end if
        ok = abs(a11) > 1.0e-10_wp * scale
        if (.not. ok) return
        a22 = a22 - a21 / a11 * a12
        b2 = b2 - a21 / a11 * b1
        ok = abs(a22) > 1.0e-10_wp * scale
        if (.not. ok) return
        x2 = b2 / a22
        x1 = (b1 - a12 * x2) / a11
    end subroutine solve_2x2

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
