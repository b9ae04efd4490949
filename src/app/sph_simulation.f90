!> The run driver: set-up, the time loop, logging, snapshots and the analytic error report.
!> This is where communication is orchestrated (migration, halo build and refresh between
!> the stages of a step); the physics modules it calls make no MPI calls.
module sph_simulation
    use sph_kinds, only: wp, i8
    use sph_config, only: config_t, config_to_text
    use sph_mpi_env, only: mpi_env_t, global_sum, global_max, global_min
    use sph_errors, only: fatal_collective
    use sph_logger, only: log_info
    use sph_particles, only: particles_t, particles_init, particles_gather, KIND_FLUID, &
        HALO_MOVE, HALO_DENSITY, HALO_STRAIN
    use sph_physics, only: physics_t, physics_from_config, DENSITY_SUMMATION, &
        VISCOSITY_STRAIN_RATE, WALLS_MIRROR, WALLS_REPULSIVE_MIRROR
    use sph_kernel, only: kernel_name
    use sph_walls, only: solids_from_config, build_mirrors, wall_layers
    use sph_solids, only: solids_t
    use sph_domain, only: domain_t, domain_create, domain_partition, migrate_particles, &
        domain_imbalance
    use sph_halo, only: halo_t, halo_setup, halo_build, halo_refresh
    use sph_cell_list, only: neighbour_list_t, build_neighbour_list, cell_sort_order
    use sph_rates, only: update_pressure, compute_summation_density, compute_strain_rate, &
        compute_rates, local_max_speed, local_max_acceleration
    use sph_timestep, only: timestep_limits_t, timestep_limits
    use sph_integrator, only: save_step_start, advance
    use sph_initial, only: create_lattice_particles
    use sph_analytic, only: couette_velocity, poiseuille_velocity
    use sph_snapshot, only: write_snapshot, snapshot_filename
    use sph_checkpoint, only: write_checkpoint, read_checkpoint, checkpoint_filename, &
        find_latest_checkpoint
    use sph_xdmf, only: xdmf_index_entry, write_xdmf
    use sph_filesystem, only: delete_file
    use sph_version, only: code_version
    implicit none
    private
    public :: simulation_t, simulation_setup, simulation_step, simulation_run
    public :: simulation_analytic_error, simulation_prepare_neighbours, simulation_free
    public :: simulation_restart, simulation_write_checkpoint

    type :: simulation_t
        type(config_t) :: cfg
        type(physics_t) :: phys
        type(solids_t) :: solids   !< walls and bodies
        type(domain_t) :: domain
        type(halo_t) :: halo
        type(particles_t) :: p
        type(neighbour_list_t) :: nl
        real(wp) :: time = 0.0_wp
        integer(i8) :: step = 0
        real(wp) :: skin = 0.0_wp          !< ghost skin: covers any motion within one step
        real(wp) :: list_skin = 0.0_wp     !< neighbour-list skin: lets a list serve both stages
        type(timestep_limits_t) :: last_limits
        character(len=:), allocatable :: input_text
        character(len=:), allocatable :: snapshot_index   !< one line per snapshot, for XDMF
        character(len=512), allocatable :: checkpoints(:) !< written by this run, oldest first
    end type simulation_t

