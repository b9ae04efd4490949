!> The uniform -> multi-resolution refinement (refine_uniform_state, interface and
!> documentation in sph_transition_driver): a restart of a uniform checkpoint with &region
!> groups, and the offline --remesh refine --regions. Split from sph_transition_driver, which
!> keeps the transition zones of a running multi-resolution state, so that each file holds
!> one concern (doc/multiresolution.md, "From a uniform run to a multi-resolution one").
submodule (sph_transition_driver) sph_uniform_refinement
    ! (the modules whose procedures it calls are named here too, importing nothing: the
    ! parent's use makes their entities visible, but the build recompiles this file only
    ! for the modules it names. Through the parent alone, whose own interface stayed the
    ! same, a stale object crashed in relax_displacements after that gained arguments.)
    use sph_mpi_env, only:
    use sph_remesh_images, only:
    use sph_errors, only:
    use sph_particles, only:
    use sph_solids, only:
    use sph_remesh_relax, only:
    use sph_domain, only:
    use sph_initial, only:
    use sph_global_ids, only:
    use sph_transition, only:
    use sph_refine, only:
    use sph_cell_list, only:
    implicit none

contains

    module procedure refine_uniform_state
        integer :: lv, dim, j, k, a, n_here, n_all, ntot, n_new, st, n_fb, n_empty, n_clip, n
        integer :: ny
        integer(i8) :: first
        integer, allocatable :: here(:), order(:), orig(:), parity(:), keep(:), om(:)
        real(wp), allocatable :: xs(:, :), fs(:, :), xa(:, :), fa(:, :), xn(:, :), fn(:, :)
        real(wp), allocatable :: ym(:, :)
        integer(i8), allocatable :: ids(:), ida(:), vid(:)
        real(wp) :: box(3), y(3), reach
        logical, allocatable :: drop(:), wanted(:), fit(:)
        real(wp), allocatable :: x_fill(:, :)
        integer, allocatable :: parity_fill(:)
        integer(i8), allocatable :: site_fill(:)
        integer :: n_fill
        logical :: is_real
        character(len=256) :: msg
        type(config_t) :: level_cfg
        type(particles_t) :: lattice

        dim = cfg%domain%dimension
        do lv = 1, zones%n_levels - 1
            ! every rank's real fluid of level lv - 1 near lv's region, on every rank
            reach = zones%width + SOURCE_MARGIN * level_phys(lv - 1)%dx
            here = pack([(j, j = 1, p%n_owned)], p%kind(1:p%n_owned) == KIND_FLUID .and. &
                p%level(1:p%n_owned) == lv - 1)
            here = pack(here, [(zones%distance_to_level(p%x(:, here(j)), lv) < reach, &
                j = 1, size(here))])
            n_here = size(here)
            n_all = int(global_sum(env, int(n_here, i8)))
            first = exclusive_scan_i8(env, int(n_here, i8))
            allocate(xs(3, n_all), fs(5, n_all), ids(n_all))
            xs = 0.0_wp
            fs = 0.0_wp
            ids = 0
            do j = 1, n_here
                xs(:, first + j) = p%x(:, here(j)) - cfg%domain%box_lo
                fs(1:3, first + j) = p%v(:, here(j))
                fs(4, first + j) = p%rho(here(j))
                fs(5, first + j) = p%e(here(j))
                ids(first + j) = p%id(here(j))
            end do
            xs = reshape(global_sum(env, reshape(xs, [3 * n_all])), [3, n_all])
            fs = reshape(global_sum(env, reshape(fs, [5 * n_all])), [5, n_all])
            ids = global_sum(env, ids)
            allocate(order(n_all))
            call id_order(ids, n_all, order)
            xs = xs(:, order)
            fs = fs(:, order)
            ids = ids(order)
            ! periodic images within reach of the box (other axes: too far to matter)
            box = 0.0_wp
            do a = 1, dim
                box(a) = cfg%domain%box_hi(a) - cfg%domain%box_lo(a)
                if (.not. cfg%domain%is_periodic(a)) box(a) = 4.0_wp * box(a) + reach
            end do
            ! the positions from the sources and their mirrors across the solids (corners
            ! included): the construction, shifted by dx/4 (fine_virtual_positions), needs a
            ! point on each surface for the fine row between it and the first coarse row (a
            ! band along the lower wall of a channel came out without that row: 2.5 % of the
            ! fluid mass gone, a gap of two fine spacings); what lands inside a solid is
            ! dropped below. Ids: the places in that list (the sources in id order, then the
            ! mirrors in their order), the same on every rank count
            ny = n_all
            ym = xs
            allocate(om(n_all))
            om = [(k, k = 1, n_all)]
            call with_mirrors(dim, solids, cfg%domain%box_lo, &
                MIRROR_DEPTH * level_phys(lv - 1)%dx, ym, om, ny)
            call with_periodic_images(dim, ny, ym, .true., box, reach, xa, orig, ntot)
            allocate(ida(ntot))
            do k = 1, ntot
                ida(k) = image_source_id(int(orig(k), i8), xa(:, k), &
                    [0.0_wp, 0.0_wp, 0.0_wp], box, dim)
            end do
            call fine_virtual_positions(dim, lv, ntot, xa, ida, level_phys(lv - 1)%dx, n_new, &
                xn, vid, parity, st, msg)
            if (global_max(env, int(st, i8)) /= 0) call fatal_collective('restart', &
                'refining a uniform checkpoint: ' // trim(msg))
            ! the points in the box, each once: those beyond a periodic face are copies of
            ! points inside, and the fitting and relaxing below would move a copy apart from
            ! its twin (a 3D band around a body that crossed a face had pairs 0.03 fine
            ! spacings apart); what lies beyond a wall is dropped below anyway
            keep = pack([(j, j = 1, n_new)], [(all(xn(1:dim, j) >= 0.0_wp .and. &
                xn(1:dim, j) < cfg%domain%box_hi(1:dim) - cfg%domain%box_lo(1:dim)), &
                j = 1, n_new)])
            xn = xn(:, keep)
            vid = vid(keep)
            parity = parity(keep)
            n_new = size(keep)
            ! next to a body the shifted rows are fitted to its surface (a fresh lattice's rule)
            allocate(fit(max(n_new, 1)))
            call fit_to_bodies(dim, n_new, xn, cfg%domain%box_lo, level_phys(lv)%dx, solids, &
                box, fit)
            ! a nested level is made from the level before it, whose sources next to a body
            ! were fitted, filled and relaxed: no lattice, and the construction leaves its
            ! irregular cells without centres over all of that band (a level-2 band of 4 fine
            ! spacings around a cylinder came out 12 % short of a fresh start's particles and
            ! mass): the empty sites of the whole band are filled from the lattice
            if (lv > 1) then
                call fill_next_to_bodies(dim, n_new, xn, fit, cfg%domain%box_lo, &
                    cfg%domain%box_hi, level_phys(lv)%dx, solids, FILL_GAP, box, n_fill, &
                    x_fill, parity_fill, site_fill, band=4.0_wp * (RELAX_BODY_BAND + 1.0_wp))
            else
                call fill_next_to_bodies(dim, n_new, xn, fit, cfg%domain%box_lo, &
                    cfg%domain%box_hi, level_phys(lv)%dx, solids, FILL_GAP, box, n_fill, &
                    x_fill, parity_fill, site_fill)
            end if
            keep = pack([(j, j = 1, n_new)], fit(1:n_new))
            xn = reshape([xn(:, keep), x_fill], [3, size(keep) + n_fill])
            vid = [vid(keep), (virtual_id(lv, -site_fill(j), 0_i8), j = 1, n_fill)]
            parity = [parity(keep), parity_fill]
            n_new = size(keep) + n_fill
            deallocate(fit)
            call relax_next_to_bodies()
            call thin_new_points()
            ! the fields from the sources alone (the linear correction of the interpolation
            ! extends the profile to the row next to a wall)
            call with_periodic_images(dim, n_all, xs, .true., box, reach, xa, orig, ntot)
            allocate(fa(5, ntot))
            do k = 1, ntot
                fa(:, k) = fs(:, orig(k))
            end do
            allocate(fn(5, max(n_new, 1)))
            call interpolate_fields(dim, level_phys(lv - 1)%dx, ntot, xa, fa, n_new, xn, fn, &
                n_fb, n_empty, n_clip, clip=[.false., .false., .false., .true., .false.])
            ! level lv - 1 inside lv's region: virtual in the zone, gone deeper
            allocate(drop(p%n_owned))
            drop = .false.
            do j = 1, p%n_owned
                if (p%level(j) /= lv - 1 .or. p%kind(j) /= KIND_FLUID) cycle
                if (zones%level_at(p%x(:, j)) == lv - 1) cycle
                if (zones%in_transition(p%x(:, j), lv - 1)) then
                    p%kind(j) = KIND_VIRTUAL
                    p%id(j) = virtual_id(lv - 1, p%id(j), -1_i8)
                else
                    drop(j) = .true.
                end if
            end do
            keep = pack([(j, j = 1, p%n_owned)], .not. drop)
            call particles_gather(p, keep)
            p%n_owned = size(keep)
            p%n_total = p%n_owned
            deallocate(drop)
            ! the new level's fluid, this rank's positions
            do j = 1, n_new
                y = xn(:, j) + cfg%domain%box_lo
                y(dim + 1:) = 0.0_wp
                if (any(y(1:dim) < cfg%domain%box_lo(1:dim) .or. &
                    y(1:dim) >= cfg%domain%box_hi(1:dim))) cycle
                if (domain_owner(domain, y) /= domain%rank) cycle
                if (deepest_solid(solids, y, 0.0_wp) /= 0) cycle
                ! (real also inside the regions of finer levels: the next pass makes those
                ! levels from them, then keeps them as virtual in its zone and drops the rest;
                ! a nested level-2 band came out empty, 20 % of the mass gone, before)
                is_real = zones%level_at(y) >= lv
                if (.not. is_real .and. .not. zones%in_transition(y, lv)) cycle
                if (fn(4, j) <= 0.0_wp) cycle
                n = p%n_owned + 1
                call particles_reserve(p, n)
                call particles_clear(p, n, n)
                p%x(:, n) = y
                p%x_old(:, n) = y
                p%v(:, n) = fn(1:3, j)
                p%v_old(:, n) = fn(1:3, j)
                p%rho(n) = fn(4, j)
                p%rho_old(n) = fn(4, j)
                p%e(n) = fn(5, j)
                p%e_old(n) = fn(5, j)
                p%m(n) = fn(4, j) * level_phys(lv)%dx**dim
                p%h(n) = level_phys(lv)%kernel%h
                p%level(n) = lv
                p%parity(n) = parity(j)
                if (is_real) then
                    p%kind(n) = KIND_FLUID
                    p%id(n) = next_id + j
                else
                    p%kind(n) = KIND_VIRTUAL
                    p%id(n) = vid(j)
                end if
                p%n_owned = n
                p%n_total = n
            end do
            next_id = next_id + n_new
            ! the new level's walls, from its lattice, within reach of its fluid
            level_cfg = cfg
            level_cfg%domain%dx = cfg%domain%dx / 2.0_wp**lv
            call particles_init(lattice, 1024, dim)
            call create_lattice_particles(level_cfg, level_phys(lv), solids, domain, lattice, &
                walls_only=.true.)
            allocate(wanted(lattice%n_owned))
            do j = 1, lattice%n_owned
                wanted(j) = lattice%kind(j) /= KIND_FLUID
                if (wanted(j)) wanted(j) = zones%distance_to_level(lattice%x(:, j), lv) < &
                    zones%width + level_phys(lv)%kernel%support
                lattice%level(j) = lv
                lattice%id(j) = next_id + lattice%id(j)
            end do
            keep = pack([(j, j = 1, lattice%n_owned)], wanted)
            next_id = global_max_id(env, lattice%id, lattice%n_owned)
            call particles_append(p, lattice, keep)
            call particles_free(lattice)
            deallocate(xs, fs, ids, order, ida, fa, fn, wanted, om)
        end do
        ! the uniform state's walls where their level no longer reaches (under a fine band
        ! along a plate: a fresh start lays none there, and they were kept, 192 in a 3D
        ! channel), by the rule a fresh start lays each level's walls with
        allocate(wanted(p%n_owned))
        do j = 1, p%n_owned
            wanted(j) = p%kind(j) /= KIND_WALL
            if (.not. wanted(j)) wanted(j) = zones%distance_to_level(p%x(:, j), p%level(j)) < &
                zones%width + level_phys(p%level(j))%kernel%support
        end do
        if (.not. all(wanted)) then
            keep = pack([(j, j = 1, p%n_owned)], wanted)
            call particles_gather(p, keep)
            p%n_owned = size(keep)
            p%n_total = p%n_owned
        end if
        p%n_ghost = 0
        next_id = global_max_id(env, p%id, p%n_owned)

    contains

        !> The new points within RELAX_BODY_BAND fine spacings of a body relaxed as a
        !> remesh relaxes its set (sph_remesh_relax, RELAX_PASSES passes; the other points,
        !> their periodic images and the mirrors of both push; a move that would leave a
        !> point closer than RELAX_BODY_GAP spacings to a body, or than RELAX_PAIR_FLOOR to
        !> another point and closer than before, is not made). The fitted and filled rows
        !> are uneven, and the band around Morris' cylinder refined from a uniform state at
        !> 50 s spread its densities over 969..1029 kg/m^3 by 350 s, against 986..1016 for a
        !> fresh start; relaxed, 978..1016, and the drag at 400 s within 1 % of the fresh
        !> start's (8.68e-7 against 8.59e-7 N/m).
        subroutine relax_next_to_bodies()
            real(wp), allocatable :: yr(:, :), moves(:, :)
            integer, allocatable :: orr(:)
            integer :: pass, nr, q, nearest
            real(wp) :: dfx, dist, z(3)
            type(relax_list_t) :: kept_list
            if (.not. allocated(solids%list)) return
            if (all(solids%list(:)%shape == SOLID_PLANE)) return
            dfx = level_phys(lv)%dx
            allocate(moves(3, max(n_new, 1)))
            do pass = 1, RELAX_PASSES
                ! the points, their periodic images and the mirrors of both push
                call with_periodic_images(dim, n_new, xn, .true., box, &
                    2.0_wp * RELAX_H_FACTOR * dfx, yr, orr, nr)
                call with_mirrors(dim, solids, cfg%domain%box_lo, 2.0_wp * RELAX_H_FACTOR * dfx, &
                    yr, orr, nr)
                call relax_displacements(dim, n_new, nr, yr, dfx, moves, kept_list, &
                    RELAX_PAIR_FLOOR)
                do q = 1, n_new
                    z = xn(:, q) + cfg%domain%box_lo
                    call nearest_body(solids, z, dist, nearest)
                    if (dist > RELAX_BODY_BAND * dfx) cycle
                    z = z + moves(:, q)
                    call nearest_body(solids, z, dist, nearest)
                    if (dist < RELAX_BODY_GAP * dfx) cycle
                    xn(:, q) = xn(:, q) + moves(:, q)
                    ! (back into the box across a periodic face; a wall's box is far larger)
                    xn(1:dim, q) = modulo(xn(1:dim, q), box(1:dim))
                end do
            end do
        end subroutine relax_next_to_bodies

        !> Of the new points xn (with vid, parity) closer than MIN_GAP fine spacings to one
        !> before them (across periodic faces too), the later goes: a greedy pass in their
        !> order, which is the same on every rank and rank count. A disordered source (a
        !> uniform 3D flow remeshed three times, its closest pair 0.89 fine spacings) gave
        !> midpoints and centres 0.28 fine spacings apart, and the relaxation keeps pairs from
        !> closing in but does not part them; the refinement of a uniform run keeps none
        !> closer than this (sph_refine) either. A near-lattice's closest lie 0.6 apart:
        !> nothing goes there.
        subroutine thin_new_points()
            real(wp), allocatable :: yr(:, :)
            integer, allocatable :: orr(:)
            logical, allocatable :: kept(:)
            type(neighbour_list_t) :: near
            real(wp) :: gap
            integer :: nr, q, k, b
            if (n_new == 0) return
            gap = MIN_GAP * level_phys(lv)%dx
            call with_periodic_images(dim, n_new, xn, .true., box, gap, yr, orr, nr)
            call build_neighbour_list(yr, nr, n_new, dim, gap, near)
            allocate(kept(n_new))
            do q = 1, n_new
                kept(q) = .true.
                do k = near%start(q), near%start(q + 1) - 1
                    b = orr(near%index(k))
                    if (b >= q) cycle
                    if (.not. kept(b)) cycle
                    if (sum((yr(1:dim, q) - yr(1:dim, near%index(k)))**2) >= gap**2) cycle
                    kept(q) = .false.
                    exit
                end do
            end do
            if (all(kept)) return
            keep = pack([(q, q = 1, n_new)], kept)
            xn = xn(:, keep)
            vid = vid(keep)
            parity = parity(keep)
            n_new = size(keep)
        end subroutine thin_new_points
    end procedure refine_uniform_state
end submodule sph_uniform_refinement
