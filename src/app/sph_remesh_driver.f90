!> The parallel side of full-domain remeshing (thesis sec. 3.2, issue 10): refine, coarsen or
!> same-level remeshing of every fluid particle of a particle set spread over the ranks. The
!> algorithms are the serial ones of src/remesh (no MPI there): sph_remesh_positions (with
!> sph_refine and sph_coarsen) for the new positions and the kept set, sph_remesh_interp for
!> the conservative transfer.
!>
!> Layout. The new POSITIONS are made on rank 0 from every fluid particle's position and id
!> (gathered there, 32 bytes a particle), as ONE set with the periodic box; the FIELDS are
!> handed on by every rank for its part of the domain (the transfer, below), so each rank
!> ends with the new fluid particles in its part as owned particles; the caller
!> rebalances (domain_partition, migrate_particles) and rebuilds the halo and the neighbours.
!> Why the positions on one rank:
!>  - coarsen_select tags in the order of a hash of the ids (Jones-Plassmann priorities): the
!>    tag of a particle depends on a chain of earlier-visited neighbours that no fixed halo
!>    width bounds, so a halo-local call gives kept sets that differ with the rank count near
!>    rank boundaries; doing it locally needs a parallel tagging loop (tag what has no
!>    untagged earlier neighbour, exchange tags, repeat) inside sph_coarsen; sph_refine's
!>    thinning and gap filling are greedy passes in key order of the same kind;
!>  - the kept set and the new ids are then identical, bit for bit, on any number of ranks.
!> The price: rank 0 holds every fluid particle's position and every new position with its
!> key (about 70 bytes per new particle) during a remesh.
!>
!> Transfer (sph_remesh_interp's stages). The old fluid particles are spread by an ORB
!> decomposition of their own (domain_partition over their positions, migrate_particles),
!> the new positions sent by rank 0 to the ranks owning them there, and each rank takes as
!> ghosts the new particles within PAIR_REACH h (the support, 2 h per axis) of its part,
!> those with mirrors farther by the reach of the mirrors (ghost_reaches; periodic images
!> included, sph_halo); h is the coarser spacing. When some old particle has no new one in
!> its support, all within NEW_REACH h (plus that of the mirrors) are taken and the
!> accumulation repeated: its nearest may lie up to 4 h away. (With every ghost within the
!> full reach a 3D refinement of 1.25 x 10^5 particles on 2 ranks peaked at 3.3 GB, 2.8
!> times a run of the refined set, its transfer 3.7 s; now 1.4 GB and 1.4 s.) Each rank
!> accumulates, from the old particles it owns, into its new particles and their ghosts
!> (transfer_accumulate: an old particle's weights are normalised over every new particle
!> within 2 h, all of which it sees, and an isolated one hands everything to the nearest
!> within 4 h); the ghosts' columns are added to their owners' (halo_reverse_sum), a new
!> particle whose column received nothing is dropped (transfer_unreached: no pair reached it,
!> so no total changes; the column is exactly zero on any rank count), and each rank
!> finishes its own new particles (transfer_finish). Every old-new pair within the
!> support is counted once, as by one rank over the periodic box; sums come in another order
!> on another rank count (or another set of ghosts), so the fields agree across rank counts
!> to round-off (the positions and ids exactly). Momentum: one uniform correction over all
!> new particles with the old total (global sums).
!>
!> Ids: refined particles get fresh ids from their refinement keys (sph_global_ids, base =
!> the largest id of any particle, walls included); kept particles of a coarsening keep their
!> ids. Same level = refine, then coarsen the refined set (its kept particles carry the fresh
!> ids), with ONE transfer from the old particles to the final ones; the particles of narrow
!> gaps (two solids facing each other closer than NARROW_GAP spacings together) stay as they
!> were, with their ids (set_aside_gaps), and the transfer hands them on like the others.
!>
!> The new set's rules (next to solids, the coarsened rows at plane walls, narrow gaps, the
!> relaxation) are sph_remesh_positions', serial, run on rank 0.
!>
!> Next to solids (optional argument solids): refine_positions applies its wall rule, and the
!> transfer is handed the mirror images (across each solid surface, and at a box's corner
!> across both or all three walls: with_mirrors) of the old and new
!> particles within MIRROR_REACH = 3 h of it, the old ones with their mass, density and
!> energy and the velocity odd about the solid's (2 v_s - v, with_mirrors: a no-slip wall's
!> shear goes on through it). Each rank mirrors the old particles it owns, and its new
!> particles with their ghosts, which reach as far as the mirrors of both can bring a pair
!> within 2 h (ghost_reaches). A new particle next to a wall then
!> sees old particles on both sides, as in the interior, and takes a mass that matches its
!> volume (without mirrors the first row got 20 % too little: only the old row behind it
!> reaches it). The mirrors' shares are dropped; as for a plane wall the exchange with the
!> mirrors is symmetric only to round-off (and for a curved one to O(dx/R)), the new masses
!> are scaled by (old total mass) / (new total mass), and momentum gets the uniform
!> correction above. The densities are not scaled: they are interpolated, the mirrors
!> carrying their particles' densities. (Scaling the densities too, when they were the
!> handed mass over the handed volume, raised every fluid density by that factor: +0.7-0.9 %
!> next to a 3D sphere or cylinder, +23 % for a coarsening around a box body 2 new spacings
!> across; the fluid at rest then flowed.)
!>
!> Density: interpolated by sph_remesh_interp's narrow first-order interpolant (a uniform or
!> linear density reproduced, a weakly compressible flow's pressure peaks next to bodies
!> kept); masses follow the volumes handed on, and the caller adjusts them to the kernel
!> sums where the new set was relaxed (sph_stepper_remesh's consistent_masses). Energy: the
!> handed-on m e divided by the new mass. Pressure, rates and start-of-step copies are left to
!> the caller (update_pressure; the next step saves its start).
module sph_remesh_driver
    use mpi_f08, only: MPI_Gather, MPI_Gatherv, MPI_Scatter, MPI_Scatterv, MPI_INTEGER, &
        MPI_Wtime
    use sph_kinds, only: wp, i8
    use sph_errors, only: check_mpi
    use sph_accurate_sums, only: accurate_add, accurate_sum
    use sph_mpi_env, only: mpi_env_t, mpi_wp, mpi_i8, global_sum, global_max, agreed_status, &
        broadcast_text
    use sph_particles, only: particles_t, particles_init, particles_reserve, particles_clear, &
        particles_append, particles_add_fields_of, particles_gather, particles_swap, KIND_FLUID
    use sph_domain, only: domain_t, domain_create, domain_partition, domain_owner, &
        migrate_particles
    use sph_halo, only: halo_t, halo_setup, halo_build, halo_reverse_sum
    use sph_solids, only: solids_t
    use sph_remesh_images, only: relative_to, mirror_shifts, with_mirrors
    use sph_remesh_positions, only: new_set_t, new_set_init, set_aside_gaps, new_positions, &
        finish_same_level, into_id_order, REMESH_NONE, REMESH_REFINE, REMESH_COARSEN, &
        REMESH_SAME, NARROW_GAP, snapped_to_grid
    use sph_remesh_interp, only: transfer_accumulate, transfer_finish, transfer_rows, &
        transfer_unreached
    use sph_global_ids, only: assign_global_ids, global_max_id
    implicit none
    private
    public :: remesh_report_t, remesh_fluid, remesh_mode_code, remesh_spacing_factor
    public :: fluid_mass_momentum, restore_momentum, restore_energy, accurate_sum
    public :: REMESH_NONE, REMESH_REFINE, REMESH_COARSEN, REMESH_SAME, NARROW_GAP


    !> mirror reach of the transfer next to solids, in units of h (see the module header)
    real(wp), parameter :: MIRROR_REACH = 3.0_wp
    !> how far (in h) from its part of the domain a rank needs the new particles in the
    !> transfer: an isolated old particle's nearest within 4 h; next to solids the new
    !> particles whose mirrors lie within 2 h of an old one (module header)
    real(wp), parameter :: NEW_REACH = 4.0_wp
    !> the reach (in h) of the new particles that no mirror involves, when no old particle
    !> is isolated: M4's support, 2 h per axis, and a margin for round-off
    real(wp), parameter :: PAIR_REACH = 2.0_wp * (1.0_wp + 1.0e-6_wp)

    !> What a remesh did (global values, the same on every rank).
    type :: remesh_report_t
        integer(i8) :: n_before = 0, n_after = 0    !< fluid particles
        real(wp) :: mass_before = 0.0_wp, mass_after = 0.0_wp
        real(wp) :: momentum_before(3) = 0.0_wp, momentum_after(3) = 0.0_wp
        !> the fluid's internal energy, sum m e
        real(wp) :: energy_before = 0.0_wp, energy_after = 0.0_wp
        !> wall seconds (slowest rank) of the new positions (gathered, made and ordered on
        !> rank 0) and of the transfer of the fields (spread over the ranks)
        real(wp) :: seconds_positions = 0.0_wp, seconds_transfer = 0.0_wp
        integer :: n_irregular = 0                   !< refinement: cells without a centre
        integer :: n_mass_fallback = 0, n_velocity_fallback = 0   !< transfer fallbacks
        integer :: n_density_fallback = 0
        !> of the mass fallbacks, old particles with no new one in their support (each handed
        !> to its nearest, the transfer's ghosts then taken at the full reach)
        integer :: n_isolated = 0
        !> new particles dropped because no old particle had them within its support
        integer :: n_unreached = 0
        integer :: relax_passes = 0                  !< relaxation passes made
        !> same level: fluid particles left as they were in narrow gaps (module header)
        integer :: n_in_gaps = 0
        !> set by the caller (sph_stepper_remesh's consistent_masses): passes of the fluid
        !> masses' adjustment to the kernel sums, and the largest |kernel sum / handed-on
        !> density - 1| of a fluid particle before and after it (mass_passes < 0: none)
        integer :: mass_passes = -1
        real(wp) :: mismatch_before = 0.0_wp, mismatch_after = 0.0_wp
    end type remesh_report_t

contains

    !> REMESH_* for 'none', 'refine', 'coarsen', 'same'; -1 otherwise.
    pure integer function remesh_mode_code(name) result(code)
        character(len=*), intent(in) :: name
        select case (trim(adjustl(name)))
        case ('none')
            code = REMESH_NONE
        case ('refine')
            code = REMESH_REFINE
        case ('coarsen')
            code = REMESH_COARSEN
        case ('same')
            code = REMESH_SAME
        case default
            code = -1
        end select
    end function remesh_mode_code

    !> New spacing / old spacing of a mode.
    pure real(wp) function remesh_spacing_factor(mode) result(f)
        integer, intent(in) :: mode
        select case (mode)
        case (REMESH_REFINE)
            f = 0.5_wp
        case (REMESH_COARSEN)
            f = 2.0_wp
        case default
            f = 1.0_wp
        end select
    end function remesh_spacing_factor

    !> Remesh the owned fluid particles of p (collective). dx: their spacing; box_lo/box_hi,
    !> periodic: the domain; h_new: smoothing length given to the new particles. The fluid
    !> may be spread over the ranks in any way. On return every rank has the new fluid
    !> particles of its part of the transfer's decomposition (module header), in id order,
    !> and after them its particles that are not fluid, unchanged and in their order; ghosts
    !> and mirrors are gone (n_total = n_owned). The caller rebalances and rebuilds.
    !> stat /= 0 (the same on every rank) when the algorithms refuse the set; p then holds the
    !> particles it had (the fluid perhaps on other ranks). solids: the walls and bodies
    !> (absolute coordinates), for sph_refine's wall rule and the mirrored transfer (module
    !> header); without them the walls are ignored. A new point that no old particle reaches
    !> (none has it within its support) is dropped and counted (report%n_unreached).
    subroutine remesh_fluid(env, mode, dim, dx, box_lo, box_hi, periodic, h_new, p, report, &
            stat, errmsg, solids, all_ghosts)
        type(mpi_env_t), intent(in) :: env
        integer, intent(in) :: mode, dim
        real(wp), intent(in) :: dx, box_lo(3), box_hi(3), h_new
        logical, intent(in) :: periodic(3)
        type(particles_t), intent(inout) :: p
        type(remesh_report_t), intent(out) :: report
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: errmsg
        type(solids_t), intent(in), optional :: solids
        !> every new particle within the full reach a ghost from the start, as when an old
        !> particle is isolated (for tests: the result agrees with the default's to round-off)
        logical, intent(in), optional :: all_ghosts
        type(new_set_t) :: set
        integer :: my_stat, i
        integer(i8) :: base
        real(wp) :: t0, t_transfer, ghost_ratio
        character(len=:), allocatable :: message
        logical, allocatable :: fluid(:)

        t0 = MPI_Wtime()
        stat = 0
        errmsg = ''
        message = ''
        ghost_ratio = real(max(p%n_total, 1), wp) / real(max(p%n_owned, 1), wp)
        ! totals before, over all ranks
        fluid = p%kind(1:p%n_owned) == KIND_FLUID
        ! the old positions on a grid, so that every decision below is the same on any rank
        ! count (sph_remesh_positions' snapped_to_grid)
        do i = 1, p%n_owned
            if (fluid(i)) p%x(:, i) = snapped_to_grid(p%x(:, i), dim, dx, box_lo, box_hi, &
                periodic)
        end do
        report%n_before = global_sum(env, int(count(fluid), i8))
        call fluid_mass_momentum(env, p, report%mass_before, report%momentum_before, &
            report%energy_before)
        base = global_max_id(env, p%id, p%n_owned)

        call gather_positions(env, p, fluid, set%n, set%x, set%ids)
        call new_set_init(set, mode, dim, dx, box_lo, box_hi, periodic, solids)
        ! same level: the particles of narrow gaps last in set%x, left out of the construction
        if (env%rank == 0 .and. mode == REMESH_SAME) call set_aside_gaps(set)
        report%n_in_gaps = int(global_max(env, int(set%n - set%n_src, i8)))
        my_stat = 0
        if (env%rank == 0) call new_positions(set, my_stat, message)
        if (refused()) return
        ! fresh ids for refined particles (collective; only rank 0 has keys)
        if (mode == REMESH_REFINE .or. mode == REMESH_SAME) call fresh_ids()
        if (env%rank == 0 .and. mode == REMESH_SAME) call finish_same_level(set, my_stat, message)
        ! the new set in id order: its particles then lie about in space order (the ids follow
        ! the keys, the keys the old ids), for the transfer and for the caller's id order
        if (env%rank == 0 .and. my_stat == 0) call into_id_order(set%xn, set%idn, set%n_new)
        if (refused()) return
        ! rank 0 made the set: every rank reports its figures
        report%n_irregular = int(global_max(env, int(set%n_irregular, i8)))
        report%relax_passes = int(global_max(env, int(set%relax_passes, i8)))
        t_transfer = MPI_Wtime()
        report%seconds_positions = global_max(env, t_transfer - t0)
        ! the new fluid particles in p (each rank those of its part), the others after them
        call spread_transfer(my_stat, message)
        if (refused()) return
        report%seconds_transfer = global_max(env, MPI_Wtime() - t_transfer)

        report%n_after = global_sum(env, int(count(p%kind(1:p%n_owned) == KIND_FLUID), i8))
        call fluid_mass_momentum(env, p, report%mass_after, report%momentum_after, &
            report%energy_after)

    contains

        !> Whether some rank's work failed (collective): then stat and errmsg say so on every
        !> rank, with the message of the lowest rank that failed.
        logical function refused()
            integer :: reporter
            stat = agreed_status(env, my_stat)
            refused = stat /= 0
            if (.not. refused) return
            reporter = int(-global_max(env, int(merge(-env%rank, -huge(0), my_stat /= 0), i8)))
            call broadcast_text(env, message, reporter)
            ! (the caller names the stage: 'error in remesh: ...')
            errmsg = message
        end function refused


        !> ids for the keys in idn (all ranks take part; rank 0 holds the keys).
        subroutine fresh_ids()
            integer(i8), allocatable :: keys(:, :), new_ids(:)
            integer(i8) :: next_base
            allocate(keys(2, max(set%n_new, 1)), new_ids(max(set%n_new, 1)))
            if (set%n_new > 0) keys(:, 1:set%n_new) = reshape(set%idn, [2, set%n_new])
            call assign_global_ids(env, keys, set%n_new, base, new_ids, next_base)
            deallocate(set%idn)
            allocate(set%idn(set%n_new))
            set%idn = new_ids(1:set%n_new)
        end subroutine fresh_ids

        !> The fields of the new particles (module header, "Transfer"), collective. On return
        !> p holds this rank's new fluid particles (absolute positions, in id order, ghosts
        !> gone) and after them its particles that are not fluid, in their order. st /= 0 on
        !> the ranks where the transfer failed; p then holds the same particles as before (the
        !> fluid spread over the ranks as the transfer's decomposition has it).
        subroutine spread_transfer(st, msg)
            integer, intent(out) :: st
            character(len=:), allocatable, intent(inout) :: msg
            type(domain_t) :: parts
            type(particles_t) :: old, others
            type(halo_t) :: halo
            real(wp), allocatable :: xo(:, :), xs(:, :), acc(:, :), reach_new(:), vo(:, :)
            integer, allocatable :: orig_o(:), orig_n(:), keep(:)
            integer :: no, ns, i, nmf, nvf, nrf, own, n_isolated, n_unreached
            logical :: ok, full_reach
            real(wp) :: h, reach, scale, mass_new
            character(len=400) :: text
            st = 0
            text = ''
            h = max(dx, dx * remesh_spacing_factor(mode))
            ! the particles that are not fluid aside (with p's run-time fields); the old fluid
            ! is p's own storage, compacted and handed to `old` (a copy of 10^5 particles cost
            ! a fifth of a coarsening), in an ORB decomposition of its own; p starts afresh
            call particles_init(others, max(count(.not. fluid), 1), dim)
            call particles_add_fields_of(others, p)
            call particles_append(others, p, pack([(i, i = 1, size(fluid))], .not. fluid))
            if (.not. all(fluid)) call particles_gather(p, pack([(i, i = 1, size(fluid))], &
                fluid))
            p%n_owned = count(fluid)
            p%n_ghost = 0
            p%n_total = p%n_owned
            call particles_init(old, 1, dim)
            call particles_add_fields_of(old, p)
            call particles_swap(p, old)
            call domain_create(parts, env, dim, box_lo, box_hi, periodic)
            call domain_partition(parts, env, old%x, old%n_owned)
            call migrate_particles(parts, env, old)
            ! p: the new particles this rank owns there, then those within reach as ghosts
            call scatter_new(parts)
            ! old positions relative to box_lo, the mirrors across the solids after them
            no = old%n_owned
            call relative_to(box_lo, old%x, no, xo, orig_o)
            vo = old%v(:, 1:max(no, 1))
            if (present(solids)) &
                call with_mirrors(dim, solids, box_lo, h * MIRROR_REACH, xo, orig_o, no, vo)
            xo(dim + 1:, :) = 0.0_wp
            reach_new = ghost_reaches(h, global_max(env, max(0.0_wp, &
                maxval(mirror_shifts(xo, orig_o, old%n_owned, no)))))
            ! the full reach: an isolated old point's nearest new one within NEW_REACH h
            reach = global_max(env, max(PAIR_REACH * h, maxval(reach_new))) + &
                (NEW_REACH - PAIR_REACH) * h
            call halo_setup(halo, parts, reach)
            ! sums from the old particles this rank owns (the ghosts' columns to their owners
            ! below): first with the ghosts that pairs within the support need (module
            ! header), again with all within the full reach when some old particle is isolated
            full_reach = .false.
            if (present(all_ghosts)) full_reach = all_ghosts
            do
                if (full_reach) then
                    call halo_build(halo, parts, env, p)
                else
                    call halo_build(halo, parts, env, p, reach_new)
                end if
                ns = p%n_total
                call relative_to(box_lo, p%x, ns, xs, orig_n)
                if (present(solids)) &
                    call with_mirrors(dim, solids, box_lo, h * MIRROR_REACH, xs, orig_n, ns)
                xs(dim + 1:, :) = 0.0_wp
                if (allocated(acc)) deallocate(acc)
                allocate(acc(transfer_rows(dim), max(ns, 1)))
                call transfer_accumulate(dim, h, no, xo, old%m(orig_o(1:no)), &
                    vo(:, 1:no), old%rho(orig_o(1:no)), old%e(orig_o(1:no)), ns, &
                    xs, acc, st, text, nmf, n_isolated, p%id(orig_n(1:ns)))
                if (full_reach .or. global_sum(env, int(n_isolated, i8)) == 0) exit
                full_reach = .true.
            end do
            ! a failure anywhere stops every rank (the caller's refused() agrees on it); p is
            ! then put back: this rank's old fluid in the transfer's decomposition, its others
            ok = agreed_status(env, st) == 0
            if (ok) then
                call halo_reverse_sum(halo, env, p%n_owned, acc)
                own = p%n_owned
                ! points the construction put where no fluid is go (transfer_unreached)
                keep = pack([(i, i = 1, own)], .not. transfer_unreached(own, acc))
                n_unreached = own - size(keep)
                if (n_unreached > 0) then
                    call particles_gather(p, keep)
                    acc(:, 1:size(keep)) = acc(:, keep)
                    own = size(keep)
                    p%n_owned = own
                end if
                p%n_ghost = 0
                p%n_total = own
                call transfer_finish(dim, own, acc, p%m, p%v, p%rho, p%e, st, text, nvf, nrf)
                ok = agreed_status(env, st) == 0
            end if
            if (.not. ok) then
                msg = trim(text)
                call particles_swap(p, old)
                p%n_ghost = 0
                p%n_total = p%n_owned
                call particles_append(p, others, [(i, i = 1, others%n_owned)])
                return
            end if
            report%n_mass_fallback = int(global_sum(env, int(nmf, i8)))
            report%n_velocity_fallback = int(global_sum(env, int(nvf, i8)))
            report%n_density_fallback = int(global_sum(env, int(nrf, i8)))
            report%n_isolated = int(global_sum(env, int(n_isolated, i8)))
            report%n_unreached = int(global_sum(env, int(n_unreached, i8)))
            mass_new = global_sum(env, accurate_sum(p%m(1:own)))
            if (present(solids)) then
                ! the mirrors' exchange is symmetric only for plane walls: restore the total
                ! mass exactly; the volumes grow alike, the densities stay (module header)
                scale = report%mass_before / mass_new
                p%m(1:own) = p%m(1:own) * scale
                mass_new = global_sum(env, accurate_sum(p%m(1:own)))
            end if
            p%v(dim + 1:, 1:own) = 0.0_wp
            ! one uniform correction over all new particles: momentum as before
            call restore_momentum(env, dim, p, [(.true., i = 1, own)], report%momentum_before, &
                mass_new)
            ! the mirrors take energy as they take mass, in proportion to the energy where
            ! they are: the masses' restoration restores it only where e is even (a same-level
            ! remesh of a cylinder flow heated at the body lost 1.9e-3 of sum m e)
            if (present(solids)) call restore_energy(env, p, [(.true., i = 1, own)], &
                report%energy_before)
            do i = 1, own
                p%h(i) = h_new
                p%x_old(:, i) = p%x(:, i)
                p%v_old(:, i) = p%v(:, i)
                p%rho_old(i) = p%rho(i)
                p%e_old(i) = p%e(i)
            end do
            call particles_append(p, others, [(i, i = 1, others%n_owned)])
            ! room for the ghosts of the new set too (as many per owned particle as before):
            ! the caller's halo build would otherwise grow every field again, copying them all
            call particles_reserve(p, int(real(p%n_owned, wp) * ghost_ratio))
        end subroutine spread_transfer

        !> Per new particle this rank owns, how far from a part of the transfer's
        !> decomposition it is needed there when no old particle is isolated: the support
        !> (2 h, per axis, as the halo measures) and a margin for round-off; with mirrors, the
        !> support plus the farthest any old point's mirror lies from it (old_shift) plus the
        !> farthest this particle's own mirrors lie from it. An old point (particle or mirror)
        !> is handled by the rank owning its particle, and its weights are normalised over
        !> every new point (particle or mirror) within 2 h of it: the mirrors of old and new
        !> pair too (their shares are dropped, their weights count), and around a body only
        !> a few spacings across its mirrors lie far closer together than the particles they
        !> mirror. With a fixed 2 h + 2 MIRROR_REACH h a rank missed some of those new
        !> particles, and the masses around Morris-size bodies differed between rank counts
        !> (7e-6 relative next to a 3D cylinder on 3 ranks, 3e-2 next to a box body). (The
        !> full reach took each rank's ghosts up to 2 h + 6 h away: in 3D on 2 ranks about
        !> twice as many ghosts as owned new particles; now only next to solids.)
        function ghost_reaches(hh, old_shift) result(r)
            real(wp), intent(in) :: hh          !< the transfer's spacing h
            real(wp), intent(in) :: old_shift   !< farthest old mirror from its particle
            real(wp), allocatable :: r(:)
            real(wp), allocatable :: y(:, :)
            integer, allocatable :: orig(:)
            integer :: ny
            allocate(r(p%n_owned))
            r = PAIR_REACH * hh
            if (.not. present(solids)) return
            if (.not. allocated(solids%list)) return
            call relative_to(box_lo, p%x, p%n_owned, y, orig)
            ny = p%n_owned
            call with_mirrors(dim, solids, box_lo, hh * MIRROR_REACH, y, orig, ny)
            r = r + old_shift
            r = r + mirror_shifts(y, orig, p%n_owned, ny)
        end function ghost_reaches


        !> Rank 0 sends each new position (xn, relative to box_lo) and id (idn), in their
        !> order, to the rank owning it in `parts`; p (emptied) takes this rank's, with
        !> absolute positions, and room for their ghosts.
        subroutine scatter_new(parts)
            type(domain_t), intent(in) :: parts
            integer, allocatable :: owner(:), counts(:), displs(:), fill(:), order(:)
            real(wp), allocatable :: sx(:, :), rx(:, :)
            integer(i8), allocatable :: sid(:), rid(:)
            integer :: k, r, n_mine, ierr
            allocate(counts(0:env%nranks - 1), displs(0:env%nranks - 1))
            counts = 0
            displs = 0
            if (env%rank == 0) then
                allocate(owner(set%n_new), order(set%n_new), fill(0:env%nranks - 1))
                do k = 1, set%n_new
                    owner(k) = domain_owner(parts, set%xn(:, k) + box_lo)
                    counts(owner(k)) = counts(owner(k)) + 1
                end do
                do r = 1, env%nranks - 1
                    displs(r) = displs(r - 1) + counts(r - 1)
                end do
                ! grouped by owner, in id order within each
                fill = displs
                do k = 1, set%n_new
                    fill(owner(k)) = fill(owner(k)) + 1
                    order(fill(owner(k))) = k
                end do
                allocate(sx(3, max(set%n_new, 1)), sid(max(set%n_new, 1)))
                do k = 1, set%n_new
                    sx(:, k) = set%xn(:, order(k))
                    sid(k) = set%idn(order(k))
                end do
            else
                allocate(sx(3, 1), sid(1))
            end if
            call MPI_Scatter(counts, 1, MPI_INTEGER, n_mine, 1, MPI_INTEGER, 0, env%comm, ierr)
            call check_mpi(ierr, 'remesh scatter counts')
            allocate(rx(3, max(n_mine, 1)), rid(max(n_mine, 1)))
            call MPI_Scatterv(sx, 3 * counts, 3 * displs, mpi_wp, rx, 3 * n_mine, mpi_wp, 0, &
                env%comm, ierr)
            call check_mpi(ierr, 'remesh scatter positions')
            call MPI_Scatterv(sid, counts, displs, mpi_i8, rid, n_mine, mpi_i8, 0, env%comm, &
                ierr)
            call check_mpi(ierr, 'remesh scatter ids')
            ! room for the ghosts too, a band of the reach around the part (a guess; the halo
            ! grows p if it needs more); slots that do not come zeroed from a growth are cleared
            p%n_owned = 0
            p%n_ghost = 0
            p%n_total = 0
            if (p%capacity >= n_mine + n_mine / 8 + 256) then
                if (n_mine > 0) call particles_clear(p, 1, n_mine)
            else
                call particles_reserve(p, n_mine + n_mine / 8 + 256)
            end if
            do k = 1, n_mine
                p%x(:, k) = rx(:, k) + box_lo
                p%x(dim + 1:, k) = 0.0_wp
                p%id(k) = rid(k)
                p%kind(k) = KIND_FLUID
            end do
            p%n_owned = n_mine
            p%n_total = n_mine
        end subroutine scatter_new

        !> Rank 0 receives every rank's fluid positions (relative to box_lo, in the box on
        !> periodic axes) and ids, in rank order.
        subroutine gather_positions(envg, q, sel, ntot, xg, idg)
            type(mpi_env_t), intent(in) :: envg
            type(particles_t), intent(in) :: q
            logical, intent(in) :: sel(:)
            integer, intent(out) :: ntot
            real(wp), allocatable, intent(out) :: xg(:, :)
            integer(i8), allocatable, intent(out) :: idg(:)
            integer :: nloc, ierr, r, a, j
            integer, allocatable :: counts(:), displs(:), idx(:)
            real(wp), allocatable :: sbuf(:, :)
            integer(i8), allocatable :: sid(:)
            idx = pack([(j, j = 1, q%n_owned)], sel)
            nloc = size(idx)
            allocate(sbuf(3, max(nloc, 1)), sid(max(nloc, 1)))
            do j = 1, nloc
                sbuf(:, j) = q%x(:, idx(j)) - box_lo
                do a = 1, dim
                    ! the particle's periodic image in [0, L)
                    if (periodic(a)) sbuf(a, j) = sbuf(a, j) - (box_hi(a) - box_lo(a)) * &
                        floor(sbuf(a, j) / (box_hi(a) - box_lo(a)))
                end do
                sbuf(dim + 1:3, j) = 0.0_wp
                sid(j) = q%id(idx(j))
            end do
            allocate(counts(envg%nranks), displs(envg%nranks))
            call MPI_Gather(nloc, 1, MPI_INTEGER, counts, 1, MPI_INTEGER, 0, envg%comm, ierr)
            call check_mpi(ierr, 'remesh gather counts')
            ntot = 0
            if (envg%rank == 0) ntot = sum(counts)
            displs = 0
            do r = 2, envg%nranks
                displs(r) = displs(r - 1) + counts(r - 1)
            end do
            allocate(xg(3, max(ntot, 1)), idg(max(ntot, 1)))
            call MPI_Gatherv(sbuf, 3 * nloc, mpi_wp, xg, 3 * counts, 3 * displs, mpi_wp, 0, &
                envg%comm, ierr)
            call check_mpi(ierr, 'remesh gather positions')
            call MPI_Gatherv(sid, nloc, mpi_i8, idg, counts, displs, mpi_i8, 0, envg%comm, ierr)
            call check_mpi(ierr, 'remesh gather ids')
        end subroutine gather_positions
    end subroutine remesh_fluid

    !> Local mass and momentum of the selected owned particles: (m, m vx, m vy, m vz).
    !> Total mass and momentum of the owned fluid particles of p over all ranks (collective).
    subroutine fluid_mass_momentum(env, p, mass, momentum, energy)
        type(mpi_env_t), intent(in) :: env
        type(particles_t), intent(in) :: p
        real(wp), intent(out) :: mass, momentum(3)
        real(wp), intent(out), optional :: energy   !< sum m e
        real(wp) :: totals(5)
        call fluid_totals(p, p%kind(1:p%n_owned) == KIND_FLUID, totals)
        totals = global_sum(env, totals)
        mass = totals(1)
        momentum = totals(2:4)
        if (present(energy)) energy = totals(5)
    end subroutine fluid_mass_momentum

    !> Mass, momentum and energy (sum m e) of the particles sel of p, summed with
    !> compensation (accurate_add):
    !> summed one by one, 10^6 equal masses came out 1.7e-11 (3D) and 3.8e-12 (2D) off their
    !> total, and a remesh that conserves to 1e-15 was logged as changing the mass by that.
    subroutine fluid_totals(p, sel, totals)
        type(particles_t), intent(in) :: p
        logical, intent(in) :: sel(:)
        real(wp), intent(out) :: totals(5)
        real(wp) :: lost(5)
        integer :: i, a
        totals = 0.0_wp
        lost = 0.0_wp
        do i = 1, size(sel)
            if (.not. sel(i)) cycle
            call accurate_add(totals(1), lost(1), p%m(i))
            do a = 1, 3
                call accurate_add(totals(1 + a), lost(1 + a), p%m(i) * p%v(a, i))
            end do
            call accurate_add(totals(5), lost(5), p%m(i) * p%e(i))
        end do
        totals = totals + lost
    end subroutine fluid_totals

    !> One uniform velocity added to the particles sel(1:size(sel)) of p (collective) so
    !> that their total momentum becomes `momentum`, their total mass being `mass`: a
    !> remesh's momentum correction (module header).
    subroutine restore_momentum(env, dim, p, sel, momentum, mass)
        type(mpi_env_t), intent(in) :: env
        integer, intent(in) :: dim
        type(particles_t), intent(inout) :: p
        logical, intent(in) :: sel(:)
        real(wp), intent(in) :: momentum(3), mass
        real(wp) :: total(3), lost(3), dv(3)
        integer :: i, a
        total = 0.0_wp
        lost = 0.0_wp
        do i = 1, size(sel)
            if (.not. sel(i)) cycle
            do a = 1, dim
                call accurate_add(total(a), lost(a), p%m(i) * p%v(a, i))
            end do
        end do
        total = global_sum(env, total + lost)
        dv = 0.0_wp
        if (mass > 0.0_wp) dv(1:dim) = (momentum(1:dim) - total(1:dim)) / mass
        do i = 1, size(sel)
            if (.not. sel(i)) cycle
            p%v(1:dim, i) = p%v(1:dim, i) + dv(1:dim)
        end do
    end subroutine restore_momentum

    !> Shift the specific energies e of the particles sel of p (every rank's share) by one
    !> uniform amount so that their sum m e is `energy` again, after a change of their masses
    !> that did not follow e (the mirrors' share, the kernel sums' masses): as momentum is
    !> restored by one uniform velocity. (A uniform factor, energy / sum m e, as before, was
    !> ill-conditioned where e has both signs: a same-level remesh of a flow with e = sin(2 pi
    !> x / L) + 0.01 turned sum m e from 0.110 to -2.05 J, the factor being negative and so
    !> not applied, and where applied it scaled every e by 2.6, 6.5 or 1e-14.)
    subroutine restore_energy(env, p, sel, energy)
        type(mpi_env_t), intent(in) :: env
        type(particles_t), intent(inout) :: p
        logical, intent(in) :: sel(:)
        real(wp), intent(in) :: energy
        real(wp) :: total(2), lost(2), shift
        integer :: i
        total = 0.0_wp
        lost = 0.0_wp
        do i = 1, size(sel)
            if (.not. sel(i)) cycle
            call accurate_add(total(1), lost(1), p%m(i) * p%e(i))
            call accurate_add(total(2), lost(2), p%m(i))
        end do
        total = global_sum(env, total + lost)
        if (total(2) <= 0.0_wp) return
        shift = (energy - total(1)) / total(2)
        do i = 1, size(sel)
            if (sel(i)) p%e(i) = p%e(i) + shift
        end do
    end subroutine restore_energy
end module sph_remesh_driver