contains

    !> What a fresh start and a restart share: parameters, walls, the domain, empty particles.
    subroutine setup_common(sim, env, cfg)
        type(simulation_t), intent(out) :: sim
        type(mpi_env_t), intent(in) :: env
        type(config_t), intent(in) :: cfg
        integer :: stat, axis
        character(len=:), allocatable :: errmsg
        logical :: periodic(3)

        sim%cfg = cfg
        sim%input_text = config_to_text(cfg)
        sim%snapshot_index = ''
        allocate(sim%checkpoints(0))
        call physics_from_config(cfg, sim%phys, stat, errmsg)
        if (stat /= 0) call fatal_collective('set-up', errmsg)
        do axis = 1, cfg%domain%dimension
            if (cfg%domain%is_periodic(axis) .and. &
                cfg%domain%box_hi(axis) - cfg%domain%box_lo(axis) < &
                2.0_wp * sim%phys%kernel%support) then
                call fatal_collective('set-up', &
                    'a periodic box side must be at least twice the ' // &
                    'kernel support radius (&domain box_lo/box_hi, &domain dx, &numerics h_factor)')
            end if
        end do
        sim%solids = solids_from_config(cfg)
        periodic = .false.
        do axis = 1, cfg%domain%dimension
            periodic(axis) = cfg%domain%is_periodic(axis)
        end do
        call domain_create(sim%domain, env, cfg%domain%dimension, cfg%domain%box_lo, &
            cfg%domain%box_hi, periodic)
        call particles_init(sim%p, 1024, cfg%domain%dimension)
        ! ghosts reach the support plus a skin that covers any motion within one step
        sim%skin = 2.0_wp * cfg%numerics%cfl * sim%phys%kernel%h
        sim%list_skin = 0.1_wp * sim%phys%kernel%h
        sim%time = 0.0_wp
        sim%step = 0
    end subroutine setup_common

    !> Build everything from a validated configuration (collective).
    subroutine simulation_setup(sim, env, cfg)
        type(simulation_t), intent(out) :: sim
        type(mpi_env_t), intent(in) :: env
        type(config_t), intent(in) :: cfg
        call setup_common(sim, env, cfg)
        call create_lattice_particles(cfg, sim%phys, sim%solids, sim%domain, sim%p)
        ! balance by particle count (walls included: they cost work too)
        call domain_partition(sim%domain, env, sim%p%x, sim%p%n_owned)
        call migrate_particles(sim%domain, env, sim%p)
        call halo_setup(sim%halo, sim%domain, sim%phys%kernel%support + sim%skin)
        call simulation_prepare_neighbours(sim, env)
        call log_setup(sim, env)
    end subroutine simulation_setup

    !> Continue from a checkpoint file, or from the newest complete one in a directory.
    !> On the rank count that wrote it the run continues bit for bit.
    subroutine simulation_restart(sim, env, cfg, from)
        type(simulation_t), intent(out) :: sim
        type(mpi_env_t), intent(in) :: env
        type(config_t), intent(in) :: cfg
        character(len=*), intent(in) :: from
        character(len=:), allocatable :: path, skipped, errmsg, stored_input, index_text
        integer :: stat
        logical :: same_layout, is_directory
        character(len=256) :: line

        call setup_common(sim, env, cfg)
        inquire(file=trim(from) // '/.', exist=is_directory)
        if (is_directory) then
            call find_latest_checkpoint(env, from, trim(cfg%run%case_name), path, skipped, stat, &
                errmsg)
            if (stat /= 0) call fatal_collective('restart', errmsg)
            if (len(skipped) > 0) call log_info('restart: skipped' // skipped)
        else
            path = from
        end if
        call read_checkpoint(env, path, sim%p, sim%domain, sim%time, sim%step, stored_input, &
            index_text, same_layout, stat, errmsg)
        if (stat /= 0) call fatal_collective('restart', errmsg)
        sim%snapshot_index = index_text
        if (.not. same_layout) then
            call domain_partition(sim%domain, env, sim%p%x, sim%p%n_owned)
            call migrate_particles(sim%domain, env, sim%p)
        end if
        call halo_setup(sim%halo, sim%domain, sim%phys%kernel%support + sim%skin)
        call simulation_prepare_neighbours(sim, env)
        call update_pressure(sim%phys, sim%p, 1, sim%p%n_total)
        write(line, '(a,es12.5,a,i0,a)') 'continuing from ' // path // ' at t = ', sim%time, &
            ' s, step ', sim%step, merge(' (same decomposition)      ', &
                                         ' (decomposition rebuilt)   ', same_layout)
        call log_info(trim(line))
        if (stored_input /= sim%input_text) call log_info('restart: the input differs from ' // &
            'the one stored in the checkpoint; the new input is used')
        call log_setup(sim, env)
    end subroutine simulation_restart

    subroutine log_setup(sim, env)
        type(simulation_t), intent(in) :: sim
        type(mpi_env_t), intent(in) :: env
        character(len=256) :: line
        write(line, '(a,es12.5,a,es12.5,a,es12.5,a)') 'physics: h = ', sim%phys%kernel%h, &
            ' m (kernel ' // kernel_name(sim%phys%kernel%id) // ', support ', &
            sim%phys%kernel%support, ' m), c = ', sim%phys%c, ' m/s'
        call log_info(trim(line))
        write(line, '(a,es12.5,a,es12.5,a,i0)') '         velocity scale ', &
            sim%phys%velocity_scale, ' m/s, length scale ', sim%phys%length_scale, &
            ' m, wall layers ', wall_layers(sim%phys)
        call log_info(trim(line))
        write(line, '(a,i0,a,i0,a,f6.3)') 'particles: ', global_sum(env, int(sim%p%n_owned, i8)), &
            ' real (fluid ', global_sum(env, int(count(sim%p%kind(1:sim%p%n_owned) == KIND_FLUID), &
                i8)), &
            '), load imbalance ', domain_imbalance(env, sim%p%n_owned)
        call log_info(trim(line))
    end subroutine log_setup

    !> Write a checkpoint of the current state and keep only the newest checkpoints_kept of
    !> those this run wrote (collective).
    subroutine simulation_write_checkpoint(sim, env)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        character(len=:), allocatable :: path, errmsg
        integer :: stat
        path = checkpoint_filename(trim(sim%cfg%output%output_dir), trim(sim%cfg%run%case_name), &
            sim%step)
        call write_checkpoint(env, sim%p, sim%domain, path, sim%time, sim%step, &
            sim%cfg%domain%dimension, &
            code_version, sim%input_text, sim%snapshot_index, stat, errmsg)
        if (stat /= 0) call fatal_collective('checkpoint', errmsg)
        if (all(sim%checkpoints /= path)) &
            sim%checkpoints = [character(len=512) :: sim%checkpoints, path]
        do while (size(sim%checkpoints) > sim%cfg%restart%checkpoints_kept)
            if (env%rank == 0) call delete_file(trim(sim%checkpoints(1)))
            sim%checkpoints = sim%checkpoints(2:)
        end do
        call log_info('checkpoint: ' // path)
    end subroutine simulation_write_checkpoint

    subroutine simulation_free(sim)
        type(simulation_t), intent(inout) :: sim
        sim%p%n_owned = 0
    end subroutine simulation_free

    !> After particles moved between ranks: order owned particles by cell (memory locality),
    !> rebuild ghosts and mirrors and the neighbour list.
    subroutine simulation_prepare_neighbours(sim, env)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        integer, allocatable :: order(:)
        allocate(order(sim%p%n_owned))
        call cell_sort_order(sim%p%x, sim%p%n_owned, sim%p%dim, sim%phys%kernel%support, order)
        call particles_gather(sim%p, order)
        sim%p%n_ghost = 0
        sim%p%n_total = sim%p%n_owned
        call halo_build(sim%halo, sim%domain, env, sim%p)
        call refresh_neighbours(sim)
    end subroutine simulation_prepare_neighbours

    !> Mirrors and the neighbour list for the current positions. The list holds pairs within
    !> support + list_skin, so it stays complete while no pair closes in by more than the skin.
    subroutine refresh_neighbours(sim)
        type(simulation_t), intent(inout) :: sim
        call build_mirrors(sim%phys, sim%solids, sim%p)
        call build_neighbour_list(sim%p%x, sim%p%n_total, sim%p%n_owned, sim%p%dim, &
            sim%phys%kernel%support + sim%list_skin, sim%nl)
    end subroutine refresh_neighbours

    !> Rates at the current state. Ghost fields are current on entry; stages that produce a
    !> field the neighbours need (summation density, strain rate) refresh the ghosts.
    subroutine evaluate_rates(sim, env)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        if (sim%phys%density_method == DENSITY_SUMMATION) then
            call compute_summation_density(sim%phys, sim%p, sim%nl)
            call halo_refresh(sim%halo, env, sim%p, HALO_DENSITY)
            call build_mirrors(sim%phys, sim%solids, sim%p)
        end if
        call update_pressure(sim%phys, sim%p, 1, sim%p%n_total)
        if (sim%phys%viscosity == VISCOSITY_STRAIN_RATE) then
            call compute_strain_rate(sim%phys, sim%p, sim%nl)
            call halo_refresh(sim%halo, env, sim%p, HALO_STRAIN)
            call build_mirrors(sim%phys, sim%solids, sim%p)
        end if
        call compute_rates(sim%phys, sim%p, sim%nl)
    end subroutine evaluate_rates

    !> Time-step limit for the current rates (collective).
    function stable_timestep(sim, env) result(lim)
        type(simulation_t), intent(in) :: sim
        type(mpi_env_t), intent(in) :: env
        type(timestep_limits_t) :: lim
        real(wp) :: vmax, amax
        vmax = global_max(env, local_max_speed(sim%p))
        amax = global_max(env, local_max_acceleration(sim%p))
        lim = timestep_limits(sim%phys%kernel%h, sim%phys%c, vmax, sim%phys%nu, amax, &
            sim%cfg%numerics%cfl, sim%cfg%numerics%viscous_safety, sim%cfg%numerics%force_safety)
    end function stable_timestep

    logical function uses_mirrors(sim)
        type(simulation_t), intent(in) :: sim
        uses_mirrors = sim%phys%walls == WALLS_MIRROR .or. sim%phys%walls == WALLS_REPULSIVE_MIRROR
    end function uses_mirrors

    !> One predictor-corrector step, at most dt_cap long (to land on output times).
    subroutine simulation_step(sim, env, dt_cap)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        real(wp), intent(in), optional :: dt_cap
        real(wp) :: dt, max_shift
        logical :: integrate_density

        integrate_density = sim%phys%density_method /= DENSITY_SUMMATION
        call evaluate_rates(sim, env)
        sim%last_limits = stable_timestep(sim, env)
        dt = sim%last_limits%dt
        if (present(dt_cap)) dt = min(dt, dt_cap)
        call save_step_start(sim%p)
        ! predictor
        call advance(sim%p, 0.5_wp * dt, integrate_density)
        call halo_refresh(sim%halo, env, sim%p, HALO_MOVE)
        ! a particle moves at most (vmax + amax dt/2) dt/2 in the half step; the list stays
        ! valid while two particles cannot close in by more than the skin. Mirrors change
        ! with the ghosts, so mirror walls always rebuild.
        max_shift = (sim%last_limits%max_speed + 0.5_wp * dt * sim%last_limits%max_accel) &
            * 0.5_wp * dt
        if (2.0_wp * max_shift >= sim%list_skin .or. uses_mirrors(sim) .or. &
            sim%p%n_total /= sim%p%n_owned + sim%p%n_ghost) then
            call refresh_neighbours(sim)
        end if
        call evaluate_rates(sim, env)
        ! corrector
        call advance(sim%p, dt, integrate_density)
        sim%time = sim%time + dt
        sim%step = sim%step + 1
        sim%last_limits%dt = dt
        ! particles that left go to their new owner; ghosts and neighbours are rebuilt
        call migrate_particles(sim%domain, env, sim%p)
        call simulation_prepare_neighbours(sim, env)
        call update_pressure(sim%phys, sim%p, 1, sim%p%n_total)
    end subroutine simulation_step

    !> Rebalance when the load imbalance passes the threshold from the input.
    subroutine maybe_rebalance(sim, env)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        real(wp) :: before, after
        character(len=128) :: line
        if (env%nranks == 1) return
        if (mod(sim%step, int(sim%cfg%parallel%rebalance_check_interval, i8)) /= 0) return
        before = domain_imbalance(env, sim%p%n_owned)
        if (before <= sim%cfg%parallel%rebalance_threshold) return
        call domain_partition(sim%domain, env, sim%p%x, sim%p%n_owned)
        call halo_setup(sim%halo, sim%domain, sim%halo%reach)
        call migrate_particles(sim%domain, env, sim%p)
        call simulation_prepare_neighbours(sim, env)
        after = domain_imbalance(env, sim%p%n_owned)
        write(line, '(a,i0,a,f6.3,a,f6.3)') 'step ', sim%step, ': rebalanced, imbalance ', &
            before, ' -> ', after
        call log_info(trim(line))
    end subroutine maybe_rebalance

    !> Relative L2 error of the velocity of all fluid particles against the analytic channel
    !> solution named by &run analytic (collective). Negative when there is none.
    real(wp) function simulation_analytic_error(sim, env, steady) result(error)
        type(simulation_t), intent(in) :: sim
        type(mpi_env_t), intent(in) :: env
        logical, intent(in), optional :: steady
        real(wp) :: sums(2), exact(3), y, width, t
        integer :: i
        error = -1.0_wp
        if (trim(sim%cfg%run%analytic) == 'none') return
        t = sim%time
        if (present(steady)) then
            if (steady) t = huge(1.0_wp)
        end if
        width = sim%cfg%domain%box_hi(2) - sim%cfg%domain%box_lo(2)
        sums = 0.0_wp
        do i = 1, sim%p%n_owned
            if (sim%p%kind(i) /= KIND_FLUID) cycle
            y = sim%p%x(2, i) - sim%cfg%domain%box_lo(2)
            exact = 0.0_wp
            select case (trim(sim%cfg%run%analytic))
            case ('poiseuille')
                exact(1) = poiseuille_velocity(y, t, sim%cfg%fluid%body_force(1), width, &
                    sim%cfg%fluid%nu)
            case ('couette')
                exact(1) = couette_velocity(y, t, sim%cfg%domain%wall_velocity(1, 4), width, &
                    sim%cfg%fluid%nu)
            end select
            sums(1) = sums(1) + sum((sim%p%v(:, i) - exact)**2)
            sums(2) = sums(2) + sum(exact**2)
        end do
        sums = global_sum(env, sums)
        if (sums(2) > 0.0_wp) then
            error = sqrt(sums(1) / sums(2))
        else
            error = sqrt(sums(1))
        end if
    end function simulation_analytic_error

    !> The whole run: set-up, loop to t_end or max_steps, snapshots and log.
    subroutine simulation_run(env, cfg, restart_from)
        type(mpi_env_t), intent(in) :: env
        type(config_t), intent(in) :: cfg
        character(len=*), intent(in) :: restart_from
        type(simulation_t) :: sim
        real(wp) :: next_output, dt_cap, wall_start, wall_now, wall_last, rho_min, rho_max
        real(wp) :: remaining, error, wall_checkpoint
        integer(i8) :: log_every, steps_since_log, interval_index, first_step
        integer :: next_listed
        character(len=256) :: line
        logical :: finished

        if (len(restart_from) > 0) then
            call simulation_restart(sim, env, cfg, restart_from)
            if (sim%time >= cfg%run%t_end * (1.0_wp - 1.0e-12_wp)) &
                call fatal_collective('restart', &
                'the checkpoint is already at the end time; raise &run t_end to continue the run')
        else
            call simulation_setup(sim, env, cfg)
            call write_output(sim, env)
        end if
        interval_index = 0
        next_listed = 1
        next_output = next_output_time()
        call cpu_clock(wall_start)
        wall_last = wall_start
        wall_checkpoint = wall_start
        first_step = sim%step
        log_every = cfg%run%log_interval
        steps_since_log = 0
        call log_info('     step     time [s]       dt [s]   max |v| [m/s]  ' // &
            'rho min..max [kg/m^3]        wall/step [s]  remaining [s]')
        finished = .false.
        do while (.not. finished)
            dt_cap = min(next_output, cfg%run%t_end) - sim%time
            call simulation_step(sim, env, dt_cap)
            call maybe_rebalance(sim, env)
            steps_since_log = steps_since_log + 1
            if (log_every == 0) then
                ! about 40 lines per run, from the first step's time step
                log_every = max(1_i8, int(cfg%run%t_end / sim%last_limits%dt / 40.0_wp, i8))
                if (sim%step == first_step + 1) then
                    write(line, '(a,es10.3,a,es10.3,a,es10.3,a,es10.3)') 'time step: dt = ', &
                        sim%last_limits%dt, ' s (limits: CFL ', sim%last_limits%cfl, &
                        ', viscous ', sim%last_limits%viscous, ', force ', sim%last_limits%force
                    call log_info(trim(line) // ')')
                end if
            end if
            finished = sim%time >= cfg%run%t_end * (1.0_wp - 1.0e-12_wp) .or. &
                sim%step >= cfg%run%max_steps
            if (sim%time >= next_output * (1.0_wp - 1.0e-12_wp) .or. finished) then
                call write_output(sim, env)
                next_output = next_output_time()
            end if
            call cpu_clock(wall_now)
            if (finished) then
                call simulation_write_checkpoint(sim, env)
            else if (cfg%restart%checkpoint_interval_steps > 0) then
                if (mod(sim%step, int(cfg%restart%checkpoint_interval_steps, i8)) == 0) then
                    call simulation_write_checkpoint(sim, env)
                    wall_checkpoint = wall_now
                end if
            end if
            ! wall-clock interval: rank 0's clock decides for everybody
            if (.not. finished .and. cfg%restart%checkpoint_interval_wall > 0.0_wp) then
                if (global_max(env, merge(wall_now - wall_checkpoint, 0.0_wp, env%rank == 0)) >= &
                    cfg%restart%checkpoint_interval_wall) then
                    call simulation_write_checkpoint(sim, env)
                    wall_checkpoint = wall_now
                end if
            end if
            if (mod(sim%step, log_every) == 0 .or. finished) then
                call cpu_clock(wall_now)
                rho_min = global_min(env, fluid_extreme(sim%p, .false.))
                rho_max = global_max(env, fluid_extreme(sim%p, .true.))
                remaining = (wall_now - wall_start) / real(sim%step - first_step, wp) * &
                    max(0.0_wp, (cfg%run%t_end - sim%time) / max(sim%last_limits%dt, tiny(1.0_wp)))
                remaining = min(remaining, (wall_now - wall_start) / real(sim%step - first_step, &
                    wp) * &
                    real(cfg%run%max_steps - sim%step, wp))
                write(line, '(i9,es13.5,es13.5,es16.6,es14.6,a,es12.6,es14.4,es14.3)') sim%step, &
                    sim%time, sim%last_limits%dt, global_max(env, local_max_speed(sim%p)), &
                    rho_min, '..', rho_max, (wall_now - wall_last) / real(steps_since_log, wp), &
                        remaining
                call log_info(trim(line))
                wall_last = wall_now
                steps_since_log = 0
            end if
        end do
        call cpu_clock(wall_now)
        write(line, '(a,i0,a,es12.5,a,f10.2,a)') 'finished: ', sim%step - first_step, &
            ' steps to t = ', sim%time, ' s in ', wall_now - wall_start, ' s wall'
        call log_info(trim(line))
        if (trim(cfg%run%analytic) /= 'none') then
            error = simulation_analytic_error(sim, env)
            write(line, '(a,es12.5,a,f9.5,a)') 'error against the analytic ' // &
                trim(cfg%run%analytic) // ' solution at t = ', sim%time, ' s: relative L2 = ', &
                100.0_wp * error, ' %'
            call log_info(trim(line))
            ! the steady profile is a meaningful reference after a few viscous times L^2/(pi^2 nu)
            if (sim%time > 5.0_wp * (cfg%domain%box_hi(2) - cfg%domain%box_lo(2))**2 &
                / (acos(-1.0_wp)**2 * cfg%fluid%nu)) then
                error = simulation_analytic_error(sim, env, steady=.true.)
                write(line, '(a,f9.5,a)') 'error against the steady profile: relative L2 = ', &
                    100.0_wp * error, ' %'
                call log_info(trim(line))
            end if
        end if

    contains

        !> The next time at which a snapshot is due (interval multiples and listed times).
        real(wp) function next_output_time() result(t)
            t = cfg%run%t_end
            if (cfg%output%output_interval > 0.0_wp) then
                do
                    interval_index = interval_index + 1
                    if (real(interval_index, wp) * cfg%output%output_interval > &
                        sim%time * (1.0_wp + 1.0e-12_wp)) exit
                end do
                interval_index = interval_index - 1
                t = min(t, real(interval_index + 1, wp) * cfg%output%output_interval)
            end if
            do while (next_listed <= size(cfg%output%output_times))
                if (cfg%output%output_times(next_listed) > sim%time * (1.0_wp + 1.0e-12_wp)) exit
                next_listed = next_listed + 1
            end do
            if (next_listed <= size(cfg%output%output_times)) &
                t = min(t, cfg%output%output_times(next_listed))
        end function next_output_time
    end subroutine simulation_run

    !> A snapshot, its line in the run's index and the XDMF series rewritten (rank 0).
    subroutine write_output(sim, env)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        character(len=:), allocatable :: path, errmsg, xdmf_path
        integer :: stat, k
        integer(i8) :: rows
        real(wp) :: error
        character(len=160) :: line
        path = snapshot_filename(trim(sim%cfg%output%output_dir), trim(sim%cfg%run%case_name), &
            sim%step)
        call write_snapshot(env, sim%p, path, sim%time, sim%step, sim%cfg%domain%dimension, &
            code_version, sim%input_text, stat, errmsg)
        if (stat /= 0) call fatal_collective('output', errmsg)
        rows = global_sum(env, int(sim%p%n_owned, i8))
        k = index(path, '/', back=.true.)
        sim%snapshot_index = sim%snapshot_index // xdmf_index_entry(sim%time, sim%step, rows, &
            path(k + 1:))
        xdmf_path = trim(sim%cfg%output%output_dir) // '/' // trim(sim%cfg%run%case_name) // &
            '.xdmf'
        stat = 0
        if (env%rank == 0) call write_xdmf(xdmf_path, sim%snapshot_index, stat)
        if (global_max(env, int(stat, i8)) /= 0) &
            call fatal_collective('output', "cannot write '" // xdmf_path // "'")
        write(line, '(a,es12.5,a)') 'snapshot t = ', sim%time, ' s: ' // path
        if (trim(sim%cfg%run%analytic) /= 'none' .and. sim%time > 0.0_wp) then
            error = simulation_analytic_error(sim, env)
            write(line, '(a,a,f8.4,a)') trim(line), ' (L2 error vs analytic ', 100.0_wp * error, &
                ' %)'
        end if
        call log_info(trim(line))
    end subroutine write_output

    !> Wall-clock seconds.
    subroutine cpu_clock(seconds)
        real(wp), intent(out) :: seconds
        integer(i8) :: count, rate
        call system_clock(count, rate)
        seconds = real(count, wp) / real(rate, wp)
    end subroutine cpu_clock

    pure real(wp) function fluid_extreme(p, want_max)
        type(particles_t), intent(in) :: p
        logical, intent(in) :: want_max
        integer :: i
        fluid_extreme = merge(-huge(1.0_wp), huge(1.0_wp), want_max)
        do i = 1, p%n_owned
            if (p%kind(i) /= KIND_FLUID) cycle
            if (want_max) then
                fluid_extreme = max(fluid_extreme, p%rho(i))
            else
                fluid_extreme = min(fluid_extreme, p%rho(i))
            end if
        end do
    end function fluid_extreme
end module sph_simulation
