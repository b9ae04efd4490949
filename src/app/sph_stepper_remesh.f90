!> Remeshing during a run (remesh_if_due, simulation_remesh) and offline
!> (simulation_remesh_file): when a remesh is due, the remesh of the state with the walls
!> regenerated at the new spacing, and its log lines.
!> Split from sph_stepper so that each file holds one concern; the interfaces and their
!> documentation are in sph_stepper.
submodule (sph_stepper) sph_stepper_remesh
    use sph_logger, only: log_warn_counted, log_warn, sci_text, fixed_text, logger_is_root, &
        mb_text, int_text
    use sph_physics, only: physics_from_config, WALLS_MORRIS
    use sph_walls, only: solids_from_config, body_holds_site
    use sph_disorder_measure, only: nearest_distance_sums, disorder_from_sums
    use sph_snapshot, only: read_snapshot_header, read_snapshot_rows, SNAPSHOT_NOT_CLOSED
    use sph_checkpoint, only: write_checkpoint, stored_spacing
    use sph_read_checks, only: check_read_particles, check_fluid_outside_solids
    use sph_remesh_driver, only: remesh_report_t, remesh_fluid, remesh_mode_code, &
        remesh_spacing_factor, fluid_mass_momentum, restore_momentum, restore_energy, &
        accurate_sum, REMESH_NONE, REMESH_REFINE, REMESH_COARSEN, REMESH_SAME, NARROW_GAP
    use sph_rates, only: compute_summation_density
    use sph_particles, only: HALO_GHOST
    use sph_errors, only: STATUS_OUTPUT_FAILED, remove_at_exit
    use sph_filesystem, only: entry_kind, ENTRY_NONE, MAX_FILE_PATH
    use sph_memory, only: peak_resident_bytes, startup_memory_bytes
    use sph_domain_input, only: misfit_axis
    implicit none

    !> the fluid masses' adjustment to the kernel sums (consistent_masses): at most this many
    !> passes, which stop once every fluid particle's kernel sum / handed-on density is within
    !> MASS_TOLERANCE of their mean
    integer, parameter :: MASS_PASSES = 8
    real(wp), parameter :: MASS_TOLERANCE = 1.0e-3_wp

