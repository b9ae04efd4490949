!> The parallel side of full-domain remeshing (thesis sec. 3.2, issue 10): refine, coarsen or
!> same-level remeshing of every fluid particle of a particle set spread over the ranks. The
!> algorithms are the serial ones of src/remesh (no MPI there): sph_refine for the new
!> positions, sph_coarsen for the kept set, sph_remesh_interp for the conservative transfer.
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
!> within 4 h); the ghosts' columns are added to their owners' (halo_reverse_sum), and each
!> rank finishes its own new particles (transfer_finish). Every old-new pair within the
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
!> Coarsening: the candidates closer than WALL_GAP new spacings to a body are dropped (the
!> fine first row lies 0.25 new spacings off: kept, it let a particle into Morris' cylinder
!> within 900 s of the coarse run), the kept set follows the flow's spacing (sph_coarsen's
!> follow_spacing), next to plane walls it is moved so that its first row lies half a new
!> spacing off each (place_plane_rows: every other fine row lies a quarter of a new spacing
!> off that, so the first coarse row lay 0.25 or 0.75 new spacings off a wall, and with the
!> 0.25 row dropped one wall had a gap of 1.25 spacings; the coarsened Poiseuille channel
!> continued at 2.52 times the error of the run made coarse throughout, now 0.81 times), and
!> the set is relaxed as the same-level one is (below): the transfer
!> gives each particle the mass of its volume, and the kept set's uneven volumes (masses
!> 17-23 % apart, up to 2.3 times the mean) cost the coarse cylinder flow 4-11 % of its mean
!> velocity; relaxed, 5-8 % apart and within 0.4 % of the coarse run's (doc/validation.md).
!> Not when the selection found no disordered particle (sph_coarsen) and there is no body:
!> the kept set of a near-lattice is its sublattice (of a channel, placed by
!> place_plane_rows), whose volumes are even; the relaxation moved it by less than 1 % of a
!> spacing, and its one pass was a tenth of the coarsening of 10^5 particles (the L/40
!> channel's coarse set is now the lattice exactly: mean ratio 2, CoV 0 against 1.994 and
!> 0.003; continued, 0.403 % against 0.405 %).
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
    use sph_mpi_env, only: mpi_env_t, mpi_wp, mpi_i8, global_sum, global_max, agreed_status, &
        broadcast_text
    use sph_particles, only: particles_t, particles_init, particles_reserve, particles_clear, &
        particles_append, particles_add_fields_of, particles_gather, particles_swap, KIND_FLUID
    use sph_domain, only: domain_t, domain_create, domain_partition, domain_owner, &
        migrate_particles
    use sph_halo, only: halo_t, halo_setup, halo_build, halo_reverse_sum
    use sph_refine, only: refine_positions, WALL_BAND
    use sph_solids, only: solids_t, solid_distance, solid_normal, facing_plane, SOLID_PLANE
    use sph_cell_list, only: neighbour_list_t, build_neighbour_list
    use sph_remesh_images, only: relative_to, mirror_shifts, with_images, &
        with_mirrors_and_images, with_mirrors
    use sph_remesh_relax, only: relax_displacements, relax_list_t, RELAX_PASSES, RELAX_H_FACTOR, &
        RELAX_TOLERANCE
    use sph_coarsen, only: coarsen_select
    use sph_remesh_interp, only: transfer_accumulate, transfer_finish, transfer_rows, &
        transfer_unreached
    use sph_global_ids, only: assign_global_ids, global_max_id, id_order
    implicit none
    private
    public :: remesh_report_t, remesh_fluid, remesh_mode_code, remesh_spacing_factor
    public :: fluid_mass_momentum, restore_momentum, restore_energy, accurate_sum
    public :: REMESH_NONE, REMESH_REFINE, REMESH_COARSEN, REMESH_SAME, NARROW_GAP

    integer, parameter :: REMESH_NONE = 0
    integer, parameter :: REMESH_REFINE = 1
    integer, parameter :: REMESH_COARSEN = 2
    integer, parameter :: REMESH_SAME = 3

    !> mirror reach of the transfer next to solids, in units of h (see the module header)
    real(wp), parameter :: MIRROR_REACH = 3.0_wp
    !> how far (in h) from its part of the domain a rank needs the new particles in the
    !> transfer: an isolated old particle's nearest within 4 h; next to solids the new
    !> particles whose mirrors lie within 2 h of an old one (module header)
    real(wp), parameter :: NEW_REACH = 4.0_wp
    !> the reach (in h) of the new particles that no mirror involves, when no old particle
    !> is isolated: M4's support, 2 h per axis, and a margin for round-off
    real(wp), parameter :: PAIR_REACH = 2.0_wp * (1.0_wp + 1.0e-6_wp)
    !> same-level remeshing and coarsening keep no new particle closer than this (in new
    !> spacings) to a solid
    real(wp), parameter :: WALL_GAP = 0.4_wp
    !> the relaxation squeezes no pair below this (in new spacings): issue 10's floor
    real(wp), parameter :: RELAX_FLOOR = 0.4_wp
    !> a refined or coarsened set's relaxation moves two particles that are each other's
    !> nearest, closer than this (in new spacings), together: a clumped flow's pairs stay
    !> pairs, and the set keeps the flow's nearest distances (issue 10). Relaxed one by one,
    !> the L/25 cylinder flow at 1500 s refined to a mean nearest distance 0.532 of the flow's
    !> (0.495 with pairs kept), and the developed cylinder flows coarsened to nearest-distance
    !> CoVs 0.73-0.80 of the flows' and a mean ratio of 2.23 at L/50, 6000 s (0.78-0.91 and
    !> 1.97-2.06 with pairs kept; 0.6 kept too few at L/50: 2.14). The sets' kernel sums of
    !> volumes are as even either way. A lattice's nearest lie 0.9-1 apart.
    real(wp), parameter :: PAIR_GAP = 0.8_wp
    !> a same-level remesh leaves the particles of a narrow gap as they are (module header):
    !> a particle lies in one when two solids whose normals there are more than 120 degrees
    !> apart (cosine below GAP_FACING) are closer than NARROW_GAP spacings together (the sum
    !> of its distances to them); new points closer than GAP_CLEAR spacings to such a
    !> particle go
    real(wp), parameter :: NARROW_GAP = 2.5_wp
    real(wp), parameter :: GAP_FACING = -0.5_wp
    real(wp), parameter :: GAP_CLEAR = 0.75_wp

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
    !> header); without them the walls are ignored.
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
        real(wp), allocatable :: x(:, :), xn(:, :)
        integer(i8), allocatable :: ids(:), idn(:)
        integer :: n, n_new, my_stat, n_src
        integer(i8) :: base
        real(wp) :: t0, t_transfer, ghost_ratio, relax_gap
        character(len=:), allocatable :: message
        logical, allocatable :: fluid(:)

        t0 = MPI_Wtime()
        stat = 0
        errmsg = ''
        message = ''
        ghost_ratio = real(max(p%n_total, 1), wp) / real(max(p%n_owned, 1), wp)
        ! totals before, over all ranks
        fluid = p%kind(1:p%n_owned) == KIND_FLUID
        report%n_before = global_sum(env, int(count(fluid), i8))
        call fluid_mass_momentum(env, p, report%mass_before, report%momentum_before, &
            report%energy_before)
        base = global_max_id(env, p%id, p%n_owned)

        call gather_positions(env, p, fluid, n, x, ids)
        ! same level: the particles of narrow gaps last in x, left out of the construction
        n_src = n
        if (env%rank == 0 .and. mode == REMESH_SAME) call set_aside_gaps()
        report%n_in_gaps = int(global_max(env, int(n - n_src, i8)))
        my_stat = 0
        n_new = 0
        allocate(xn(3, 0), idn(0))
        if (env%rank == 0) call new_positions(my_stat, message)
        if (refused()) return
        ! fresh ids for refined particles (collective; only rank 0 has keys)
        if (mode == REMESH_REFINE .or. mode == REMESH_SAME) call fresh_ids()
        ! same level: back to the count the fluid had (the fill pass of sph_coarsen), with
        ! the first row about half a spacing from each solid, as in the initial lattice (the
        ! refined set's rows next to a plane wall lie at 0.5 and 1.0 dx: none is dropped)
        if (env%rank == 0 .and. mode == REMESH_SAME) then
            call keep_off_solids(WALL_GAP * dx)
            if (n_src < n) call keep_out_of_gaps()
            call coarsen_step(dx / 2.0_wp, n_src, my_stat, message)
            ! the particles of the narrow gaps join the set as they were, with their ids
            ! (below every fresh one); the relaxation moves none of them (off_solids)
            if (my_stat == 0 .and. n_src < n) then
                xn = reshape([xn(:, 1:n_new), x(:, n_src + 1:n)], [3, n_new + n - n_src])
                idn = [idn(1:n_new), ids(n_src + 1:n)]
                n_new = n_new + n - n_src
            end if
            if (my_stat == 0) call relax_new_set(dx)
        end if
        ! the new set in id order: its particles then lie about in space order (the ids follow
        ! the keys, the keys the old ids), for the transfer and for the caller's id order
        if (env%rank == 0 .and. my_stat == 0) call into_id_order(xn, idn, n_new)
        if (refused()) return
        ! rank 0 relaxed the set: every rank reports its passes
        report%relax_passes = int(global_max(env, int(report%relax_passes, i8)))
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
            errmsg = 'remesh: ' // message
        end function refused

        !> Rank 0: xn and (coarsening) idn of the new set, positions relative to box_lo.
        subroutine new_positions(st, msg)
            integer, intent(out) :: st
            character(len=:), allocatable, intent(inout) :: msg
            integer(i8), allocatable :: keys(:, :)
            character(len=200) :: text
            integer :: irregular, n_disordered
            st = 0
            text = ''
            select case (mode)
            case (REMESH_REFINE, REMESH_SAME)
                deallocate(xn)
                call refine_positions(dim, n_src, x, ids, dx, n_new, xn, keys, st, text, &
                    algorithm_box(dx), irregular, solids, box_lo, &
                    merge(0.0_wp, WALL_BAND, mode == REMESH_SAME), &
                    merge(2**dim * n, 0, mode == REMESH_REFINE))
                report%n_irregular = irregular
                ! where the construction's wall rules meet (a body close to a wall, a box's
                ! edges) a point may lie closer than WALL_GAP new spacings to a solid (0.31
                ! in a closed 3D box with a sphere): it goes, as in a coarsening, and its
                ! share of the mass goes to its neighbours (the relaxation moves none there)
                if (st == 0 .and. mode == REMESH_REFINE) call refined_off_solids(keys)
                ! a clumped flow's construction (irregular cells, gaps filled) and the cells
                ! next to a body's staircase leave uneven volumes: kernel sums 0.41-1.86 of
                ! the even value on Morris' L/25 cylinder at 1500 s refined, whose continued
                ! run then broke down at 5649 s (module header); a lattice's refinement is one
                if (st == 0 .and. mode == REMESH_REFINE .and. (irregular > 0 .or. has_body())) &
                    call relax_new_set(0.5_wp * dx, PAIR_GAP)
                ! the keys travel in idn's place until fresh_ids turns them into ids
                deallocate(idn)
                allocate(idn(2 * n_new))
                if (n_new > 0) idn = reshape(keys(:, 1:n_new), [2 * n_new])
            case (REMESH_COARSEN)
                deallocate(idn)
                allocate(idn(n))
                idn = ids(1:n)
                deallocate(xn)
                allocate(xn(3, n))
                xn = x(:, 1:n)
                n_new = n
                ! the first coarse row about half a new spacing from each solid, as in the
                ! initial lattice: next to a body the fine first row (0.25 new spacings off)
                ! is not kept; next to a plane wall the kept rows are moved (module header)
                call keep_off_solids(WALL_GAP * 2.0_wp * dx, curved_only=.true.)
                call coarsen_step(dx, nint(real(n, wp) / 2.0_wp**dim), st, msg, n_disordered)
                if (st == 0) call place_plane_rows(2.0_wp * dx)
                ! a selection from a near-lattice (no particle whose rows sit off whole
                ! spacings) with no body in it is its sublattice, whose volumes are even
                ! already (next to a body the lattice's staircase leaves uneven ones)
                ! the kept set in id order, whatever the ranks' share of the gathered one: the
                ! selection does not depend on the order, but the relaxation's sums and its
                ! pairs' ties do (a coarsened lattice next to a body kept other pairs on 2
                ! ranks than on 1); a refined set comes in key order
                if (st == 0 .and. (n_disordered > 0 .or. has_body())) then
                    call into_id_order(xn, idn, n_new)
                    call relax_new_set(2.0_wp * dx, PAIR_GAP)
                end if
                ! where a body lies within a spacing of a plane wall, place_plane_rows cannot
                ! put the rows between them on the wall's gap without crossing the body's:
                ! what is left closer than WALL_GAP to any solid goes (its mass is handed on;
                ! 6 particles 0.25 new spacings off the wall under a 3D cylinder 1.5 old
                ! spacings from it were kept, against the documented 0.4). The factor lets
                ! the particles put on a gap's edge stay, to round-off.
                if (st == 0) call keep_off_solids((1.0_wp - 1.0e-9_wp) * WALL_GAP * 2.0_wp * dx)
                ! the rows put half a spacing off plane walls may come closer than the floor
                ! to a particle kept next to them (0.395 new spacings in a closed 3D box); a
                ! near-lattice's sublattice has none (its pairs are a whole new spacing apart)
                if (st == 0 .and. (n_disordered > 0 .or. has_body())) &
                    call drop_close_pairs((1.0_wp - 1.0e-9_wp) * RELAX_FLOOR * 2.0_wp * dx)
                return
            case default
                st = 1
                text = 'unknown mode'
            end select
            if (st /= 0) msg = trim(text)
        end subroutine new_positions

        !> Keep the coarsen_select set of xn/idn (spacing dxs), filled up to n_target particles
        !> where the set is disordered. Coarsening follows the flow's spacing (the kept set
        !> keeps the flow's clumping at twice the spacing, issue 10's "disorder kept"); the
        !> same-level remesh does not: it is there to give a clumped flow a fresh set, and a
        !> kept clumping cost the developed cylinder flow 9 % of its mean velocity
        !> (doc/validation.md).
        subroutine coarsen_step(dxs, n_target, st, msg, n_disordered)
            real(wp), intent(in) :: dxs
            integer, intent(in) :: n_target
            integer, intent(out) :: st
            character(len=:), allocatable, intent(inout) :: msg
            !> the set's particles whose rows sit off whole spacings (sph_coarsen)
            integer, intent(out), optional :: n_disordered
            integer, allocatable :: kept(:), tag(:)
            integer :: n_kept
            character(len=200) :: text
            text = ''
            call coarsen_select(dim, n_new, xn, idn, dxs, n_kept, kept, tag, st, text, &
                algorithm_box(dxs), n_target=n_target, follow_spacing=mode == REMESH_COARSEN, &
                n_disordered=n_disordered)
            if (st /= 0) then
                msg = trim(text)
                return
            end if
            xn = xn(:, kept)
            idn = idn(kept)
            n_new = n_kept
        end subroutine coarsen_step

        !> Rank 0: drop the refined points xn and their keys closer than WALL_GAP new
        !> spacings to a solid (to round-off: a plane wall's first row, half a spacing off,
        !> stays).
        subroutine refined_off_solids(keys)
            integer(i8), allocatable, intent(inout) :: keys(:, :)
            logical, allocatable :: clear(:)
            integer :: a
            clear = clear_mask((1.0_wp - 1.0e-9_wp) * WALL_GAP * 0.5_wp * dx)
            if (all(clear)) return
            xn = xn(:, pack([(a, a = 1, n_new)], clear))
            keys = keys(:, pack([(a, a = 1, n_new)], clear))
            n_new = size(xn, 2)
        end subroutine refined_off_solids

        !> Rank 0: of every pair of xn closer than `floor` (through the periodic faces too),
        !> the particle with the larger id goes (its mass is handed on to the others).
        subroutine drop_close_pairs(floor)
            real(wp), intent(in) :: floor
            real(wp), allocatable :: y(:, :)
            integer, allocatable :: orig(:)
            logical, allocatable :: keep(:)
            type(neighbour_list_t) :: near
            integer :: ny, a, k, b
            if (n_new < 2) return
            call with_images(dim, box_lo, box_hi, periodic, n_new, xn, floor, y, orig, ny)
            call build_neighbour_list(y, ny, n_new, dim, floor, near)
            allocate(keep(n_new))
            keep = .true.
            do a = 1, n_new
                do k = near%start(a), near%start(a + 1) - 1
                    b = orig(near%index(k))
                    if (b == a .or. .not. keep(a) .or. .not. keep(b)) cycle
                    if (sum((y(1:dim, a) - y(1:dim, near%index(k)))**2) >= floor**2) cycle
                    if (idn(b) > idn(a)) then
                        keep(b) = .false.
                    else
                        keep(a) = .false.
                    end if
                end do
            end do
            call keep_only(keep)
        end subroutine drop_close_pairs

        !> Rank 0: keep the points of xn/idn marked in keep, in their order.
        subroutine keep_only(keep)
            logical, intent(in) :: keep(:)
            integer :: a
            if (all(keep)) return
            xn = xn(:, pack([(a, a = 1, n_new)], keep))
            idn = idn(pack([(a, a = 1, n_new)], keep))
            n_new = size(idn)
        end subroutine keep_only

        !> Rank 0: drop the candidates xn/idn closer than gap to any solid surface (with
        !> curved_only, to any solid that is not a plane).
        subroutine keep_off_solids(gap, curved_only)
            real(wp), intent(in) :: gap
            logical, intent(in), optional :: curved_only
            call keep_only(clear_mask(gap, curved_only))
        end subroutine keep_off_solids

        !> Rank 0: whether each point of xn is at least gap from every solid surface (with
        !> curved_only, from every solid that is not a plane); all true, with no pass over
        !> the set, when no solid applies (a periodic box; only planes with curved_only).
        function clear_mask(gap, curved_only) result(clear)
            real(wp), intent(in) :: gap
            logical, intent(in), optional :: curved_only
            logical, allocatable :: clear(:)
            logical :: planes
            integer :: a
            allocate(clear(n_new))
            clear = .true.
            if (.not. present(solids)) return
            if (.not. allocated(solids%list)) return
            if (size(solids%list) == 0) return
            planes = .true.
            if (present(curved_only)) planes = .not. curved_only
            if (.not. planes .and. all(solids%list(:)%shape == SOLID_PLANE)) return
            do a = 1, n_new
                clear(a) = clear_of_solids(xn(:, a), gap, curved_only)
            end do
        end function clear_mask

        !> Rank 0: even out the volumes of the selected set xn of spacing sp (sph_remesh_relax),
        !> its periodic images and mirrors across the solids pushing; a move that would bring a
        !> particle closer than WALL_GAP sp to a solid is not made. At most RELAX_PASSES
        !> passes; it stops after a pass whose largest move is below RELAX_TOLERANCE sp.
        subroutine relax_new_set(sp, pair_gap)
            real(wp), intent(in) :: sp
            real(wp), intent(in), optional :: pair_gap
            real(wp), allocatable :: y(:, :), moves(:, :)
            integer, allocatable :: orig(:), moves_with(:)
            real(wp) :: reach, largest
            integer :: pass, ny, a
            type(relax_list_t) :: kept
            reach = 2.0_wp * RELAX_H_FACTOR * sp
            relax_gap = WALL_GAP * sp
            allocate(moves(3, max(n_new, 1)))
            do pass = 1, RELAX_PASSES
                call with_mirrors_and_images(dim, box_lo, box_hi, periodic, solids, reach, &
                    reach, n_new, xn, y, orig, ny, moves_with)
                call relax_displacements(dim, n_new, ny, y, sp, moves, kept, RELAX_FLOOR, &
                    off_solids, pair_gap, moves_with)
                largest = 0.0_wp
                do a = 1, n_new
                    xn(:, a) = wrapped(xn(:, a) + moves(:, a))
                    largest = max(largest, norm2(moves(:, a)))
                end do
                report%relax_passes = pass
                ! an even set (a lattice's sublattice) barely moves: the passes left would not
                ! move it either
                if (largest < RELAX_TOLERANCE * sp) exit
            end do
        end subroutine relax_new_set

        !> relax_new_set's constraint: a move that would bring a particle closer than
        !> relax_gap to a solid is refused
        logical function off_solids(z)
            real(wp), intent(in) :: z(3)
            off_solids = clear_of_solids(wrapped(z), relax_gap)
            ! (and, with particles left in narrow gaps, out of the gaps: those stay put)
            if (off_solids .and. n_src < n) off_solids = .not. in_narrow_gap(wrapped(z))
        end function off_solids

        !> Rank 0, same level: the particles of x/ids that lie in a narrow gap moved to the
        !> end (their order kept), n_src the count before them. Across a gap narrower than
        !> NARROW_GAP spacings the free strip (WALL_GAP off each side) is narrower than the
        !> selection's radius, so the construction and selection leave one row at a whole
        !> spacing where the flow holds its particles closer (a gap of 1.4 spacings: one row
        !> at 0.7), and the transfer takes the difference's mass out of the gap; remeshed
        !> every 20 steps, a channel with such gaps ran 29 % faster than the run made at half
        !> the spacing (unremeshed: 6 %).
        !> A particle closer than RELAX_FLOOR spacings to another is remeshed with the rest,
        !> both of the pair: a pair the set-up left 0.095 dx apart between two discs 1 dx
        !> apart was kept through 47 remeshes. (Closer than WALL_GAP to a solid is the flow's
        !> own place, as unremeshed; remeshing those too halved the flux through a gap of 1.4
        !> spacings under a disc: 0.34-0.37 against 0.58-0.65, at half the spacing 0.63.)
        subroutine set_aside_gaps()
            logical, allocatable :: gap(:)
            integer, allocatable :: order(:), orig(:)
            real(wp), allocatable :: y(:, :)
            type(neighbour_list_t) :: near
            real(wp) :: floor
            integer :: a, k, b, ny
            allocate(gap(n))
            do a = 1, n
                gap(a) = in_narrow_gap(x(:, a))
            end do
            if (.not. any(gap)) return
            ! a pair closer than the floor is remeshed with the rest, both of it
            floor = (1.0_wp - 1.0e-9_wp) * RELAX_FLOOR * dx
            call with_images(dim, box_lo, box_hi, periodic, n, x, floor, y, orig, ny)
            call build_neighbour_list(y, ny, n, dim, floor, near)
            do a = 1, n
                do k = near%start(a), near%start(a + 1) - 1
                    b = orig(near%index(k))
                    if (b == a .or. .not. (gap(a) .or. gap(b))) cycle
                    if (sum((y(1:dim, a) - y(1:dim, near%index(k)))**2) >= floor**2) cycle
                    gap(a) = .false.
                    gap(b) = .false.
                end do
            end do
            if (.not. any(gap)) return
            n_src = count(.not. gap)
            allocate(order(n))
            order(1:n_src) = pack([(a, a = 1, n)], .not. gap)
            order(n_src + 1:n) = pack([(a, a = 1, n)], gap)
            x(:, 1:n) = x(:, order)
            ids(1:n) = ids(order)
        end subroutine set_aside_gaps

        !> Whether z (relative to box_lo) lies in a narrow gap (set_aside_gaps): two solids
        !> facing each other there, closer than NARROW_GAP spacings together.
        logical function in_narrow_gap(z)
            real(wp), intent(in) :: z(3)
            ! the solids within NARROW_GAP spacings of z (only those can make a gap with it)
            integer, parameter :: MAX_NEAR = 32
            real(wp) :: d, normal(3, MAX_NEAR), d_near(MAX_NEAR)
            integer :: s, t, n_near
            in_narrow_gap = .false.
            if (.not. present(solids)) return
            if (.not. allocated(solids%list)) return
            n_near = 0
            do s = 1, size(solids%list)
                d = solid_distance(solids%list(s), z + box_lo)
                if (d >= NARROW_GAP * dx .or. n_near == MAX_NEAR) cycle
                n_near = n_near + 1
                d_near(n_near) = d
                normal(:, n_near) = solid_normal(solids%list(s), z + box_lo)
            end do
            do s = 1, n_near
                do t = s + 1, n_near
                    if (d_near(s) + d_near(t) >= NARROW_GAP * dx) cycle
                    if (dot_product(normal(:, s), normal(:, t)) >= GAP_FACING) cycle
                    in_narrow_gap = .true.
                    return
                end do
            end do
        end function in_narrow_gap

        !> Rank 0, same level: drop the new points xn/idn that lie in a narrow gap or closer
        !> than GAP_CLEAR spacings to a particle left there (x(:, n_src + 1:n), periodic
        !> images included).
        subroutine keep_out_of_gaps()
            real(wp), allocatable :: y(:, :), yi(:, :)
            integer, allocatable :: orig(:)
            logical, allocatable :: keep(:)
            type(neighbour_list_t) :: near
            integer :: a, k, b, n_gap, ny
            n_gap = n - n_src
            allocate(keep(n_new))
            do a = 1, n_new
                keep(a) = .not. in_narrow_gap(xn(:, a))
            end do
            ! the gap's particles are the list's rows, the new points its candidates
            y = reshape([x(:, n_src + 1:n), xn(:, 1:n_new)], [3, n_gap + n_new])
            call with_images(dim, box_lo, box_hi, periodic, n_gap + n_new, y, GAP_CLEAR * dx, &
                yi, orig, ny)
            call build_neighbour_list(yi, ny, n_gap, dim, GAP_CLEAR * dx, near)
            do a = 1, n_gap
                do k = near%start(a), near%start(a + 1) - 1
                    b = orig(near%index(k)) - n_gap
                    if (b < 1) cycle
                    if (sum((yi(1:dim, a) - yi(1:dim, near%index(k)))**2) < (GAP_CLEAR * dx)**2) &
                        keep(b) = .false.
                end do
            end do
            call keep_only(keep)
        end subroutine keep_out_of_gaps

        !> z wrapped into the box along the periodic axes
        function wrapped(z) result(w)
            real(wp), intent(in) :: z(3)
            real(wp) :: w(3)
            integer :: ax
            w = z
            do ax = 1, dim
                if (periodic(ax)) w(ax) = modulo(w(ax), box_hi(ax) - box_lo(ax))
            end do
        end function wrapped

        !> Whether some solid is not a plane (a body).
        logical function has_body()
            has_body = .false.
            if (.not. present(solids)) return
            if (.not. allocated(solids%list)) return
            has_body = any(solids%list(:)%shape /= SOLID_PLANE)
        end function has_body

        !> Whether the point z (relative to box_lo) lies at least gap from every solid (with
        !> curved_only, from every solid that is not a plane).
        logical function clear_of_solids(z, gap, curved_only)
            real(wp), intent(in) :: z(3), gap
            logical, intent(in), optional :: curved_only
            integer :: s
            logical :: planes
            clear_of_solids = .true.
            if (.not. present(solids)) return
            if (.not. allocated(solids%list)) return
            planes = .true.
            if (present(curved_only)) planes = .not. curved_only
            do s = 1, size(solids%list)
                if (.not. planes .and. solids%list(s)%shape == SOLID_PLANE) cycle
                if (solid_distance(solids%list(s), z + box_lo) < gap) clear_of_solids = .false.
            end do
        end function clear_of_solids

        !> Rank 0: the coarsened set xn (spacing sp) moved so that its first row next to each
        !> plane wall lies half a spacing off it (module header, "Coarsening"). Wall s wants
        !> its first row (the particles within one spacing of it that have it as their
        !> nearest plane; mean distance f_s) moved by delta_s = sp / 2 - f_s along its
        !> normal. Between two facing walls (opposite normals, distances d_s and d_t) a
        !> particle moves by delta_s d_t / (d_s + d_t) along the one normal plus delta_t d_s /
        !> (d_s + d_t) along the other: the move varies linearly across the channel, so the
        !> rows stay evenly spaced (when both walls want the same shift, as a set of every
        !> other fine row does, the whole set moves by it); next to a wall that faces none the
        !> move fades out over WALL_BAND spacings. A particle left within WALL_GAP sp of a
        !> plane (a disordered first row, spread over the gap, whose mean barely moves) is put
        !> on the gap's edge; a move that would bring a particle within the gap of a body is
        !> not made. (Measured on the lid-driven cavity coarsened at 0.02 s: without that
        !> edge 23 of 625 particles ended within the gap, down to 0.15 spacings.)
        subroutine place_plane_rows(sp)
            real(wp), intent(in) :: sp
            real(wp), allocatable :: row_sum(:), delta(:), d(:, :)
            integer, allocatable :: row_count(:), facing(:)
            real(wp) :: u(3), z(3)
            integer :: a, s, t, ns, near
            if (.not. present(solids)) return
            if (.not. allocated(solids%list)) return
            if (.not. any(solids%list(:)%shape == SOLID_PLANE)) return
            ns = size(solids%list)
            allocate(row_sum(ns), row_count(ns), delta(ns), facing(ns), d(ns, n_new))
            ! the facing wall of each plane (0: none)
            facing = [(facing_plane(solids, s), s = 1, ns)]
            ! every particle's distances from the planes, and each plane's first row
            row_sum = 0.0_wp
            row_count = 0
            do a = 1, n_new
                near = 0
                do s = 1, ns
                    d(s, a) = huge(1.0_wp)
                    if (solids%list(s)%shape /= SOLID_PLANE) cycle
                    d(s, a) = solid_distance(solids%list(s), xn(:, a) + box_lo)
                    if (near == 0) then
                        near = s
                    else if (d(s, a) < d(near, a)) then
                        near = s
                    end if
                end do
                if (d(near, a) >= sp) cycle
                row_sum(near) = row_sum(near) + d(near, a)
                row_count(near) = row_count(near) + 1
            end do
            delta = 0.0_wp
            where (row_count > 0) delta = 0.5_wp * sp - row_sum / max(row_count, 1)
            do a = 1, n_new
                u = 0.0_wp
                do s = 1, ns
                    if (solids%list(s)%shape /= SOLID_PLANE) cycle
                    t = facing(s)
                    if (t > 0) then
                        if (d(s, a) + d(t, a) > 0.0_wp) u = u + delta(s) * d(t, a) / &
                            (d(s, a) + d(t, a)) * solids%list(s)%normal
                    else
                        u = u + delta(s) * max(0.0_wp, 1.0_wp - d(s, a) / (WALL_BAND * sp)) * &
                            solids%list(s)%normal
                    end if
                end do
                ! a particle of a disordered first row that still lies within the gap (the
                ! row's mean barely moves where it is spread over the gap) is put on its edge
                do s = 1, ns
                    if (solids%list(s)%shape /= SOLID_PLANE) cycle
                    u = u + max(0.0_wp, WALL_GAP * sp - (d(s, a) + dot_product(u, &
                        solids%list(s)%normal))) * solids%list(s)%normal
                end do
                u(dim + 1:) = 0.0_wp
                z = xn(:, a) + u
                ! (the planes' gaps hold by construction)
                if (clear_of_solids(z, WALL_GAP * sp, curved_only=.true.)) xn(:, a) = z
            end do
        end subroutine place_plane_rows

        !> Rank 0: the new set xn/idn in increasing id order.
        !> Rank 0: the points xs(:, 1:count) and their ids idv in id order.
        subroutine into_id_order(xs, idv, count)
            real(wp), intent(inout) :: xs(:, :)
            integer(i8), intent(inout) :: idv(:)
            integer, intent(in) :: count
            integer, allocatable :: order(:)
            allocate(order(count))
            call id_order(idv, count, order)
            xs(:, 1:count) = xs(:, order)
            idv(1:count) = idv(order)
        end subroutine into_id_order

        !> ids for the keys in idn (all ranks take part; rank 0 holds the keys).
        subroutine fresh_ids()
            integer(i8), allocatable :: keys(:, :), new_ids(:)
            integer(i8) :: next_base
            allocate(keys(2, max(n_new, 1)), new_ids(max(n_new, 1)))
            if (n_new > 0) keys(:, 1:n_new) = reshape(idn, [2, n_new])
            call assign_global_ids(env, keys, n_new, base, new_ids, next_base)
            deallocate(idn)
            allocate(idn(n_new))
            idn = new_ids(1:n_new)
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
            character(len=200) :: text
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
                    xs, acc, st, text, nmf, n_isolated)
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
                allocate(owner(n_new), order(n_new), fill(0:env%nranks - 1))
                do k = 1, n_new
                    owner(k) = domain_owner(parts, xn(:, k) + box_lo)
                    counts(owner(k)) = counts(owner(k)) + 1
                end do
                do r = 1, env%nranks - 1
                    displs(r) = displs(r - 1) + counts(r - 1)
                end do
                ! grouped by owner, in id order within each
                fill = displs
                do k = 1, n_new
                    fill(owner(k)) = fill(owner(k)) + 1
                    order(fill(owner(k))) = k
                end do
                allocate(sx(3, max(n_new, 1)), sid(max(n_new, 1)))
                do k = 1, n_new
                    sx(:, k) = xn(:, order(k))
                    sid(k) = idn(order(k))
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

        !> The box given to refine_positions / coarsen_select: the domain on periodic axes;
        !> on the others a length so much larger that their images never meet a particle.
        function algorithm_box(spacing) result(b)
            real(wp), intent(in) :: spacing
            real(wp) :: b(3)
            integer :: a
            b = 0.0_wp
            do a = 1, dim
                b(a) = box_hi(a) - box_lo(a)
                if (.not. periodic(a)) b(a) = 2.0_wp * b(a) + 64.0_wp * spacing
            end do
        end function algorithm_box

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

    !> sum + x with the rounding error of the addition kept in lost (Neumaier's compensated
    !> summation: the result is sum + lost, exact to about one rounding whatever the count).
    pure subroutine accurate_add(sum, lost, x)
        real(wp), intent(inout) :: sum, lost
        real(wp), intent(in) :: x
        real(wp) :: t
        t = sum + x
        if (abs(sum) >= abs(x)) then
            lost = lost + ((sum - t) + x)
        else
            lost = lost + ((x - t) + sum)
        end if
        sum = t
    end subroutine accurate_add

    !> The sum of values, compensated (accurate_add).
    pure real(wp) function accurate_sum(values) result(total)
        real(wp), intent(in) :: values(:)
        real(wp) :: lost
        integer :: i
        total = 0.0_wp
        lost = 0.0_wp
        do i = 1, size(values)
            call accurate_add(total, lost, values(i))
        end do
        total = total + lost
    end function accurate_sum

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
