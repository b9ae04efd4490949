!> What the step in sph_stepper and its other submodules share: the set-up common to a
!> start, a restart and offline remeshing, migration and halo refresh, synchronisation
!> before output, rate evaluation and the time-step limit.
!> They are private helpers of sph_stepper, yet live in a submodule: gfortran 12 (Debian
!> bookworm's) gives a private procedure of a module local linkage, so a submodule compiled
!> apart cannot call it (undefined reference at link, reproduced with a three-file program);
!> a private separate module procedure defined in a submodule has global linkage. Their
!> interfaces and documentation are in sph_stepper.
submodule (sph_stepper) sph_stepper_shared
    use sph_config, only: config_to_text
    use sph_memory, only: node_memory_bytes
    use sph_particles, only: particles_init, particles_enable, HALO_DENSITY, HALO_STRAIN, &
        particles_append, particles_free
    use sph_physics, only: physics_from_config, VISCOSITY_STRAIN_RATE, WALLS_MORRIS, &
        WALL_PRESSURE_EXTRAPOLATED, stiffest_viscosity
    use sph_walls, only: solids_from_config
    use sph_domain, only: domain_create, migrate_particles
    use sph_halo, only: halo_refresh
    use sph_rates, only: compute_summation_density, compute_strain_rate, compute_rates, &
        extrapolate_wall_density, local_motion_maxima
    use sph_timestep, only: timestep_limits, level_substeps
    use sph_reference, only: reference_from_config
    use sph_zones, only: zones_create
    use sph_level_balance, only: PUSH_SUMS, mark_near_virtual, level_push_sums, &
        remove_virtual_push
    use sph_step_timers, only: TIMER_RATES, TIMER_IDLE
    implicit none

contains

    module procedure setup_common
        integer :: stat, axis
        character(len=:), allocatable :: errmsg
        logical :: periodic(3)
        integer(i8) :: total, available
        character(len=200) :: line

        ! a size given for the nodes' memory (sph_memory) must read as one, on every rank
        call node_memory_bytes(total, available, errmsg)
        if (global_max(env, int(merge(1, 0, len(errmsg) > 0), i8)) > 0) then
            if (len(errmsg) == 0) errmsg = 'SPHREMESH_NODE_MEMORY is not a size on some rank'
            call fatal_collective('set-up', errmsg)
        end if
        sim%cfg = cfg
        sim%input_text = config_to_text(cfg)
        sim%snapshot_index = ''
        allocate(sim%checkpoints(0))
        call physics_from_config(cfg, sim%phys, stat, errmsg)
        if (stat /= 0) call fatal_collective('set-up', errmsg)
        ! (the input's own dx passed sph_config's check_periodic_sides: here a checkpoint's
        ! spacing, which a remesh written for study may have made too coarse for the box)
        do axis = 1, cfg%domain%dimension
            if (cfg%domain%is_periodic(axis) .and. &
                cfg%domain%box_hi(axis) - cfg%domain%box_lo(axis) < &
                2.0_wp * sim%phys%kernel%support) then
                write(line, '(a,i0,a,es9.3,a,es9.3,a,es9.3,a)') 'the periodic side on ' // &
                    'axis ', axis, ' (', cfg%domain%box_hi(axis) - cfg%domain%box_lo(axis), &
                    ' m) is less than two kernel supports (2 x ', sim%phys%kernel%support, &
                    ' m) at the spacing dx = ', cfg%domain%dx, ' m'
                call fatal_collective('set-up', trim(line) // ' (&domain dx, or the ' // &
                    'spacing of the checkpoint continued or remeshed: one that a remesh ' // &
                    'wrote for study cannot be set up)')
            end if
        end do
        sim%solids = solids_from_config(cfg)
        sim%zones = zones_create(cfg, sim%solids)
        call setup_level_physics(sim)
        allocate(sim%wall_forces(3, 2, size(sim%solids%list)))
        sim%wall_forces = 0.0_wp
        allocate(sim%force_integral(3, 2, size(sim%solids%list)), source=0.0_wp)
        sim%force_window = 0.0_wp
        ! multi-resolution Verlet steps level by level (max_subcycles = 1: all alike)
        sim%subcycling = multires(sim) .and. trim(cfg%numerics%integrator) == 'verlet'
        allocate(sim%level_substeps(0:sim%zones%n_levels - 1), &
            sim%level_span(0:sim%zones%n_levels - 1), &
            sim%level_elapsed(0:sim%zones%n_levels - 1))
        sim%level_substeps = 1
        sim%level_span = 0.0_wp
        sim%level_elapsed = 0.0_wp
        sim%cycle_step = 0
        if (sim%subcycling) then
            allocate(sim%level_wall_forces(3, 2, size(sim%solids%list), &
                0:sim%zones%n_levels - 1))
            sim%level_wall_forces = 0.0_wp
        end if
        call reference_from_config(cfg, sim%ref, stat, errmsg)
        if (stat /= 0) call fatal_collective('set-up', errmsg)
        periodic = .false.
        do axis = 1, cfg%domain%dimension
            periodic(axis) = cfg%domain%is_periodic(axis)
        end do
        call domain_create(sim%domain, env, cfg%domain%dimension, cfg%domain%box_lo, &
            cfg%domain%box_hi, periodic)
        call particles_init(sim%p, 1024, cfg%domain%dimension)
        ! the fields only some models use (sph_particles)
        call particles_enable(sim%p, transport=sim%phys%transport_velocity, &
            strain=sim%phys%viscosity == VISCOSITY_STRAIN_RATE)
        if (multires(sim) .and. sim%zones%split_virtuals) call add_lineage_field(sim%p)
        ! ghosts reach the support plus a skin that covers any motion within one step, plus
        ! the neighbour-list skin that particles may use up over the steps between rebuilds
        sim%skin = 2.0_wp * cfg%numerics%cfl * sim%phys%kernel%h
        sim%list_skin = 0.1_wp * sim%phys%kernel%h
        sim%time = 0.0_wp
        sim%step = 0
        sim%next_remesh_time = huge(1.0_wp)
        if (cfg%remesh%every_time > 0.0_wp) sim%next_remesh_time = cfg%remesh%every_time
        sim%verlet = trim(cfg%numerics%integrator) == 'verlet'
        sim%rates_stale = .true.
    end procedure setup_common

    !> The physics of every resolution level: the kernel (and what scales with it) at the
    !> level's spacing dx / 2^level; one sound speed for all (the largest), so the equation of
    !> state is the same on both sides of an interface.
    subroutine setup_level_physics(sim)
        type(simulation_t), intent(inout) :: sim
        type(config_t) :: level_cfg
        integer :: lv, stat
        character(len=:), allocatable :: errmsg
        allocate(sim%level_phys(0:sim%zones%n_levels - 1))
        sim%level_phys(0) = sim%phys
        do lv = 1, sim%zones%n_levels - 1
            level_cfg = sim%cfg
            level_cfg%domain%dx = sim%cfg%domain%dx / 2.0_wp**lv
            call physics_from_config(level_cfg, sim%level_phys(lv), stat, errmsg)
            if (stat /= 0) call fatal_collective('set-up', errmsg)
        end do
        sim%phys%c = maxval(sim%level_phys(:)%c)
        sim%level_phys(:)%c = sim%phys%c
    end subroutine setup_level_physics

    module procedure multires
        multires = sim%zones%n_levels > 1
    end procedure multires

    module procedure refresh_ghosts
        integer :: previous
        call timers_enter(sim%timers, TIMER_HALO, previous)
        call halo_refresh(sim%halo, env, sim%p, fields)
        call timers_leave(sim%timers, previous)
    end procedure refresh_ghosts

    module procedure migrate
        integer :: previous
        call timers_enter(sim%timers, TIMER_HALO, previous)
        call migrate_particles(sim%domain, env, sim%p)
        call timers_leave(sim%timers, previous)
    end procedure migrate

    module procedure synchronise
        if (sim%drift <= 0.0_wp) return
        call migrate(sim, env)
        call simulation_prepare_neighbours(sim, env)
        call update_pressure(sim%phys, sim%p, 1, sim%p%n_total)
    end procedure synchronise

    module procedure evaluate_rates
        integer :: previous
        call timers_enter(sim%timers, TIMER_RATES, previous)
        sim%kick_maxima_step = -1
        if (sim%timers%current /= TIMER_IDLE) sim%timers%rate_evaluations = &
            sim%timers%rate_evaluations + 1
        if (multires(sim)) then
            call evaluate_level_rates(sim, env, levels)
        else
            call evaluate_uniform_rates(sim, env)
        end if
        call timers_leave(sim%timers, previous)
    end procedure evaluate_rates

    !> evaluate_rates with one level.
    subroutine evaluate_uniform_rates(sim, env)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        if (sim%phys%density_method == DENSITY_SUMMATION) then
            call compute_summation_density(sim%phys, sim%p, sim%nl)
            call refresh_ghosts(sim, env, HALO_DENSITY)
            call build_mirrors(sim%phys, sim%solids, sim%p)
        end if
        call update_pressure(sim%phys, sim%p, 1, sim%p%n_total)
        if (sim%phys%walls == WALLS_MORRIS .and. &
            sim%phys%wall_pressure == WALL_PRESSURE_EXTRAPOLATED) then
            call extrapolate_wall_density(sim%phys, sim%p, sim%nl)
            call refresh_ghosts(sim, env, HALO_DENSITY)
            call update_pressure(sim%phys, sim%p, 1, sim%p%n_total)
        end if
        if (sim%phys%viscosity == VISCOSITY_STRAIN_RATE) then
            call compute_strain_rate(sim%phys, sim%p, sim%nl, sim%solids)
            call refresh_ghosts(sim, env, HALO_STRAIN)
            call build_mirrors(sim%phys, sim%solids, sim%p)
        end if
        sim%wall_forces = 0.0_wp
        call compute_rates(sim%phys, sim%p, sim%nl, sim%solids, sim%wall_forces)
    end subroutine evaluate_uniform_rates

    !> evaluate_rates for several levels: every stage level by level with the level's physics
    !> (the neighbour list pairs particles of one level only), one halo refresh per stage.
    !> levels: only these levels' stages (sub-cycling). With sub-cycling the forces on the
    !> solids are the sum of each level's last ones.
    subroutine evaluate_level_rates(sim, env, levels)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        logical, intent(in), optional :: levels(0:)
        logical :: active(0:sim%zones%n_levels - 1)
        real(wp) :: solid_force(3, 0:sim%zones%n_levels - 1)
        integer :: lv
        active = .true.
        solid_force = 0.0_wp
        if (present(levels)) active = levels
        if (sim%phys%density_method == DENSITY_SUMMATION) then
            do lv = 0, sim%zones%n_levels - 1
                if (active(lv)) call compute_summation_density(sim%level_phys(lv), sim%p, &
                    sim%nl, lv)
            end do
            call refresh_ghosts(sim, env, HALO_DENSITY)
        end if
        call update_pressure(sim%phys, sim%p, 1, sim%p%n_total)
        if (sim%phys%walls == WALLS_MORRIS .and. &
            sim%phys%wall_pressure == WALL_PRESSURE_EXTRAPOLATED) then
            do lv = 0, sim%zones%n_levels - 1
                if (active(lv)) call extrapolate_wall_density(sim%level_phys(lv), sim%p, &
                    sim%nl, lv)
            end do
            call refresh_ghosts(sim, env, HALO_DENSITY)
            call update_pressure(sim%phys, sim%p, 1, sim%p%n_total)
        end if
        if (sim%phys%viscosity == VISCOSITY_STRAIN_RATE) then
            do lv = 0, sim%zones%n_levels - 1
                if (active(lv)) call compute_strain_rate(sim%level_phys(lv), sim%p, sim%nl, &
                    sim%solids, lv)
            end do
            call refresh_ghosts(sim, env, HALO_STRAIN)
        end if
        if (.not. sim%subcycling) then
            sim%wall_forces = 0.0_wp
            do lv = 0, sim%zones%n_levels - 1
                ! each level's force on the solids, for the balance below
                solid_force(:, lv) = -solid_total(sim%wall_forces)
                call compute_rates(sim%level_phys(lv), sim%p, sim%nl, sim%solids, &
                    sim%wall_forces, lv)
                solid_force(:, lv) = solid_force(:, lv) + solid_total(sim%wall_forces)
            end do
        else
            do lv = 0, sim%zones%n_levels - 1
                if (.not. active(lv)) cycle
                sim%level_wall_forces(:, :, :, lv) = 0.0_wp
                call compute_rates(sim%level_phys(lv), sim%p, sim%nl, sim%solids, &
                    sim%level_wall_forces(:, :, :, lv), lv)
                solid_force(:, lv) = solid_total(sim%level_wall_forces(:, :, :, lv))
            end do
            sim%wall_forces = sum(sim%level_wall_forces, dim=4)
        end if
        if (sim%cfg%refinement%conserve) call balance_virtual_push(sim, env, active, solid_force)
    contains
        !> The force on all solids (pressure and viscous parts, every solid) of wall_forces.
        function solid_total(forces) result(total)
            real(wp), intent(in) :: forces(:, :, :)
            real(wp) :: total(3)
            integer :: a
            do a = 1, 3
                total(a) = sum(forces(a, :, :))
            end do
        end function solid_total
    end subroutine evaluate_level_rates

    !> &refinement conserve, after the rates of the `active` levels (sph_level_balance): each
    !> such level's virtual push V = sum m dv/dt - F sum m + D over its real fluid (D its
    !> force on the solids, this rank's part in solid_force), then the levels' pushes
    !> together (the latest of the levels not evaluated now: sub-cycling) removed as one
    !> acceleration from the real particles of the active levels next to virtual ones, so
    !> that over a cycle every level's share of it goes (collective). With &refinement
    !> remove_push = .false. the push is measured (for the log) and left in place.
    subroutine balance_virtual_push(sim, env, active, solid_force)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        logical, intent(in) :: active(0:)
        real(wp), intent(in) :: solid_force(:, 0:)
        real(wp) :: sums(PUSH_SUMS + 3, 0:sim%zones%n_levels - 1), push(3), near_mass
        real(wp), allocatable :: supports(:)
        integer :: lv, n
        n = sim%zones%n_levels
        ! the particles next to virtual ones now (mark_near_virtual), among those that can
        ! be while the neighbour list lasts, marked again for each new list
        ! (the supports copied first: the strided section was a temporary that Debug
        ! builds warn about at every new list)
        supports = sim%level_phys(:)%kernel%support
        if (sim%near_virtual_list /= sim%nl%generation) then
            if (allocated(sim%near_virtual)) then
                if (size(sim%near_virtual) < sim%p%n_owned) &
                    deallocate(sim%near_virtual, sim%near_virtual_candidates)
            end if
            if (.not. allocated(sim%near_virtual)) &
                allocate(sim%near_virtual(max(sim%p%n_owned, 1)), &
                sim%near_virtual_candidates(max(sim%p%n_owned, 1)))
            call mark_near_virtual(sim%p, sim%nl, supports + sim%list_skin, &
                sim%near_virtual_candidates)
            sim%near_virtual_list = sim%nl%generation
        end if
        call mark_near_virtual(sim%p, sim%nl, supports, sim%near_virtual, &
            sim%near_virtual_candidates)
        sums = 0.0_wp
        do lv = 0, n - 1
            if (.not. active(lv)) cycle
            call level_push_sums(sim%p, lv, sim%near_virtual, sums(1:PUSH_SUMS, lv))
            sums(PUSH_SUMS + 1:, lv) = solid_force(:, lv)
        end do
        sums = reshape(global_sum(env, reshape(sums, [size(sums)])), shape(sums))
        do lv = 0, n - 1
            if (.not. active(lv)) cycle
            sim%level_push(:, lv) = sums(1:3, lv) - sim%level_phys(lv)%body_force * &
                sums(4, lv) + sums(PUSH_SUMS + 1:, lv)
            sim%level_push_mass(lv) = sums(5, lv)
        end do
        push = sum(sim%level_push, dim=2)
        near_mass = sum(sim%level_push_mass)
        ! measured for the log either way, removed only when asked
        sim%push_removed = sim%push_removed + push
        sim%push_evaluations = sim%push_evaluations + 1
        if (.not. sim%cfg%refinement%remove_push) return
        if (near_mass <= 0.0_wp) return
        do lv = 0, n - 1
            if (active(lv)) call remove_virtual_push(sim%p, lv, sim%near_virtual, &
                push / near_mass)
        end do
    end subroutine balance_virtual_push

    module procedure planned_substeps
        real(wp) :: limit(0:sim%zones%n_levels - 1)
        type(timestep_limits_t) :: lim
        integer :: lv
        do lv = 0, sim%zones%n_levels - 1
            lim = timestep_limits(sim%level_phys(lv)%kernel%h, sim%phys%c, &
                sim%last_limits%max_speed, stiffest_viscosity(sim%phys), &
                sim%last_limits%max_accel, &
                sim%cfg%numerics%cfl, sim%cfg%numerics%viscous_safety, &
                sim%cfg%numerics%force_safety)
            limit(lv) = lim%dt
        end do
        k = level_substeps(dt, limit, sim%cfg%refinement%max_subcycles)
    end procedure planned_substeps

    module procedure stable_timestep
        real(wp) :: maxima(2), h
        ! the last Verlet kick's, while nothing has changed the particles since
        if (sim%kick_maxima_step == sim%step) then
            maxima = sim%kick_maxima
        else
            maxima = global_max(env, local_motion_maxima(sim%p, sim%phys%transport_velocity))
        end if
        ! the finest level's smoothing length sets the step
        h = sim%phys%kernel%h
        if (multires(sim)) h = minval(sim%level_phys(:)%kernel%h)
        lim = timestep_limits(h, sim%phys%c, maxima(1), stiffest_viscosity(sim%phys), maxima(2), &
            sim%cfg%numerics%cfl, sim%cfg%numerics%viscous_safety, sim%cfg%numerics%force_safety)
    end procedure stable_timestep

    module procedure lay_lattice_walls
        type(particles_t) :: walls
        integer, allocatable :: keep(:)
        integer(i8) :: base
        integer :: k, c
        keep = pack([(k, k = 1, sim%p%n_owned)], sim%p%kind(1:sim%p%n_owned) == KIND_FLUID)
        call particles_gather(sim%p, keep)
        sim%p%n_owned = size(keep)
        sim%p%n_total = sim%p%n_owned
        base = global_max_id(env, sim%p%id, sim%p%n_owned)
        call particles_init(walls, 1024, sim%cfg%domain%dimension)
        call create_lattice_particles(sim%cfg, sim%phys, sim%solids, sim%domain, walls, &
            walls_only=.true.)
        keep = pack([(k, k = 1, walls%n_owned)], walls%kind(1:walls%n_owned) /= KIND_FLUID)
        c = sim%p%n_owned
        call particles_append(sim%p, walls, keep)
        sim%p%id(c + 1:c + size(keep)) = base + sim%p%id(c + 1:c + size(keep))
        call particles_free(walls)
    end procedure lay_lattice_walls

    module procedure next_multiple
        ! (a ratio beyond the largest real would overflow: a trap in a debug build)
        if (period <= time / (0.25_wp * huge(1.0_wp))) then
            next = time
            return
        end if
        next = period * (aint(time / period * (1.0_wp + 1.0e-12_wp)) + 1.0_wp)
        if (.not. next > time) next = time
    end procedure next_multiple

    module procedure halo_reach
        reach = sim%phys%kernel%support + sim%skin + sim%list_skin
        if (sim%zones%n_levels > 1) reach = max(reach, 2.0_wp * &
            sqrt(real(sim%cfg%domain%dimension, wp)) * sim%cfg%domain%dx + sim%skin + &
            sim%list_skin)
        ! (mirror images of the box's plane walls, and through its concave corners, lie
        ! nearer their sources than any fluid they act on; bodies, whose convex corners would
        ! need three supports, are refused with mirror walls: sph_body_input)
    end procedure halo_reach

    module procedure hold_real_mass
        real(wp) :: mass
        mass = global_sum(env, real_fluid_mass(sim%p))
        if (mass <= 0.0_wp) return
        call scale_masses(sim%p, sim%reference_mass / mass)
        sim%mass_restored = sim%mass_restored + (sim%reference_mass - mass)
    end procedure hold_real_mass
end submodule sph_stepper_shared