contains

    module procedure remesh_if_due
        logical :: due
        integer :: mode, previous
        real(wp) :: disorder
        character(len=120) :: text
        character(len=:), allocatable :: problem
        mode = remesh_mode_code(sim%cfg%remesh%mode)
        if (mode == REMESH_NONE) return
        due = .false.
        if (sim%cfg%remesh%every_steps > 0) &
            due = mod(sim%step, int(sim%cfg%remesh%every_steps, i8)) == 0
        if (sim%time >= sim%next_remesh_time * (1.0_wp - 1.0e-12_wp)) then
            due = .true.
            sim%next_remesh_time = next_multiple(sim%time, sim%cfg%remesh%every_time)
        end if
        if (.not. due .and. sim%cfg%remesh%disorder_threshold > 0.0_wp) then
            if (mod(sim%step, int(sim%cfg%remesh%disorder_check_steps, i8)) == 0) then
                disorder = disorder_from_sums(global_sum(env, &
                    nearest_distance_sums(sim%p, sim%nl)))
                due = disorder > sim%cfg%remesh%disorder_threshold
                if (due) then
                    write(text, '(a, f8.5, a, f8.5)') 'remesh: disorder (CoV of the ' // &
                        'nearest-neighbour distances) ', disorder, ' > threshold ', &
                        sim%cfg%remesh%disorder_threshold
                    call log_info(text)
                end if
            end if
        end if
        if (.not. due) return
        ! a spacing whose lattice cannot fill the box (coarsening again and again, or a box of
        ! an odd number of spacings): the run goes on at its spacing
        problem = spacing_problem(sim%cfg, mode)
        if (len(problem) > 0) then
            ! (the same on every rank: rank 0 says it)
            if (env%rank == 0) call log_warn_counted('remesh_spacing', &
                'remesh: not remeshed: ' // problem)
            return
        end if
        ! refining again and again (every_steps with mode = 'refine') multiplies the particles
        ! by 2^dim each time, and rank 0 makes every new position: a remesh that the nodes
        ! cannot hold is skipped, not killed by the system with the run's work since its
        ! last checkpoint
        problem = remesh_capacity_problem(sim, env, mode)
        if (len(problem) > 0) then
            if (env%rank == 0) call log_warn_counted('remesh_capacity', &
                'remesh: not remeshed: ' // problem // '; the run goes on at its spacing')
            return
        end if
        call timers_enter(sim%timers, TIMER_OTHER, previous)
        call simulation_remesh(sim, env, mode)
        call timers_leave(sim%timers, previous)
        if (sim%cfg%remesh%disorder_threshold <= 0.0_wp) return
        ! a fresh set has some disorder of its own (0.15-0.18 on the cylinder flow): a
        ! threshold below it would remesh at every check
        disorder = disorder_from_sums(global_sum(env, nearest_distance_sums(sim%p, sim%nl)))
        write(text, '(a, f8.5)') 'remesh: disorder after the remesh ', disorder
        call log_info(text)
        if (disorder > sim%cfg%remesh%disorder_threshold .and. env%rank == 0) &
            call log_warn_counted( &
            'disorder_threshold', '&remesh disorder_threshold is below the disorder of a ' // &
            'freshly remeshed set: every check will remesh; raise it above the value logged ' // &
            "after the remesh ('remesh: disorder after the remesh')")
    end procedure remesh_if_due

    module procedure simulation_remesh
        call remesh_state(sim, env, mode, mode /= REMESH_SAME)
    end procedure simulation_remesh

    !> The remesh itself; regenerate: new wall particles at the new spacing.
    subroutine remesh_state(sim, env, mode, regenerate)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        integer, intent(in) :: mode
        logical, intent(in) :: regenerate
        type(remesh_report_t) :: report
        real(wp) :: dx_old, dx_new, h_new
        integer :: stat, axis
        logical :: periodic(3)
        character(len=:), allocatable :: errmsg
        integer, allocatable :: order(:)
        real(wp) :: t_rebuild

        ! positions wrapped into the box and owned where they lie (the Verlet list may have
        ! been reused since the last rebuild): the remeshing works on the periodic box
        call synchronise(sim, env)
        dx_old = sim%cfg%domain%dx
        dx_new = dx_old * remesh_spacing_factor(mode)
        periodic = .false.
        do axis = 1, sim%cfg%domain%dimension
            periodic(axis) = sim%cfg%domain%is_periodic(axis)
        end do
        if (mode /= REMESH_SAME) then
            sim%cfg%domain%dx = dx_new
            call physics_from_config(sim%cfg, sim%phys, stat, errmsg)
            if (stat /= 0) call fatal_collective('remesh', errmsg)
            sim%level_phys(0) = sim%phys
            sim%solids = solids_from_config(sim%cfg)
            sim%skin = 2.0_wp * sim%cfg%numerics%cfl * sim%phys%kernel%h
            sim%list_skin = 0.1_wp * sim%phys%kernel%h
        end if
        h_new = sim%phys%kernel%h
        call remesh_fluid(env, mode, sim%cfg%domain%dimension, dx_old, sim%cfg%domain%box_lo, &
            sim%cfg%domain%box_hi, periodic, h_new, sim%p, report, stat, errmsg, sim%solids)
        if (stat /= 0) call fatal_collective('remesh', errmsg)
        t_rebuild = MPI_Wtime()
        ! the fluid first (rank 0 holds it all), then the walls of the lattice at dx_new, each
        ! made by the rank whose region (the partition from before the remesh) holds it; the
        ! partition below and the migration hand them to their owners
        if (regenerate) call lay_lattice_walls(sim, env)
        call domain_partition(sim%domain, env, sim%p%x, sim%p%n_owned)
        ! (the reach every set-up, restart and rebalance uses: with support + skin alone the
        ! run held fewer ghosts than a restart from a later checkpoint builds, and on 2 ranks
        ! the restart differed from the run by round-off)
        call halo_setup(sim%halo, sim%domain, halo_reach(sim))
        call migrate(sim, env)
        ! in id order before the cell sort, as on set-up: independent of the arrival order
        allocate(order(sim%p%n_owned))
        call id_order(sim%p%id, sim%p%n_owned, order)
        call particles_gather(sim%p, order)
        call simulation_prepare_neighbours(sim, env)
        ! (a coarsened continuity flow keeps the masses the transfer gave, and so does a
        ! refined lattice, which is not relaxed: below)
        if (sim%phys%density_method == DENSITY_SUMMATION .or. (mode /= REMESH_COARSEN .and. &
            report%relax_passes > 0)) call consistent_masses(sim, env, report)
        call update_pressure(sim%phys, sim%p, 1, sim%p%n_total)
        sim%rates_stale = .true.
        ! the health check's time-step floor is a fraction of the first step at this spacing
        ! (a refinement shortens the viscous limit fourfold: the fifth in a run read as a
        ! collapse of the step, 2.1e-3 -> 2.1e-6 s)
        if (mode /= REMESH_SAME) sim%first_dt = 0.0_wp
        sim%remesh_stages = [report%seconds_positions, report%seconds_transfer, &
            global_max(env, MPI_Wtime() - t_rebuild)]
        call log_remesh(report, sim%remesh_stages, mode, dx_old, dx_new, sim%time, sim%step, &
            sim%phys%density_method == DENSITY_SUMMATION)
    end subroutine remesh_state

    !> The transfer gives each new particle the mass of the volume it is handed, at the OLD
    !> kernel's scale; at the new one the kernel sums of volumes sum_j (m_j / rho_j) W_ij
    !> (walls included) are uneven where the old set was clumped or left a gap:
    !>  - a run whose density is the kernel sum of the masses (&numerics density_method =
    !>    'summation') discards the handed-on densities at its next step (the lid-driven cavity
    !>    at L/50, 0.01 s, refined: kernel sums up to 66 % off, the continued run stopped at
    !>    its first step with a density of 1500 kg/m^3);
    !>  - a continuity run keeps its densities, but its rates see the uneven volumes: a
    !>    developed flow keeps its particles half an OLD spacing off a body, and its refined
    !>    set was short of mass in the first new spacing (kernel sums 0.86 next to Morris'
    !>    sphere at L/10, 3000 s, refined; 0.62-1.29 over the L/25 cylinder at 6000 s, spread
    !>    6.4 % against the flow's 1.4 %). The continued runs' densities climbed to 1170 and
    !>    1158 kg/m^3 (the runs made fine throughout: 1027, 1051) and the cylinder's fluid
    !>    entered it (doc/validation.md).
    !> So the fluid masses are adjusted until the kernel sums give the handed-on densities
    !> (a continuity run's coarsening excepted: there the fine flow's particles next to a body
    !> hand the first coarse row kernel sums 4-6 % high, the adjustment took 5 % of its mass
    !> out to the next rows, and masses stay with their particles for the rest of the run: the
    !> coarsened L/50 cylinder continued 2.2 % faster than the L/25 run, against -0.5 %
    !> unadjusted; and a refined lattice, which its volumes being even is not relaxed: one
    !> pass on the Poiseuille recipe's channel moved its error at 1 s from 0.133 % to 0.150 %,
    !> and the pass cost a lattice's refinement half a time step):
    !> m_i <- m_i rho_i / sum_j m_j W_ij (walls keep theirs), at most MASS_PASSES passes, until
    !> their ratios agree to MASS_TOLERANCE (a common factor goes with the total mass); then
    !> scaled back to the total mass before the remesh, the momentum restored by one uniform
    !> velocity correction (as sph_remesh_driver does) and the energy sum m e by one uniform
    !> shift of e (restore_energy). A summation run goes on with the kernel sums as
    !> densities, a continuity run with the handed-on ones (its pressure field). The report
    !> takes the new totals and the
    !> largest mismatch before and after. Measured on that cavity: largest mismatch 0.66 ->
    !> 0.10, root mean square 0.093 -> 0.012 in 8 passes; the continued run's densities over
    !> 0.003 s spanned 938..1077 kg/m^3, the run made at L/100 from the start 953..1049 over
    !> its first 0.003 s. On the continuity runs above: 945..1057 and 967..1054 kg/m^3, no
    !> fluid inside the cylinder, the refined L/25 cylinder's mean velocity +0.47 % of the
    !> L/50 run's (-3.98 % unadjusted), the sphere's +1.7 % of the L/20 run's (+12 %)
    !> (doc/validation.md).
    subroutine consistent_masses(sim, env, report)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        type(remesh_report_t), intent(inout) :: report
        real(wp), allocatable :: handed(:)
        logical, allocatable :: fluid(:)
        integer :: n, pass
        integer(i8) :: n_fluid
        real(wp) :: worst, mass, ratio
        n = sim%p%n_owned
        allocate(fluid(n), handed(n))
        fluid = sim%p%kind(1:n) == KIND_FLUID
        handed = sim%p%rho(1:n)
        report%mass_passes = 0
        n_fluid = global_sum(env, int(count(fluid), i8))
        do pass = 0, MASS_PASSES
            call compute_summation_density(sim%phys, sim%p, sim%nl)
            worst = global_max(env, maxval(abs(sim%p%rho(1:n) / handed - 1.0_wp), mask=fluid))
            if (pass == 0) report%mismatch_before = worst
            report%mismatch_after = worst
            if (pass == MASS_PASSES) exit
            ! the passes even out the ratios; their common factor goes with the total mass
            ! restored below (a lattice's kernel sums differ from rho0 by its own factor)
            ratio = global_sum(env, sum(sim%p%rho(1:n) / handed, mask=fluid)) / &
                real(max(n_fluid, 1_i8), wp)
            if (global_max(env, maxval(abs(sim%p%rho(1:n) / (ratio * handed) - 1.0_wp), &
                mask=fluid)) < MASS_TOLERANCE) exit
            where (fluid) sim%p%m(1:n) = sim%p%m(1:n) * (handed / sim%p%rho(1:n))
            call refresh_ghosts(sim, env, HALO_GHOST)
            call build_mirrors(sim%phys, sim%solids, sim%p)
            report%mass_passes = pass + 1
        end do
        ! (no pass: the masses and totals are the transfer's; a lattice's refinement)
        if (report%mass_passes > 0) then
            ! the totals before the remesh
            mass = global_sum(env, accurate_sum(pack(sim%p%m(1:n), fluid)))
            where (fluid) sim%p%m(1:n) = sim%p%m(1:n) * (report%mass_before / mass)
            call restore_momentum(env, sim%p%dim, sim%p, fluid, report%momentum_before, &
                report%mass_before)
            call restore_energy(env, sim%p, fluid, report%energy_before)
            call fluid_mass_momentum(env, sim%p, report%mass_after, report%momentum_after, &
                report%energy_after)
            call refresh_ghosts(sim, env, HALO_GHOST)
            call build_mirrors(sim%phys, sim%solids, sim%p)
            call compute_summation_density(sim%phys, sim%p, sim%nl)
            ! what the run goes on with: the mismatch after the total mass was restored (the
            ! last pass's, before it, was logged: 3.7e-2 where the densities ended 6.5 % off)
            report%mismatch_after = global_max(env, maxval(abs(sim%p%rho(1:n) / handed - &
                1.0_wp), mask=fluid))
        end if
        if (sim%phys%density_method /= DENSITY_SUMMATION) where (fluid) sim%p%rho(1:n) = handed
        call refresh_ghosts(sim, env, HALO_DENSITY)
        call build_mirrors(sim%phys, sim%solids, sim%p)
    end subroutine consistent_masses

    !> Why a run cannot go on at the spacing a remesh of `mode` makes ('' when it can):
    !> spacing_problem_at that spacing.
    function spacing_problem(cfg, mode) result(problem)
        type(config_t), intent(in) :: cfg
        integer, intent(in) :: mode
        character(len=:), allocatable :: problem
        problem = spacing_problem_at(cfg, cfg%domain%dx * remesh_spacing_factor(mode))
    end function spacing_problem

    module procedure spacing_problem_at
        character(len=200) :: text
        character(len=:), allocatable :: errmsg
        type(config_t) :: after
        type(physics_t) :: phys
        type(solids_t) :: solids
        real(wp) :: side
        integer :: axis, stat, body
        problem = ''
        axis = misfit_axis(cfg%domain, dx_new)
        if (axis /= 0) then
            side = cfg%domain%box_hi(axis) - cfg%domain%box_lo(axis)
            write(text, '(a,es9.3,a,i0,a,es9.3,a,f0.3,a)') 'the new spacing ', dx_new, &
                ' m does not divide the box length on axis ', axis, ' (', side, ' m, ', &
                side / dx_new, ' spacings)'
            problem = trim(text)
            return
        end if
        after = cfg
        after%domain%dx = dx_new
        call physics_from_config(after, phys, stat, errmsg)
        if (stat /= 0) then
            problem = 'at the new spacing: ' // errmsg
            return
        end if
        do axis = 1, cfg%domain%dimension
            if (.not. cfg%domain%is_periodic(axis)) cycle
            side = cfg%domain%box_hi(axis) - cfg%domain%box_lo(axis)
            if (side >= 2.0_wp * phys%kernel%support) cycle
            write(text, '(a,es9.3,a,i0,a,es9.3,a)') 'the kernel support at the new spacing (', &
                phys%kernel%support, ' m) exceeds half the periodic box on axis ', axis, &
                ' (', side, ' m)'
            problem = trim(text)
            return
        end do
        ! the input's rule for a round body (sph_body_input): a radius of at least half the
        ! spacing (a coarsening left r = 0.36 and 0.25 new spacings and ran on, where a
        ! fresh start at that spacing is refused: fz44)
        if (.not. allocated(cfg%bodies)) return
        do body = 1, size(cfg%bodies)
            if (all(trim(cfg%bodies(body)%shape) /= [character(len=8) :: 'circle', 'sphere', &
                'cylinder'])) cycle
            if (cfg%bodies(body)%radius >= 0.5_wp * dx_new) cycle
            write(text, '(a,i0,a,es9.3,a,es9.3,a)') '&body ', body, " ('" // &
                trim(cfg%bodies(body)%name) // "') radius ", cfg%bodies(body)%radius, &
                ' m would be below half the new spacing (', dx_new, ' m), as no input allows'
            problem = trim(text)
            return
        end do
        ! Morris walls laid again at the new spacing: a body must still hold a site (a circle
        ! of 0.6 dx holds one at dx but may hold none at 2 dx: the run went on without it)
        if (phys%walls /= WALLS_MORRIS) return
        solids = solids_from_config(after)
        do body = 1, size(cfg%bodies)
            if (body_holds_site(after, solids, body, dx_new)) cycle
            write(text, '(a,i0,a,es9.3,a)') '&body ', body, " ('" // &
                trim(cfg%bodies(body)%name) // "') would hold no site of the lattice at " // &
                'the new spacing (', dx_new, " m), so with wall_model = 'morris' it would " // &
                'have no wall particle'
            problem = trim(text)
            return
        end do
    end procedure spacing_problem_at

    !> Why remeshing the fluid of sim (mode) cannot run on these ranks ('' if it can;
    !> collective): the new set must fit the ranks' neighbour lists and the nodes' memory
    !> (fit_on_nodes), with rank 0's serial work on top, where the new positions are made
    !> from all of the fluid. That work, measured on 2 ranks as rank 0's peak above the
    !> other's (2D and 3D): a refinement 81 and 45 bytes per new particle, a same-level
    !> remesh (refine, then coarsen the refined set) 976 and 3,700 bytes per particle, a
    !> coarsening 190 and 410; the bounds below are about 70 % of those.
    function remesh_capacity_problem(sim, env, mode) result(problem)
        type(simulation_t), intent(in) :: sim
        type(mpi_env_t), intent(in) :: env
        integer, intent(in) :: mode
        character(len=:), allocatable :: problem
        real(wp), parameter :: REFINE_BYTES(3) = [30.0_wp, 60.0_wp, 30.0_wp], &
            SAME_BYTES(3) = [300.0_wp, 700.0_wp, 2600.0_wp], &
            COARSEN_BYTES(3) = [60.0_wp, 130.0_wp, 280.0_wp]
        character(len=:), allocatable :: warning, verb
        real(wp) :: n_fluid, n_new, serial
        integer :: dim
        dim = sim%cfg%domain%dimension
        n_fluid = real(global_sum(env, int(count(sim%p%kind(1:sim%p%n_owned) == KIND_FLUID), &
            i8)), wp)
        select case (mode)
        case (REMESH_REFINE)
            n_new = 2.0_wp**dim * n_fluid
            serial = REFINE_BYTES(dim) * n_new
            verb = 'refining'
        case (REMESH_SAME)
            n_new = n_fluid
            serial = SAME_BYTES(dim) * n_fluid
            verb = 'remeshing at the same level'
        case default
            n_new = n_fluid / 2.0_wp**dim
            serial = COARSEN_BYTES(dim) * n_fluid
            verb = 'coarsening'
        end select
        call fit_on_nodes(sim, env, n_new, serial, problem, warning)
        if (len(problem) == 0) return
        problem = verb // ' the ' // sci_text(n_fluid) // ' fluid particles into about ' // &
            sci_text(n_new) // ' (rank 0 makes their positions)' // problem
    end function remesh_capacity_problem

    !> --check's estimate of a run's peak with &remesh (sph_stepper): rank 0 makes every new
    !> position, so the remesh's peak is there, above the memory measured after the set-up
    !> (process peaks on 1 rank, Release: the L/500 cylinder lattice, 220,420 particles,
    !> 2D; the 3D Poiseuille channel at L/80, 198,144): a same-level remesh 1,460 and 3,720
    !> bytes a fluid particle more, a coarsening 305 and 500; a refinement multiplies the
    !> fluid by 2^dim and takes 290 and 860 bytes a new particle on top of the refined
    !> state. The figures below round those up. Before, --check said nothing of it: 92 MB
    !> for a refining run that peaked at 2.9 GB.
    module procedure log_remesh_memory
        ! (the capacity check's bounds, remesh_capacity_problem, are about 70 % of rank 0's
        ! share on 2 ranks: a floor that refuses only what cannot fit; these are the whole
        ! peak on 1 rank, what a user sizes a job by)
        real(wp), parameter :: SAME_BYTES(3) = [1500.0_wp, 1500.0_wp, 3800.0_wp], &
            COARSEN_BYTES(3) = [320.0_wp, 320.0_wp, 520.0_wp], &
            REFINE_BYTES(3) = [300.0_wp, 300.0_wp, 900.0_wp]
        !> the libraries' share of a rank when the start-up's was not measured
        real(wp), parameter :: BASE_BYTES = 27.0e6_wp
        integer(i8) :: mine
        real(wp) :: n_fluid, largest, rank0, base, grown
        integer :: dim, mode
        mode = remesh_mode_code(sim%cfg%remesh%mode)
        if (mode == REMESH_NONE) return
        mine = peak_resident_bytes()
        if (global_max(env, merge(1_i8, 0_i8, mine < 0)) > 0) return
        dim = sim%cfg%domain%dimension
        n_fluid = real(global_sum(env, int(count(sim%p%kind(1:sim%p%n_owned) == &
            KIND_FLUID), i8)), wp)
        largest = real(global_max(env, mine), wp)
        rank0 = real(mine, wp)
        base = real(startup_memory_bytes(), wp)
        if (base <= 0.0_wp) base = BASE_BYTES
        call broadcast_value(rank0)
        call broadcast_value(base)
        select case (mode)
        case (REMESH_SAME)
            call log_info("check: &remesh mode = 'same': rank 0 needs about " // &
                mb_text(rank0 + SAME_BYTES(dim) * n_fluid) // ' while it remeshes (it ' // &
                'makes every new position), and keeps most of it for the next remesh')
        case (REMESH_COARSEN)
            call log_info("check: &remesh mode = 'coarsen': rank 0 needs about " // &
                mb_text(rank0 + COARSEN_BYTES(dim) * n_fluid) // ' while it coarsens ' // &
                '(it makes every new position)')
        case default
            ! the particles' share grows with them, the libraries' does not
            grown = base + 2.0_wp**dim * max(largest - base, 0.0_wp)
            call log_info("check: &remesh mode = 'refine': each refinement multiplies " // &
                'the fluid particles by ' // int_text(2_i8**dim) // ' and the memory ' // &
                'with them: after the first, about ' // mb_text(grown) // ' on the ' // &
                'largest rank, and rank 0 about ' // mb_text(base + 2.0_wp**dim * &
                max(rank0 - base, 0.0_wp) + REFINE_BYTES(dim) * 2.0_wp**dim * n_fluid) // &
                ' while it refines (it makes every new position)')
        end select
    contains
        !> rank 0's value on every rank
        subroutine broadcast_value(x)
            real(wp), intent(inout) :: x
            x = global_max(env, merge(x, -huge(1.0_wp), env%rank == 0))
        end subroutine broadcast_value
    end procedure log_remesh_memory

    !> The log lines of one remesh (rank 0 prints); stages as simulation_t's remesh_stages.
    subroutine log_remesh(report, stages, mode, dx_old, dx_new, time, step, summation)
        type(remesh_report_t), intent(in) :: report
        real(wp), intent(in) :: stages(3)
        integer, intent(in) :: mode
        real(wp), intent(in) :: dx_old, dx_new, time
        integer(i8), intent(in) :: step
        !> the run's density is the kernel sum (it goes on with the mismatch logged)
        logical, intent(in) :: summation
        character(len=400) :: line
        character(len=8), parameter :: names(0:3) = [character(len=8) :: 'none', 'refine', &
            'coarsen', 'same']
        real(wp) :: scale
        write(line, '(a,es12.5,a,i0,a,i0,a,i0,a,es10.3,a,es10.3,a)') 'remesh ' // &
            trim(names(mode)) // ' at t = ', time, ' s, step ', step, ': fluid particles ', &
            report%n_before, ' -> ', report%n_after, ', dx ', dx_old, ' -> ', dx_new, ' m'
        call log_info(trim(line))
        write(line, '(a,es23.15,a,es23.15,a,es10.3,a)') '  mass ', report%mass_before, &
            ' -> ', report%mass_after, ' kg (relative change ', &
            abs(report%mass_after - report%mass_before) / max(abs(report%mass_before), &
            tiny(1.0_wp)), ')'
        call log_info(trim(line))
        ! momentum change relative to the larger of |P| and (mass x largest speed scale 1)
        scale = max(norm2(report%momentum_before), tiny(1.0_wp))
        write(line, '(a,3es13.5,a,3es13.5,a,es10.3,a)') '  momentum ', report%momentum_before, &
            ' ->', report%momentum_after, ' kg m/s (|change| / |before| ', &
            norm2(report%momentum_after - report%momentum_before) / scale, ')'
        call log_info(trim(line))
        write(line, '(a,es23.15,a,es23.15,a,es10.3,a)') '  energy (sum m e) ', &
            report%energy_before, ' -> ', report%energy_after, ' J (relative change ', &
            abs(report%energy_after - report%energy_before) / max(abs(report%energy_before), &
            tiny(1.0_wp)), ')'
        call log_info(trim(line))
        write(line, '(a,f10.3,a,f10.3,a,3(f9.3,a))') '  time ', sum(stages), ' s (', &
            1.0e6_wp * sum(stages) / real(max(report%n_before, report%n_after, 1_i8), wp), &
            ' us per particle): new positions', stages(1), ' s, transfer', stages(2), &
            ' s, walls and neighbours', stages(3), ' s'
        call log_info(trim(line))
        write(line, '(a,i0,a,i0,a,i0,a,i0,a,i0,a,i0)') '  irregular cells ', &
            report%n_irregular, ', transfer fallbacks: mass ', report%n_mass_fallback, &
            ' (isolated ', report%n_isolated, '), velocity ', report%n_velocity_fallback, &
            ', density ', report%n_density_fallback, '; relaxation passes ', report%relax_passes
        call log_info(trim(line))
        if (report%n_unreached > 0) then
            write(line, '(a,i0,a)') '  dropped ', report%n_unreached, ' new point(s) with ' // &
                'no fluid within the support (e.g. in a slot between solids that holds none)'
            call log_info(trim(line))
            ! (a transfer that missed pairs would drop points too: say it once, loudly)
            if (logger_is_root()) call log_warn_counted('remesh_unreached', 'remesh: ' // &
                'new points that no old fluid particle reaches were dropped (the totals ' // &
                'are unchanged); expected only where the set-up left a region between ' // &
                'solids without fluid')
        end if
        if (report%n_in_gaps > 0) then
            write(line, '(a,i0,a,f0.1,a)') '  narrow gaps: ', report%n_in_gaps, ' fluid ' // &
                'particles left as they were (solids facing each other less than ', &
                NARROW_GAP, ' spacings apart)'
            call log_info(trim(line))
        end if
        if (report%mass_passes < 0) return
        write(line, '(a,i0,a,es9.2,a,es9.2,a)') '  fluid masses adjusted to the kernel sums in ', &
            report%mass_passes, ' passes, largest |kernel sum / handed-on density - 1| ', &
            report%mismatch_before, ' -> ', report%mismatch_after
        call log_info(trim(line))
        ! (a same-level remesh of a fluid at rest next to a small body: densities 0.4-6.5 %
        ! above rho0, and the fluid started to move)
        ! (a global figure, the same on every rank: rank 0 says it)
        if (report%mismatch_after > 0.01_wp .and. logger_is_root() .and. &
            summation) &
            call log_warn_counted('summation_mismatch', &
            'remesh: with the total mass held, the new set''s kernel sums stay up to ' // &
            trim(adjustl(fixed_text(100.0_wp * report%mismatch_after, 8, 2))) // &
            ' % off the densities handed on, and this summation run goes on with them ' // &
            '(a run with &numerics density_method = ''continuity'' would keep the ' // &
            'handed-on densities instead)')
    end subroutine log_remesh

    module procedure simulation_remesh_file
        type(simulation_t) :: sim
        type(config_t) :: cfg
        character(len=:), allocatable :: input_text, errmsg
        integer :: stat, dimension, mode, n, k
        integer(i8) :: n_rows, share, extra, offset, step
        real(wp) :: time, dx_file
        integer, allocatable :: keep(:)
        character(len=32) :: number
        character(len=:), allocatable :: problem
        logical :: for_study

        mode = remesh_mode_code(mode_name)
        if (mode <= REMESH_NONE) call fatal_collective('remesh', "unknown mode '" // &
            mode_name // "' (refine, coarsen or same)")
        call check_out_path(env, in_path, out_path)
        call read_snapshot_header(env, in_path, time, step, dimension, n_rows, input_text, &
            stat, errmsg)
        if (stat /= 0) call fatal_collective('remesh', errmsg)
        call config_parse(cfg, input_text, in_path // ' (stored input)', stat, errmsg, &
            check_paths=.false.)
        if (stat /= 0) call fatal_collective('remesh', errmsg)
        ! a file remeshed before carries its spacing; its stored input has the original dx
        dx_file = stored_spacing(env, in_path)
        if (dx_file < 0.0_wp) call fatal_collective('remesh', "'" // in_path // &
            "': its attribute dx is not a positive spacing: refused")
        if (dx_file > 0.0_wp) cfg%domain%dx = dx_file
        ! the remeshing rules take one spacing: the levels of a multi-resolution state would be
        ! mixed into one set (a two-level channel refined gave 2020 particles where 2000 were
        ! due, 7380 irregular cells). Every &region has a level >= 1: one region is two levels.
        ! (Refused before the spacing's warning below, which would not apply.)
        if (allocated(cfg%regions)) then
            if (size(cfg%regions) > 0) call fatal_collective('remesh', "IN '" // in_path // &
                "' holds a multi-resolution state (its stored input has &region groups): " // &
                '--remesh takes a single-resolution state (the resolution of regions is set ' // &
                'by their &region groups, doc/multiresolution.md); nothing written')
        end if
        ! a new spacing longer than a side of the box leaves no room for one particle (the
        ! transfer then blamed a narrow gap between solids: a cavity coarsened five times)
        do k = 1, cfg%domain%dimension
            if (cfg%domain%dx * remesh_spacing_factor(mode) <= cfg%domain%box_hi(k) - &
                cfg%domain%box_lo(k)) cycle
            write(number, '(es10.3)') cfg%domain%dx * remesh_spacing_factor(mode)
            call fatal_collective('remesh', 'the new spacing (' // trim(adjustl(number)) // &
                " m) is longer than the box on axis " // achar(iachar('0') + k) // &
                ': no particle fits; nothing written')
        end do
        ! OUT is still written (its particles are what the rules make, for study), but no run
        ! can continue it: say so before the work
        problem = spacing_problem(cfg, mode)
        for_study = len(problem) > 0
        if (for_study) call log_warn('remesh: ' // problem // ': no run can continue ' // &
            'OUT at that spacing (it is written for study)')
        call setup_common(sim, env, cfg)
        share = n_rows / env%nranks
        extra = mod(n_rows, int(env%nranks, i8))
        n = int(share + merge(1_i8, 0_i8, env%rank < extra))
        offset = env%rank * share + min(int(env%rank, i8), extra)
        call read_snapshot_rows(env, in_path, sim%p, offset, n, stat, errmsg)
        if (stat /= 0) call fatal_collective('remesh', errmsg)
        call check_read_particles(env, sim%p, 1, size(sim%solids%list), in_path, stat, errmsg)
        if (stat /= 0) call fatal_collective('remesh', errmsg)
        call check_fluid_outside_solids(env, sim%p, sim%solids, IN_SOLID_SLACK, in_path, stat, &
            errmsg)
        if (stat /= 0) call fatal_collective('remesh', errmsg)
        sim%time = time
        sim%step = step
        ! walls are made anew at the new spacing: only the fluid is kept
        keep = pack([(k, k = 1, sim%p%n_owned)], sim%p%kind(1:sim%p%n_owned) == KIND_FLUID)
        call particles_gather(sim%p, keep)
        sim%p%n_owned = size(keep)
        sim%p%n_total = sim%p%n_owned
        problem = remesh_capacity_problem(sim, env, mode)
        if (len(problem) > 0) call fatal_collective('remesh', problem // '; run on more ' // &
            merge('ranks', 'nodes', index(problem, 'neighbour list') > 0) // '; nothing written')
        call log_info('remesh: ' // in_path // ' -> ' // out_path)
        call remesh_state(sim, env, mode, .true.)
        ! a verlet run continues from the rates of the remeshed state (simulation_restart)
        if (sim%verlet) call evaluate_rates(sim, env)
        call write_checkpoint(env, sim%p, sim%domain, out_path, sim%time, sim%step, &
            sim%cfg%domain%dimension, code_version, input_text, '', stat, errmsg, &
            sim%cfg%domain%dx)
        if (stat == 2) call fatal_collective('remesh', errmsg)
        if (stat /= 0) call fatal_collective('remesh', errmsg, STATUS_OUTPUT_FAILED, &
            abort=stat == SNAPSHOT_NOT_CLOSED)
        write(number, '(es15.8)') sim%cfg%domain%dx
        ! (not where no run can continue it: the warning before the work said so, and the
        ! hint sent users to a restart that every input refuses)
        if (for_study) then
            call log_info('remesh: checkpoint ' // out_path // ' written (for study: no ' // &
                'run can continue it at dx = ' // trim(adjustl(number)) // ')')
        else
            call log_info('remesh: checkpoint ' // out_path // ' written; continue with ' // &
                '--restart ' // out_path // ' and &domain dx = ' // trim(adjustl(number)))
        end if
    end procedure simulation_remesh_file

    module procedure simulation_refine_regions_file
        type(simulation_t) :: sim
        type(config_t) :: stored
        character(len=:), allocatable :: input_text, errmsg
        integer :: stat, dimension
        integer(i8) :: n_rows, step
        real(wp) :: time
        real(wp), allocatable :: balance(:)
        if (.not. allocated(cfg%regions)) then
            call fatal_collective('remesh', "--regions: '" // regions_path // "' has no " // &
                '&region groups: nothing to refine; nothing written')
        else if (size(cfg%regions) == 0) then
            call fatal_collective('remesh', "--regions: '" // regions_path // "' has no " // &
                '&region groups: nothing to refine; nothing written')
        end if
        call check_out_path(env, in_path, out_path)
        ! IN must be uniform: a multi-resolution state has its regions (its stored input's)
        call read_snapshot_header(env, in_path, time, step, dimension, n_rows, input_text, &
            stat, errmsg)
        if (stat /= 0) call fatal_collective('remesh', errmsg)
        call config_parse(stored, input_text, in_path // ' (stored input)', stat, errmsg, &
            check_paths=.false.)
        if (stat == 0 .and. allocated(stored%regions)) then
            if (size(stored%regions) > 0) call fatal_collective('remesh', "IN '" // in_path // &
                "' holds a multi-resolution state already (its stored input has &region " // &
                'groups): --regions refines a uniform one; nothing written')
        end if
        ! OUT is continued with this input: one that ends at or before IN's state could not
        ! (the restart refused it only after OUT was written)
        if (time >= cfg%run%t_end * (1.0_wp - 1.0e-12_wp) .or. step >= cfg%run%max_steps) &
            call fatal_collective('remesh', "--regions: IN '" // in_path // "' is at or " // &
            "past the end of '" // regions_path // "' (&run t_end or max_steps): no run " // &
            'could continue OUT with it; raise them; nothing written')
        call log_info('remesh: ' // in_path // ' -> ' // out_path // ', the &region groups ' // &
            'of ' // regions_path // ' refined')
        ! the restart's path: the regions refined (refine_if_uniform), the levels started
        call simulation_restart(sim, env, cfg, in_path, 'remesh --regions')
        ! a verlet run continues from the rates of the state it reads (simulation_restart)
        if (sim%verlet) call evaluate_rates(sim, env)
        call checkpoint_balance(sim, balance)
        call write_checkpoint(env, sim%p, sim%domain, out_path, sim%time, sim%step, &
            sim%cfg%domain%dimension, code_version, sim%input_text, sim%snapshot_index, stat, &
            errmsg, sim%cfg%domain%dx, balance)
        if (stat == 2) call fatal_collective('remesh', errmsg)
        if (stat /= 0) call fatal_collective('remesh', errmsg, STATUS_OUTPUT_FAILED, &
            abort=stat == SNAPSHOT_NOT_CLOSED)
        call log_info('remesh: checkpoint ' // out_path // ' written; continue with ' // &
            'sphremesh ' // regions_path // ' --restart ' // out_path)
    end procedure simulation_refine_regions_file

    !> OUT of an offline remesh is a new file in a folder that takes it (collective): an
    !> existing file (IN itself, or a checkpoint the user still needs; a link, even one that
    !> points nowhere) is never replaced, and a folder that cannot take OUT.tmp (where the
    !> checkpoint goes first) is found out before the work. OUT.tmp is then made and kept
    !> (removed when the process leaves on an error): a second remesh to the same OUT finds
    !> it and stops (two at once both passed, and the second replaced the first's OUT; fz40).
    !> Stops every rank with a message otherwise.
    subroutine check_out_path(env, in_path, out_path)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: in_path, out_path
        logical :: out_exists, out_writable
        integer :: unit, ios
        ! OUT.tmp goes through MPI-IO, which takes MAX_FILE_PATH characters at most: found
        ! here, not after the work (the write then stopped the remesh with status 74)
        if (len(out_path) + len('.tmp') > MAX_FILE_PATH) &
            call fatal_collective('remesh', "OUT '" // out_path // "' is " // &
                int_text(int(len(out_path), i8)) // ' characters long: the checkpoint is ' // &
                'written (as OUT.tmp) through MPI-IO, which takes at most ' // &
                int_text(int(MAX_FILE_PATH - len('.tmp'), i8)) // ' for OUT; give a ' // &
                'shorter path (or a symbolic link to its folder); nothing done')
        out_exists = .false.
        if (env%rank == 0) out_exists = entry_kind(out_path) /= ENTRY_NONE
        if (global_max(env, merge(1_i8, 0_i8, out_exists)) > 0) then
            if (out_path == in_path) then
                call fatal_collective('remesh', "OUT '" // out_path // "' is IN: the " // &
                    'remeshed checkpoint is written to a new file; give OUT another name')
            end if
            call fatal_collective('remesh', "OUT '" // out_path // "' exists: the " // &
                'remeshed checkpoint is written to a new file and never replaces one; ' // &
                'give OUT another name or remove that file')
        end if
        ! OUT.tmp too is never replaced: the probe below, and the write, replaced a file of
        ! that name (through a link: its target truncated to 0 bytes) without a word
        if (env%rank == 0) out_exists = entry_kind(out_path // '.tmp') /= ENTRY_NONE
        if (global_max(env, merge(1_i8, 0_i8, out_exists)) > 0) &
            call fatal_collective('remesh', "'" // out_path // ".tmp' exists (left by an " // &
                'interrupted remesh to OUT, or a file of yours): the checkpoint is written ' // &
                'there first and never replaces a file; remove or rename it; nothing done')
        out_writable = .true.
        if (env%rank == 0) then
            ! (status 'new' creates it exclusively: never through a link)
            open(newunit=unit, file=out_path // '.tmp', status='new', action='write', &
                iostat=ios)
            out_writable = ios == 0
            if (out_writable) then
                close(unit)
                call remove_at_exit(out_path // '.tmp')
            end if
        end if
        if (global_max(env, merge(1_i8, 0_i8, .not. out_writable)) > 0) &
            call fatal_collective('remesh', "cannot create OUT '" // out_path // "' (its " // &
                "folder is missing or not writable, or '" // out_path // ".tmp' is a " // &
                'link); nothing done')
    end subroutine check_out_path
end submodule sph_stepper_remesh
