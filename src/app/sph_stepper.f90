!> The simulation state and how it advances: set-up, restart, one time step as a sequence of
!> named stages, rebalancing and the multi-resolution zone updates. This is where
!> communication is orchestrated (migration, halo build and refresh between the stages of a
!> step); the physics modules it calls make no MPI calls. When to write, log and stop is
!> decided by sph_schedule; the loop is sph_simulation.
!> Submodules hold the rest, one concern per file, behind the interfaces declared here:
!> sph_stepper_remesh (remeshing during a run and offline), sph_stepper_output (forces,
!> snapshots, checkpoints, the check report, the levels' log lines, the analytic error) and
!> sph_stepper_shared (the helpers those submodules call as well as the step: see there).
module sph_stepper
    use mpi_f08, only: MPI_Wtime
    use sph_kinds, only: wp, i8
    use sph_config, only: config_t, config_parse
    use sph_mpi_env, only: mpi_env_t, global_sum, global_max, broadcast_text
    use sph_errors, only: fatal_collective
    use sph_logger, only: log_info, sci_text
    use sph_particles, only: particles_t, particles_gather, KIND_FLUID, KIND_VIRTUAL, &
        HALO_DENSITY, HALO_MOVE, HALO_TRANSPORT, HALO_GHOST
    use sph_physics, only: physics_t, DENSITY_SUMMATION, WALLS_MIRROR, WALLS_REPULSIVE_MIRROR, &
        SHIFTING_NONE
    use sph_kernel, only: kernel_name
    use sph_walls, only: build_mirrors, wall_layers
    use sph_solids, only: solids_t
    use sph_domain, only: domain_t, domain_partition, domain_imbalance
    use sph_halo, only: halo_t, halo_setup, halo_build
    use sph_cell_list, only: neighbour_list_t, build_neighbour_list, cell_sort_order
    use sph_rates, only: update_pressure, release_rates_scratch, shepard_density
    use sph_shifting, only: shifting_diffusion, shift_particles
    use sph_timestep, only: timestep_limits_t
    use sph_integrator, only: save_step_start, advance, max_step_displacement, verlet_drift, &
        verlet_kick, stage_displacement_bound, verlet_drift_levels, verlet_close_levels, &
        verlet_kick_levels
    use sph_initial, only: create_lattice_particles
    use sph_particle_file, only: read_initial_particles
    use sph_global_ids, only: id_order, global_max_id
    use sph_reference, only: reference_t
    use sph_snapshot, only: snapshot_filename, snapshot_begin, snapshot_end, SNAPSHOT_NOT_CLOSED
    use sph_hdf5, only: h5_file_t, h5_write_attribute
    use sph_health, only: health_problem_t, check_particles, check_timestep, HEALTH_OK, &
        HEALTH_NONFINITE, check_displacement, IN_SOLID_SLACK
    use sph_checkpoint, only: read_checkpoint, find_latest_checkpoint
    use sph_read_checks, only: check_read_particles, check_fluid_outside_solids
    use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
    use sph_version, only: code_version
    use sph_zones, only: zones_t
    use sph_level_balance, only: real_fluid_mass, scale_masses
    use sph_step_timers, only: step_timers_t, timers_enter, timers_leave, TIMER_SEARCH, &
        TIMER_HALO, TIMER_INTEGRATION, TIMER_OTHER
    use sph_transition_driver, only: level_stats_t, create_level_particles, &
        update_transition_zones_of => update_transition_zones, level_totals, &
        refresh_virtual_fields, refine_uniform_state, set_virtual_masses, refresh_plan_t, &
        add_lineage_field
    implicit none
    private
    public :: simulation_solid_forces, simulation_write_forces, simulation_log_forces
    public :: simulation_check_report
    public :: simulation_t, simulation_setup, simulation_step, simulation_rebalance
    public :: simulation_analytic_error, simulation_prepare_neighbours, simulation_free
    public :: simulation_restart, simulation_write_checkpoint, simulation_write_snapshot
    public :: fluid_density_range, simulation_remesh, simulation_remesh_file
    public :: simulation_refine_regions_file
    public :: simulation_log_levels, simulation_neighbours_per_particle
    public :: simulation_synchronised, next_multiple

    type :: simulation_t
        type(config_t) :: cfg
        type(physics_t) :: phys
        type(solids_t) :: solids   !< walls and bodies
        type(reference_t) :: ref           !< the analytic reference (&run analytic)
        type(domain_t) :: domain
        type(halo_t) :: halo
        type(particles_t) :: p
        type(neighbour_list_t) :: nl
        real(wp) :: time = 0.0_wp
        integer(i8) :: step = 0
        real(wp) :: skin = 0.0_wp          !< ghost skin: covers any motion within one step
        real(wp) :: list_skin = 0.0_wp     !< neighbour-list skin: lets a list serve both stages
        !> bound on how far any particle has moved since the last migration and halo build
        !> (the sum of the steps' largest displacements, over all ranks)
        real(wp) :: drift = 0.0_wp
        type(timestep_limits_t) :: last_limits
        real(wp) :: first_dt = 0.0_wp      !< the run's first time step (health check)
        !> the last step as the limits (or &numerics fixed_dt) set it, before it was shortened
        !> to land on an output time or t_end: what the health check watches for a collapse
        real(wp) :: uncapped_dt = 0.0_wp
        !> force of the fluid on each solid from the last rates: (xyz, pressure|viscous, solid),
        !> this rank's fluid particles only (simulation_solid_forces sums over ranks)
        real(wp), allocatable :: wall_forces(:, :, :)
        !> wall_forces integrated over the steps since the forces were last written, and the
        !> time that covers (this rank's part; simulation_write_forces writes their mean)
        real(wp), allocatable :: force_integral(:, :, :)
        real(wp) :: force_window = 0.0_wp
        character(len=:), allocatable :: input_text
        character(len=:), allocatable :: snapshot_index   !< one line per snapshot, for XDMF
        character(len=512), allocatable :: checkpoints(:) !< written by this run, oldest first
        real(wp) :: next_remesh_time = huge(1.0_wp)  !< &remesh every_time: when the next is due
        !> the last remesh's wall seconds (slowest rank): new positions, transfer of the
        !> fields, and the rebuild after them (walls, partition, migration, neighbours)
        real(wp) :: remesh_stages(3) = 0.0_wp
        ! multi-resolution (&region): the levels' regions and transition zones, the physics of
        ! each level (level_phys(0) is phys), the next unused global id base (the same on
        ! every rank) and the transition updates' counters since the last log line
        type(zones_t) :: zones
        type(physics_t), allocatable :: level_phys(:)
        integer(i8) :: next_id = 0
        type(level_stats_t) :: level_stats
        !> the virtual particles' refresh candidates; invalid after every rebuild
        type(refresh_plan_t) :: refresh_plan
        real(wp), allocatable :: first_level_mass(:)   !< real mass per level at the start
        !> &refinement conserve (sph_level_balance): the total real mass the transition
        !> updates hold (the fluid's at set-up, or the checkpoint's), each level's last
        !> virtual push (xyz) and mass of real particles next to virtual ones, which
        !> particles those are (marked at each evaluation), and for the log the mass
        !> the rescales put back and the push removed (summed over the rate evaluations,
        !> and their count) since its last line
        real(wp) :: reference_mass = 0.0_wp
        real(wp), allocatable :: level_push(:, :), level_push_mass(:)
        logical, allocatable :: near_virtual(:)
        !> the particles that can come next to a virtual one while the list lasts, and the
        !> neighbour list's generation they are of
        logical, allocatable :: near_virtual_candidates(:)
        integer :: near_virtual_list = -1
        real(wp) :: mass_restored = 0.0_wp
        real(wp) :: push_removed(3) = 0.0_wp
        integer(i8) :: push_evaluations = 0
        !> wall seconds spent in the transition zones' updates (with their rebuild) so far
        real(wp) :: transition_seconds = 0.0_wp
        logical :: zones_due = .false.   !< the zones are made anew after this step
        !> drift since the zones were last made: it alone sets when they are made again, so
        !> the rebuilds of output, checkpoints and rebalancing (which reset drift) do not
        !> move the zones' updates (kept in checkpoints, with the levels' balance)
        real(wp) :: zone_drift = 0.0_wp
        !> &numerics integrator = 'verlet': one rate evaluation per step, the rates of the
        !> step-start state kept from the previous step (or evaluated again when stale)
        logical :: verlet = .false.
        !> the particles' rates do not belong to their current state (set-up, a restart from
        !> a checkpoint without Verlet rates, a remesh, shifting): verlet evaluates them first
        logical :: rates_stale = .true.
        !> the largest speed and acceleration (over all ranks) that the last Verlet kick found,
        !> for the next step's limits, and the step they belong to (-1: none). Every rate
        !> evaluation voids them; so does anything that changes the particles after a kick,
        !> since it sets rates_stale and the next step evaluates the rates first.
        real(wp) :: kick_maxima(2) = 0.0_wp
        integer(i8) :: kick_maxima_step = -1
        !> multi-resolution Verlet (sph_integrator's sub-cycled form; with &refinement
        !> max_subcycles > 1 coarser levels take longer steps): the steps of the
        !> finest level that each level's step spans in the current cycle, each level's
        !> planned step and the time since it began, the cycle's finest-level steps so far
        !> (0: every level is at the end of a step, the state is synchronised) and the step
        !> it planned, the largest move of the last step (set by every Verlet step, sub-cycled
        !> or not), and the forces on the solids from each level's last rates (xyz,
        !> pressure|viscous, solid, level)
        logical :: subcycling = .false.
        integer, allocatable :: level_substeps(:)
        real(wp), allocatable :: level_span(:), level_elapsed(:)
        integer :: cycle_step = 0
        real(wp) :: cycle_dt = 0.0_wp
        real(wp) :: step_moved = 0.0_wp
        real(wp), allocatable :: level_wall_forces(:, :, :, :)
        !> where the step loop's wall time goes (sph_step_timers; the run loop starts them)
        type(step_timers_t) :: timers
    end type simulation_t

    ! The parts of set-up, migration, rate evaluation and the time step that the step and the
    ! submodules share (submodule sph_stepper_shared; private).
    interface
        !> What a fresh start and a restart share: parameters, walls, the domain, empty particles.
        module subroutine setup_common(sim, env, cfg)
            type(simulation_t), intent(out) :: sim
            type(mpi_env_t), intent(in) :: env
            type(config_t), intent(in) :: cfg
        end subroutine setup_common

        !> More than one resolution level (&region groups).
        module pure logical function multires(sim)
            type(simulation_t), intent(in) :: sim
        end function multires

        !> halo_refresh of `fields`, charged to the halo exchange.
        module subroutine refresh_ghosts(sim, env, fields)
            type(simulation_t), intent(inout) :: sim
            type(mpi_env_t), intent(in) :: env
            integer, intent(in) :: fields
        end subroutine refresh_ghosts

        !> Particles to the ranks whose regions they are in, charged to the halo exchange.
        module subroutine migrate(sim, env)
            type(simulation_t), intent(inout) :: sim
            type(mpi_env_t), intent(in) :: env
        end subroutine migrate

        !> Particles back in their owners' regions (periodic positions wrapped) and everything
        !> rebuilt, unless nothing moved since the last rebuild: before a snapshot, a checkpoint
        !> (a restart then continues bit for bit) or a rebalance (collective).
        module subroutine synchronise(sim, env)
            type(simulation_t), intent(inout) :: sim
            type(mpi_env_t), intent(in) :: env
        end subroutine synchronise

        !> Rates at the current state. Ghost fields are current on entry; stages that produce a
        !> field the neighbours need (summation density, strain rate) refresh the ghosts.
        !> levels: only the rates of these levels (sub-cycling); all when absent.
        module subroutine evaluate_rates(sim, env, levels)
            type(simulation_t), intent(inout) :: sim
            type(mpi_env_t), intent(in) :: env
            logical, intent(in), optional :: levels(0:)
        end subroutine evaluate_rates

        !> Sub-cycling: the steps of the finest level that each level's step would span with
        !> finest step dt and the last limits' speed and acceleration (sph_timestep
        !> level_substeps, each level's own smoothing length, &refinement max_subcycles).
        module function planned_substeps(sim, dt) result(k)
            type(simulation_t), intent(in) :: sim
            real(wp), intent(in) :: dt
            integer :: k(0:sim%zones%n_levels - 1)
        end function planned_substeps

        !> Time-step limit for the current rates (collective).
        module function stable_timestep(sim, env) result(lim)
            type(simulation_t), intent(in) :: sim
            type(mpi_env_t), intent(in) :: env
            type(timestep_limits_t) :: lim
        end function stable_timestep
    end interface

    ! Remeshing during a run and offline (submodule sph_stepper_remesh).
    interface
        !> Full-domain remeshing when &remesh says it is due: every every_steps steps, whenever
        !> the time passes a multiple of every_time, or when the disorder measure passes
        !> disorder_threshold (checked every disorder_check_steps steps; collective).
        module subroutine remesh_if_due(sim, env)
            type(simulation_t), intent(inout) :: sim
            type(mpi_env_t), intent(in) :: env
        end subroutine remesh_if_due

        !> --check's line on the memory a run's &remesh will take on top of what the set-up
        !> measured (nothing without &remesh; collective; sph_stepper_remesh).
        module subroutine log_remesh_memory(sim, env)
            type(simulation_t), intent(in) :: sim
            type(mpi_env_t), intent(in) :: env
        end subroutine log_remesh_memory

        !> Remesh every fluid particle (sph_remesh_driver: refine, coarsen or same level) and
        !> rebuild around them (collective). Refining or coarsening changes &domain dx in the
        !> run's configuration (kernel, walls, time step follow) and regenerates the wall
        !> particles at the new spacing; same level keeps them. Logs what it did.
        module subroutine simulation_remesh(sim, env, mode)
            type(simulation_t), intent(inout) :: sim
            type(mpi_env_t), intent(in) :: env
            integer, intent(in) :: mode
        end subroutine simulation_remesh

        !> Offline remeshing (sphremesh --remesh MODE IN.h5 OUT.h5, collective, any rank count):
        !> the particles of a snapshot or checkpoint IN, set up with the input stored in it, are
        !> remeshed and written as a checkpoint OUT a run continues from (--restart OUT.h5 with
        !> &domain dx set to the new spacing, which OUT records as its attribute 'dx'; the input
        !> stored in OUT is IN's). The wall particles are always regenerated from the stored
        !> input's walls and bodies at the new spacing (a snapshot lacks their wall geometry).
        module subroutine simulation_remesh_file(env, mode_name, in_path, out_path)
            type(mpi_env_t), intent(in) :: env
            character(len=*), intent(in) :: mode_name, in_path, out_path
        end subroutine simulation_remesh_file

        !> Offline refinement of regions (sphremesh --remesh refine IN.h5 OUT.h5 --regions
        !> INPUT.nml, collective): the uniform checkpoint IN continued with cfg (INPUT.nml,
        !> read from regions_path, with its &region groups) as a restart would continue it,
        !> its regions refined (refine_if_uniform), written as the multi-resolution checkpoint
        !> OUT at IN's time and step, INPUT.nml stored in it: sphremesh INPUT.nml --restart
        !> OUT continues from it. Refused (nothing written): an input without &region groups,
        !> an IN that is multi-resolution already, an OUT that exists.
        module subroutine simulation_refine_regions_file(env, cfg, regions_path, in_path, &
                out_path)
            type(mpi_env_t), intent(in) :: env
            type(config_t), intent(in) :: cfg
            character(len=*), intent(in) :: regions_path, in_path, out_path
        end subroutine simulation_refine_regions_file

        !> Why a run of cfg cannot go on at spacing dx_new ('' when it can): its lattice must
        !> fill the box (the input check's rule for dx, sph_domain_input) and a periodic side
        !> must hold twice the kernel's support there (setup_common's rule). A remesh that
        !> would break them is skipped in a run and written only for study offline.
        module function spacing_problem_at(cfg, dx_new) result(problem)
            type(config_t), intent(in) :: cfg
            real(wp), intent(in) :: dx_new
            character(len=:), allocatable :: problem
        end function spacing_problem_at
    end interface

    ! Reports and output files: forces, snapshots, checkpoints, the check report, the levels'
    ! log lines, the error against the analytic reference (submodule sph_stepper_output).
    interface
        !> Write a checkpoint of the current state and keep only the newest checkpoints_kept of
        !> those this run wrote (collective).
        module subroutine simulation_write_checkpoint(sim, env, forces_row_follows)
            type(simulation_t), intent(inout) :: sim
            type(mpi_env_t), intent(in) :: env
            !> the forces file gets a row at this step after the checkpoint (a log line):
            !> the checkpoint's running mean is then empty, as the continued run finds it
            logical, intent(in), optional :: forces_row_follows
        end subroutine simulation_write_checkpoint

        !> What a checkpoint holds of the levels' balance of a multi-resolution run (the
        !> reference mass, the virtual pushes and their mass, then the zones' drift;
        !> sph_checkpoint); unallocated for one level.
        module subroutine checkpoint_balance(sim, balance)
            type(simulation_t), intent(in) :: sim
            real(wp), allocatable, intent(out) :: balance(:)
        end subroutine checkpoint_balance

        !> Force of the fluid on every solid (xyz, pressure|viscous, solid) from the rates of the
        !> step's second stage, the ones that advanced it (collective).
        module function simulation_solid_forces(sim, env) result(forces)
            type(simulation_t), intent(in) :: sim
            type(mpi_env_t), intent(in) :: env
            real(wp), allocatable :: forces(:, :, :)
        end function simulation_solid_forces

        !> The forces on the solids as rows of <output_dir>/<case>_forces.csv: time, step, body,
        !> Fx, Fy, Fz, then the pressure and viscous parts (N, per unit depth in 2D), then the
        !> total force's mean over the steps since the previous row (Fx_mean, ...; since
        !> t = 0 at a run's first row; a restart goes on with its checkpoint's sums).
        !> Collective; rank 0 writes. `fresh` starts the file (a new run); otherwise rows are appended.
        module subroutine simulation_write_forces(sim, env, fresh)
            type(simulation_t), intent(inout) :: sim
            type(mpi_env_t), intent(in) :: env
            logical, intent(in) :: fresh
        end subroutine simulation_write_forces

        !> The forces on the solids in the log, one line per solid (collective).
        module subroutine simulation_log_forces(sim, env)
            type(simulation_t), intent(in) :: sim
            type(mpi_env_t), intent(in) :: env
        end subroutine simulation_log_forces

        !> What --check reports after set-up (collective): particles per kind and level, the
        !> memory they take, the first time step with its limiting criterion and the steps to
        !> t_end. Evaluates the rates once; advances nothing and writes no file.
        module subroutine simulation_check_report(sim, env)
            type(simulation_t), intent(inout) :: sim
            type(mpi_env_t), intent(in) :: env
        end subroutine simulation_check_report

        !> Per level: real and virtual particles, conversions per step since the last call, real
        !> mass and momentum, and the drift of the real mass from the start (collective; no
        !> output with one level).
        module subroutine simulation_log_levels(sim, env)
            type(simulation_t), intent(inout) :: sim
            type(mpi_env_t), intent(in) :: env
        end subroutine simulation_log_levels

        !> Relative L2 error of the velocity of all fluid particles against the analytic
        !> reference named by &run analytic (sph_reference; collective). -1 when there is none,
        !> -2 when the reference is below its series' round-off (the flow has barely started:
        !> analytic_error_text says so).
        module real(wp) function simulation_analytic_error(sim, env, steady) result(error)
            type(simulation_t), intent(in) :: sim
            type(mpi_env_t), intent(in) :: env
            logical, intent(in), optional :: steady
        end function simulation_analytic_error

        !> A snapshot, its line in the run's index and the XDMF series rewritten (rank 0).
        module subroutine simulation_write_snapshot(sim, env)
            type(simulation_t), intent(inout) :: sim
            type(mpi_env_t), intent(in) :: env
        end subroutine simulation_write_snapshot

        !> Mean number of neighbours within the kernel support (of the particle's level) per
        !> owned particle, every kind of particle and neighbour counted, each pair from both
        !> sides (collective). The bench reports it with the pair interactions per second.
        module real(wp) function simulation_neighbours_per_particle(sim, env) result(mean)
            type(simulation_t), intent(in) :: sim
            type(mpi_env_t), intent(in) :: env
        end function simulation_neighbours_per_particle

        !> Stop before laying a lattice that cannot run (collective; sph_stepper_checks).
        module subroutine check_lattice_size(sim, env)
            type(simulation_t), intent(in) :: sim
            type(mpi_env_t), intent(in) :: env
        end subroutine check_lattice_size

        !> Whether `particles` (over all ranks) fit the ranks' neighbour lists and the nodes'
        !> memory, rank0_bytes more on rank 0's (collective; sph_stepper_checks): problem
        !> and warning (': ...' or '').
        module subroutine fit_on_nodes(sim, env, particles, rank0_bytes, problem, warning)
            type(simulation_t), intent(in) :: sim
            type(mpi_env_t), intent(in) :: env
            real(wp), intent(in) :: particles, rank0_bytes
            character(len=:), allocatable, intent(out) :: problem, warning
        end subroutine fit_on_nodes

        !> How the geometry of a checkpoint's stored input differs from cfg's ('' if it does
        !> not; sph_stepper_checks).
        module function geometry_mismatch(stored, cfg) result(text)
            type(config_t), intent(in) :: stored, cfg
            character(len=:), allocatable :: text
        end function geometry_mismatch

        !> How the masses of a checkpoint's stored input's lattice differ from cfg's ('' if
        !> they do not; sph_stepper_checks): in a summation-density run they depend on the
        !> kernel and h_factor (sph_initial's lattice_mass_factor).
        module function masses_mismatch(stored, cfg) result(text)
            type(config_t), intent(in) :: stored, cfg
            character(len=:), allocatable :: text
        end function masses_mismatch

        !> What of the wall and body particles a checkpoint's stored input laid differs from
        !> cfg's ('' if nothing; sph_stepper_checks): their layers (the kernel support over
        !> dx), the wall model, the walls' and the bodies' velocities.
        module function walls_mismatch(stored, cfg) result(text)
            type(config_t), intent(in) :: stored, cfg
            character(len=:), allocatable :: text
        end function walls_mismatch

        !> Whether what the rates depend on (the &domain, &fluid, &numerics, &body,
        !> &refinement and &region groups of the resolved inputs) differs between a
        !> checkpoint's stored input and cfg (sph_stepper_checks): then a checkpoint's rates
        !> (a verlet run's) are another input's.
        module function rates_inputs_differ(stored, cfg) result(differ)
            type(config_t), intent(in) :: stored, cfg
            logical :: differ
        end function rates_inputs_differ

        !> Smallest and largest fluid density over all ranks (collective).
        module function fluid_density_range(sim, env) result(range)
            type(simulation_t), intent(in) :: sim
            type(mpi_env_t), intent(in) :: env
            real(wp) :: range(2)
        end function fluid_density_range
    end interface

    ! Set-up and restart (submodule sph_stepper_setup).
    interface
        !> Build everything from a validated configuration (collective).
        module subroutine simulation_setup(sim, env, cfg)
            type(simulation_t), intent(out) :: sim
            type(mpi_env_t), intent(in) :: env
            type(config_t), intent(in) :: cfg
        end subroutine simulation_setup

        !> Continue from a checkpoint file, or from the newest complete one in a directory.
        !> On the rank count that wrote it the run continues bit for bit. label: what its
        !> errors and log lines name (default 'restart'; the offline refinement of regions
        !> reads its IN this way).
        module subroutine simulation_restart(sim, env, cfg, from, label)
            type(simulation_t), intent(out) :: sim
            type(mpi_env_t), intent(in) :: env
            type(config_t), intent(in) :: cfg
            character(len=*), intent(in) :: from
            character(len=*), intent(in), optional :: label
        end subroutine simulation_restart

        ! (in sph_stepper_shared, as the submodules call them: gfortran emits no symbol for a
        ! procedure of the module itself that it has inlined at every call there)

        !> The owned particles other than fluid replaced by the wall and body particles of
        !> the lattice at the configuration's spacing (sph_initial, walls_only), their ids
        !> after every other particle's (lattice ids are unique and rank independent), each
        !> made by the rank whose region of sim%domain holds it (sph_stepper_shared).
        module subroutine lay_lattice_walls(sim, env)
            type(simulation_t), intent(inout) :: sim
            type(mpi_env_t), intent(in) :: env
        end subroutine lay_lattice_walls

        !> The first multiple of `period` after `time` (to 1e-12 relative: a time that
        !> lands on a multiple is past it), in floating point: a period below the time's
        !> resolution overflowed an integer count (every_time 1e-30 s trapped at a restart)
        !> and, added step by step, never passed the time; such a period gives the time
        !> itself (due at every step).
        pure module function next_multiple(time, period) result(next)
            real(wp), intent(in) :: time, period
            real(wp) :: next
        end function next_multiple

        !> How far ghosts reach beyond a rank's region (see migrate_and_rebuild).
        !> With several levels, ghosts must also cover what the transition zones' virtual
        !> particles are made from: the interpolation reaches 2 sqrt(dim) coarse spacings.
        pure module function halo_reach(sim) result(reach)
            type(simulation_t), intent(in) :: sim
            real(wp) :: reach
        end function halo_reach

        !> &refinement conserve: the masses of the real fluid and the walls scaled by one
        !> factor that brings the real fluid back to the reference total (sph_level_balance).
        module subroutine hold_real_mass(sim, env)
            type(simulation_t), intent(inout) :: sim
            type(mpi_env_t), intent(in) :: env
        end subroutine hold_real_mass
    end interface

contains

    !> Forget the particles of a simulation (its arrays stay allocated for reuse).
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
        integer :: previous, in_search
        call timers_enter(sim%timers, TIMER_SEARCH, previous)
        ! the pair loop's kept arrays would add to the peaks of the gather and of output
        call release_rates_scratch()
        allocate(order(sim%p%n_owned))
        ! cells of the finest level's support: a cell of the coarse one holds four times as
        ! many fine particles, whose partners then lie farther apart in memory (the fine pair
        ! loop ran about 5 % slower, bench_multires at L/320)
        call cell_sort_order(sim%p%x, sim%p%n_owned, sim%p%dim, sort_cell_size(sim), order)
        call particles_gather(sim%p, order)
        sim%p%n_ghost = 0
        sim%p%n_total = sim%p%n_owned
        call timers_enter(sim%timers, TIMER_HALO, in_search)
        call halo_build(sim%halo, sim%domain, env, sim%p)
        call timers_leave(sim%timers, in_search)
        ! the transport offsets travel only in runs that use them, so new ghosts fetch theirs
        if (sim%phys%transport_velocity) call refresh_ghosts(sim, env, HALO_TRANSPORT)
        call refresh_neighbours(sim)
        call timers_leave(sim%timers, previous)
        sim%drift = 0.0_wp
        sim%refresh_plan%valid = .false.
    end subroutine simulation_prepare_neighbours

    !> Mirrors and the neighbour list for the current positions. The list holds pairs within
    !> support + list_skin, so it stays complete while no pair closes in by more than the skin.
    subroutine refresh_neighbours(sim)
        type(simulation_t), intent(inout) :: sim
        integer :: previous
        call timers_enter(sim%timers, TIMER_SEARCH, previous)
        call build_mirrors(sim%phys, sim%solids, sim%p)
        if (multires(sim)) then
            ! each level's particles pair with their own level only, within its support
            call build_neighbour_list(sim%p%x, sim%p%n_total, sim%p%n_owned, sim%p%dim, &
                sim%phys%kernel%support + sim%list_skin, sim%nl, sim%p%level, &
                sim%level_phys(:)%kernel%support + sim%list_skin)
        else
            call build_neighbour_list(sim%p%x, sim%p%n_total, sim%p%n_owned, sim%p%dim, &
                sim%phys%kernel%support + sim%list_skin, sim%nl)
        end if
        call timers_leave(sim%timers, previous)
    end subroutine refresh_neighbours

    !> The cell size of the storage order: the smallest kernel support of the levels.
    pure real(wp) function sort_cell_size(sim)
        type(simulation_t), intent(in) :: sim
        sort_cell_size = sim%phys%kernel%support
        if (multires(sim)) sort_cell_size = minval(sim%level_phys(:)%kernel%support)
    end function sort_cell_size

    logical function uses_mirrors(sim)
        type(simulation_t), intent(in) :: sim
        uses_mirrors = sim%phys%walls == WALLS_MIRROR .or. sim%phys%walls == WALLS_REPULSIVE_MIRROR
    end function uses_mirrors

    !> One predictor-corrector step, at most dt_cap long (to land on output times). Ghosts,
    !> mirrors and the neighbour list are current on entry and on exit.
    !> With &numerics integrator = 'verlet' one velocity-Verlet step instead (verlet_step).
    subroutine simulation_step(sim, env, dt_cap)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        real(wp), intent(in), optional :: dt_cap
        integer :: previous
        real(wp) :: start
        ! what no other part claims (time-step limits, reductions, health) is integration
        call timers_enter(sim%timers, TIMER_INTEGRATION, previous)
        start = sim%time
        if (sim%verlet) then
            call verlet_step(sim, env, dt_cap)
        else
            call predictor_corrector_step(sim, env, dt_cap)
        end if
        ! the forces on the solids from the step's last rates, over the time it took
        sim%force_integral = sim%force_integral + (sim%time - start) * sim%wall_forces
        sim%force_window = sim%force_window + (sim%time - start)
        call timers_leave(sim%timers, previous)
    end subroutine simulation_step

    !> One predictor-corrector step (simulation_step).
    subroutine predictor_corrector_step(sim, env, dt_cap)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        real(wp), intent(in), optional :: dt_cap
        real(wp) :: dt

        call evaluate_rates(sim, env)
        sim%last_limits = stable_timestep(sim, env)
        dt = sim%last_limits%dt
        ! a fixed step (&numerics fixed_dt) overrides the limit: the health checks catch it
        ! when it is too large
        if (sim%cfg%numerics%fixed_dt > 0.0_wp) dt = sim%cfg%numerics%fixed_dt
        sim%uncapped_dt = dt
        if (present(dt_cap)) dt = min(dt, dt_cap)
        call predictor(sim, dt)
        call refresh_halo(sim, env)
        call prepare_boundaries(sim, dt)
        call evaluate_rates(sim, env)
        call corrector(sim, dt)
        call shift(sim, env, dt)
        call migrate_and_rebuild(sim, env)
        call filter_density(sim, env, sim%step)
        call remesh_if_due(sim, env)
        call update_transition_zones(sim, env)
        call check_health(sim, env)
    end subroutine predictor_corrector_step

    !> &numerics density_filter = 'shepard' in step number `step` (every
    !> density_filter_interval steps), with ghosts and list current: the real fluid's
    !> densities filtered level by level (sph_rates shepard_density), the ghosts and pressures
    !> following. The predictor-corrector filters the step's end state (after its migration);
    !> Verlet the drifted state before its rate evaluation, and the change goes into the
    !> half-kicked densities too, from which the kick completes the step (one level only:
    !> refused with &region, whose Verlet steps level by level).
    subroutine filter_density(sim, env, step)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        integer(i8), intent(in) :: step
        integer :: lv, previous
        if (sim%phys%density_filter_interval <= 0) return
        if (mod(step, int(sim%phys%density_filter_interval, i8)) /= 0_i8) return
        call timers_enter(sim%timers, TIMER_OTHER, previous)
        if (multires(sim)) then
            do lv = 0, sim%zones%n_levels - 1
                call shepard_density(sim%level_phys(lv), sim%p, sim%nl, lv)
            end do
        else if (sim%verlet) then
            call shepard_density(sim%phys, sim%p, sim%nl, also=sim%p%rho_old)
        else
            call shepard_density(sim%phys, sim%p, sim%nl)
        end if
        call refresh_ghosts(sim, env, HALO_DENSITY)
        ! the refresh ends the table at the ghosts: the mirror images the list points at are
        ! made again, in the same order, with the filtered densities (without them the Verlet
        ! step's rates read past the table's end, and the predictor-corrector's next step
        ! read stale images: 6 ranks 4e-5 from 1, fz33)
        call build_mirrors(sim%phys, sim%solids, sim%p)
        call update_pressure(sim%phys, sim%p, 1, sim%p%n_total)
        call timers_leave(sim%timers, previous)
    end subroutine filter_density

    !> One velocity-Verlet step (sph_integrator verlet_drift, verlet_kick) with one rate
    !> evaluation: the step-start rates are those kept from the previous step (evaluated
    !> here only when stale); the time step is chosen from them. The rates are evaluated at
    !> the new positions with the velocity (and density) estimate v_half + dt/2 a^n, and
    !> kept for the next step. Ghosts, mirrors and the list are current on entry and exit.
    subroutine verlet_step(sim, env, dt_cap)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        real(wp), intent(in), optional :: dt_cap
        real(wp) :: dt

        if (sim%subcycling) then
            call subcycled_verlet_step(sim, env, dt_cap)
            return
        end if
        if (sim%rates_stale) call evaluate_rates(sim, env)
        sim%rates_stale = .false.
        sim%last_limits = stable_timestep(sim, env)
        dt = sim%last_limits%dt
        if (sim%cfg%numerics%fixed_dt > 0.0_wp) dt = sim%cfg%numerics%fixed_dt
        sim%uncapped_dt = dt
        if (present(dt_cap)) dt = min(dt, dt_cap)
        ! a shifting step measures its particles' displacement from x_old (migrate_and_rebuild)
        call verlet_drift(sim%p, dt, integrated_density(sim), sim%step_moved, &
            keep_start=sim%phys%shifting /= SHIFTING_NONE, &
            integrate_energy=sim%phys%energy_equation)
        call refresh_halo(sim, env)
        call prepare_boundaries(sim, dt)
        call filter_density(sim, env, sim%step + 1_i8)
        call evaluate_rates(sim, env)
        call verlet_kick(sim%p, dt, integrated_density(sim), sim%kick_maxima, &
            integrate_energy=sim%phys%energy_equation)
        sim%kick_maxima = global_max(env, sim%kick_maxima)
        sim%time = sim%time + dt
        sim%step = sim%step + 1
        sim%kick_maxima_step = sim%step
        sim%last_limits%dt = dt
        ! shifting moves the particles after the rates were evaluated
        call shift(sim, env, dt)
        if (sim%phys%shifting /= SHIFTING_NONE) then
            sim%rates_stale = .true.
            call migrate_and_rebuild(sim, env)
        else
            ! the drift moved each particle dt |v_half|: no pass over the positions to find it
            call migrate_and_rebuild(sim, env, moved=sim%step_moved)
        end if
        call remesh_if_due(sim, env)
        call update_transition_zones(sim, env)
        call check_health(sim, env)
    end subroutine verlet_step

    !> One step of the finest level with sub-cycled Verlet (sph_integrator), the Verlet step
    !> of every multi-resolution run (with &refinement max_subcycles = 1 every level steps
    !> each time). When every level is at the end of a step a cycle is planned: the
    !> finest level's step from the limits and, per level, how many of them its step spans
    !> (sph_timestep level_substeps, its own limits). Each step then starts the levels due,
    !> drifts every particle, and evaluates the rates of and kicks the levels whose step
    !> ends; the coarser levels' pair loops run only then. A step cut short to land on an
    !> output time or t_end ends every level's step there, so snapshots, checkpoints and the
    !> zones' updates see a synchronised state. Ghosts, mirrors and the list are current on
    !> entry and exit.
    subroutine subcycled_verlet_step(sim, env, dt_cap)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        real(wp), intent(in), optional :: dt_cap
        real(wp) :: dt, max_shift
        logical :: starts(0:sim%zones%n_levels - 1), ends(0:sim%zones%n_levels - 1)

        if (sim%rates_stale) call evaluate_rates(sim, env)
        sim%rates_stale = .false.
        sim%last_limits = stable_timestep(sim, env)
        if (sim%cycle_step == 0) call plan_cycle(sim)
        dt = min(sim%last_limits%dt, sim%cycle_dt)
        if (sim%cfg%numerics%fixed_dt > 0.0_wp) dt = sim%cfg%numerics%fixed_dt
        sim%uncapped_dt = dt
        ends = .false.
        if (present(dt_cap)) then
            if (dt_cap <= dt) ends = .true.
            dt = min(dt, dt_cap)
        end if
        starts = mod(sim%cycle_step, sim%level_substeps) == 0
        call verlet_drift_levels(sim%p, dt, starts, sim%level_span, sim%level_elapsed, &
            integrated_density(sim), sim%step_moved)
        sim%cycle_step = sim%cycle_step + 1
        ends = ends .or. mod(sim%cycle_step, sim%level_substeps) == 0
        call refresh_halo(sim, env)
        ! a particle in the middle of its level's step moves dt |v_half| per step, and its
        ! half kick may be half the longest level step long
        max_shift = (sim%last_limits%max_speed + 0.5_wp * maxval(sim%level_span) * &
            sim%last_limits%max_accel) * dt
        call prepare_boundaries(sim, dt, max_shift)
        ! the virtual particles of the levels whose rates are due take the other level's
        ! fields where they now are, so those rates see the other level as it is
        call refresh_virtuals(sim, env, ends)
        call verlet_close_levels(sim%p, ends, sim%level_span, sim%level_elapsed, &
            integrated_density(sim))
        call evaluate_rates(sim, env, ends)
        call verlet_kick_levels(sim%p, ends, sim%level_elapsed, integrated_density(sim))
        where (ends) sim%level_elapsed = 0.0_wp
        if (all(ends)) sim%cycle_step = 0
        sim%time = sim%time + dt
        sim%step = sim%step + 1
        sim%last_limits%dt = dt
        call migrate_and_rebuild(sim, env, subcycled=.true., moved=sim%step_moved)
        call update_transition_zones(sim, env)
        call check_health(sim, env)
    end subroutine subcycled_verlet_step

    !> A new cycle of sub-cycled Verlet (subcycled_verlet_step) from the current limits: the
    !> finest level's step, and each level's span from its own smoothing length. The log
    !> says when the spans change.
    subroutine plan_cycle(sim)
        type(simulation_t), intent(inout) :: sim
        integer :: before(0:sim%zones%n_levels - 1)
        character(len=256) :: line
        sim%cycle_dt = sim%last_limits%dt
        if (sim%cfg%numerics%fixed_dt > 0.0_wp) sim%cycle_dt = sim%cfg%numerics%fixed_dt
        before = sim%level_substeps
        sim%level_substeps = planned_substeps(sim, sim%cycle_dt)
        sim%level_span = real(sim%level_substeps, wp) * sim%cycle_dt
        sim%level_elapsed = 0.0_wp
        if (any(before /= sim%level_substeps)) then
            write(line, '(a,i0,a,*(i0,:,", "))') 'step ', sim%step, &
                ': sub-cycling, finest-level steps per step of levels 0.. : ', &
                sim%level_substeps
            call log_info(trim(line))
        end if
    end subroutine plan_cycle

    !> Each owned particle's share of a step's work, for the load balance: 1, but with
    !> sub-cycling a level whose step spans k steps of the finest level runs its pair loop
    !> once per k of them: PAIR_LOOP_SHARE / k + 1 - PAIR_LOOP_SHARE. The refresh of the
    !> virtual particles is left out on purpose: it runs between two halo exchanges, apart
    !> from the pair loop, so a rank that holds an interface cannot make up for it with less
    !> pair-loop work (counting it, 7 particle steps per virtual particle, left the pair
    !> loops 5.45 s against 3.57 s on a two-level channel at L/320 on 2 ranks).
    function particle_loads(sim) result(w)
        type(simulation_t), intent(in) :: sim
        real(wp) :: w(sim%p%n_owned)
        !> the pair loop's share of a Verlet step (rates 66-78 % in bench/run, 2D and 3D)
        real(wp), parameter :: PAIR_LOOP_SHARE = 0.7_wp
        integer :: i
        w = 1.0_wp
        if (.not. sim%subcycling) return
        do i = 1, sim%p%n_owned
            w(i) = PAIR_LOOP_SHARE / real(sim%level_substeps(sim%p%level(i)), wp) + &
                (1.0_wp - PAIR_LOOP_SHARE)
        end do
    end function particle_loads

    !> Is every level at the end of a step (always, without sub-cycling)? Snapshots,
    !> checkpoints and the end of a run wait for it (sph_schedule).
    pure logical function simulation_synchronised(sim)
        type(simulation_t), intent(in) :: sim
        simulation_synchronised = sim%cycle_step == 0
    end function simulation_synchronised

    !> Half a step from the saved step-start state with the step-start rates.
    subroutine predictor(sim, dt)
        type(simulation_t), intent(inout) :: sim
        real(wp), intent(in) :: dt
        call save_step_start(sim%p)
        call advance(sim%p, 0.5_wp * dt, integrated_density(sim), sim%phys%transport_velocity, &
            sim%phys%energy_equation)
    end subroutine predictor

    !> Ghosts take their owners' predicted positions and velocities.
    subroutine refresh_halo(sim, env)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        call refresh_ghosts(sim, env, moved_fields(sim))
    end subroutine refresh_halo

    !> What changes when particles move: positions, velocities, density, energy, and with the
    !> transport velocity its offset (sph_particles HALO_TRANSPORT).
    pure integer function moved_fields(sim)
        type(simulation_t), intent(in) :: sim
        moved_fields = HALO_MOVE
        if (sim%phys%transport_velocity) moved_fields = HALO_MOVE + HALO_TRANSPORT
    end function moved_fields

    !> Mirrors and the neighbour list for the predicted positions. A particle moves at most
    !> (vmax + amax dt/2) dt/2 in the half step (twice that in verlet's full-step drift),
    !> after the drift since the list was built;
    !> the list stays valid while two particles cannot close in by more than the skin.
    !> Mirrors change with the ghosts, so mirror walls always rebuild.
    !> shift: the bound to use instead (sub-cycling).
    subroutine prepare_boundaries(sim, dt, shift)
        type(simulation_t), intent(inout) :: sim
        real(wp), intent(in) :: dt
        real(wp), intent(in), optional :: shift
        real(wp) :: max_shift
        max_shift = stage_displacement_bound(sim%last_limits%max_speed, &
            sim%last_limits%max_accel, dt, sim%verlet)
        if (present(shift)) max_shift = shift
        if (2.0_wp * (sim%drift + max_shift) >= sim%list_skin .or. uses_mirrors(sim) .or. &
            sim%p%n_total /= sim%p%n_owned + sim%p%n_ghost) then
            call refresh_neighbours(sim)
        end if
    end subroutine prepare_boundaries

    !> The full step from the step-start state with the mid-step rates; time advances.
    subroutine corrector(sim, dt)
        type(simulation_t), intent(inout) :: sim
        real(wp), intent(in) :: dt
        call advance(sim%p, dt, integrated_density(sim), sim%phys%transport_velocity, &
            sim%phys%energy_equation)
        sim%time = sim%time + dt
        sim%step = sim%step + 1
        sim%last_limits%dt = dt
    end subroutine corrector

    !> Particle shifting (&numerics shifting, sph_shifting), when chosen: after the corrector
    !> the ghosts still hold the predicted (half-step) state, so they are refreshed first and
    !> the neighbour list is rebuilt for the corrected positions; the shift is then computed
    !> from the end-of-step state. D = A h |v|max dt with the step-start |v|max (global).
    !> Particles moved by the shift are handed on by the migration that follows.
    subroutine shift(sim, env, dt)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        real(wp), intent(in) :: dt
        integer :: lv, previous
        if (sim%phys%shifting == SHIFTING_NONE) return
        call timers_enter(sim%timers, TIMER_OTHER, previous)
        call refresh_ghosts(sim, env, HALO_MOVE)
        call refresh_neighbours(sim)
        if (multires(sim)) then
            do lv = 0, sim%zones%n_levels - 1
                call shift_particles(sim%level_phys(lv), sim%p, sim%nl, &
                    shifting_diffusion(sim%level_phys(lv), sim%last_limits%max_speed, dt), &
                    level=lv)
            end do
        else
            call shift_particles(sim%phys, sim%p, sim%nl, &
                shifting_diffusion(sim%phys, sim%last_limits%max_speed, dt))
        end if
        call timers_leave(sim%timers, previous)
    end subroutine shift

    !> Verlet-list reuse: while no two particles can have closed in by more than half the
    !> list skin since the last rebuild (2 drift < list_skin / 2), the ghosts only take their
    !> owners' new state and the neighbour list is kept; particles stay with their rank even
    !> if they left its region. Otherwise particles that left go to their new owner and the
    !> ghosts, mirrors and the list are rebuilt (cell order, wrapped periodic positions).
    !> The halo reaches support + skin + list_skin, so its ghosts cover every pair within the
    !> support while 2 drift + the motion of one step stays within skin + list_skin.
    !> The multi-resolution Verlet step (subcycled: present) refreshes the virtual particles
    !> itself, before its rates, and has the zones made anew only once every level is at the
    !> end of a step. moved: the largest distance an owned particle moved in this step, when
    !> the step knows it (otherwise found from the step-start positions).
    subroutine migrate_and_rebuild(sim, env, subcycled, moved)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        logical, intent(in), optional :: subcycled
        real(wp), intent(in), optional :: moved
        real(wp) :: step_move
        logical :: zones_reached
        if (present(moved)) then
            step_move = global_max(env, moved)
        else
            step_move = global_max(env, max_step_displacement(sim%p))
        end if
        ! a step that threw particles out of all proportion stops here, before the cell list
        ! bins them (the health check after the step would come too late)
        ! (finiteness first: a comparison with NaN traps in a debug build)
        if (.not. ieee_is_finite(step_move)) then
            call check_health(sim, env, step_move)
        else if (step_move > maxval(sim%cfg%domain%box_hi(1:sim%cfg%domain%dimension) - &
            sim%cfg%domain%box_lo(1:sim%cfg%domain%dimension))) then
            call check_health(sim, env, step_move)
        end if
        sim%drift = sim%drift + step_move
        sim%zone_drift = sim%zone_drift + step_move
        ! the zones' own schedule: made anew when their drift reaches the list's limit, as
        ! the list's does in a run that writes nothing (a stopped and restarted
        ! multi-resolution run departed from the uninterrupted one by 4e-3 of its peak speed
        ! when the zones followed the rebuilds of the checkpoint before)
        zones_reached = multires(sim) .and. .not. sim%zones_due .and. &
            2.0_wp * sim%zone_drift >= 0.5_wp * sim%list_skin
        if (2.0_wp * sim%drift < 0.5_wp * sim%list_skin .and. .not. zones_reached) then
            ! the sub-cycled step reads no ghost field before its next drift refreshes them
            ! (a zone update or a rebalance builds the halo anew)
            if (.not. present(subcycled)) call refresh_ghosts(sim, env, moved_fields(sim))
            if (uses_mirrors(sim)) call refresh_neighbours(sim)
            if (multires(sim) .and. .not. present(subcycled)) call refresh_virtuals(sim, env)
        else
            call migrate(sim, env)
            call simulation_prepare_neighbours(sim, env)
            sim%zones_due = multires(sim)
        end if
        call update_pressure(sim%phys, sim%p, 1, sim%p%n_total)
    end subroutine migrate_and_rebuild

    !> The virtual particles (of the levels `ended`, all when absent) take the other level's
    !> fields where they now are; their ghosts follow.
    subroutine refresh_virtuals(sim, env, ended)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        logical, intent(in), optional :: ended(0:)
        real(wp) :: start
        integer :: previous
        call timers_enter(sim%timers, TIMER_OTHER, previous)
        start = MPI_Wtime()
        call refresh_virtual_fields(sim%zones, sim%level_phys, sim%p, sim%level_stats, &
            sim%refresh_plan, sim%list_skin, ended, step_state=present(ended))
        call refresh_ghosts(sim, env, moved_fields(sim))
        sim%transition_seconds = sim%transition_seconds + (MPI_Wtime() - start)
        call timers_leave(sim%timers, previous)
    end subroutine refresh_virtuals

    !> Multi-resolution steps: conversions and new virtual particles in the transition zones
    !> (sph_transition_driver), then the halo and the neighbour list for the new set. The
    !> zones are made anew when particles have moved a twentieth of a smoothing length since
    !> they were last made (zone_drift, migrate_and_rebuild); in between, the
    !> virtual particles move with the flow and take the other level's fields every step
    !> (refresh_virtual_fields). The thesis makes them anew every step; at the time steps of
    !> low-Reynolds-number flows particles move about 1e-4 spacings per step, so that would
    !> make the same set again and again, and rebuild the neighbour list every step.
    subroutine update_transition_zones(sim, env)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        real(wp) :: start
        integer :: previous
        if (.not. sim%zones_due .or. .not. simulation_synchronised(sim)) return
        call timers_enter(sim%timers, TIMER_OTHER, previous)
        sim%zones_due = .false.
        sim%zone_drift = 0.0_wp
        start = MPI_Wtime()
        ! the sub-cycled step leaves the ghosts at their state before its kick
        if (sim%subcycling) call refresh_ghosts(sim, env, moved_fields(sim))
        call update_transition_zones_of(env, sim%zones, sim%level_phys, sim%solids, sim%domain, &
            sim%cfg%domain%box_lo, sim%cfg%domain%box_hi, sim%p, sim%next_id, sim%level_stats)
        if (sim%cfg%refinement%conserve) call hold_real_mass(sim, env)
        call simulation_prepare_neighbours(sim, env)
        ! the new virtuals' masses from the volumes their level leaves them, then the ghosts'
        call set_virtual_masses(sim%zones, sim%level_phys, sim%p, sim%nl)
        call refresh_ghosts(sim, env, HALO_GHOST)
        call update_pressure(sim%phys, sim%p, 1, sim%p%n_total)
        ! the new virtual particles have no rates yet: verlet evaluates them before its step
        sim%rates_stale = .true.
        sim%transition_seconds = sim%transition_seconds + (MPI_Wtime() - start)
        call timers_leave(sim%timers, previous)
    end subroutine update_transition_zones

    !> The largest sound speed of the levels: the fastest a fluid particle may move.
    pure real(wp) function fastest_sound(sim) result(c)
        type(simulation_t), intent(in) :: sim
        c = sim%phys%c
        if (allocated(sim%level_phys)) then
            if (size(sim%level_phys) > 0) c = max(c, maxval(sim%level_phys(:)%c))
        end if
    end function fastest_sound

    !> Stop collectively when the run has become unhealthy (sph_health): non-finite values, a
    !> fluid particle inside a solid, a density outside the band, a particle faster than
    !> sound, a collapsed time step. The
    !> lowest rank with a problem names it; a failure snapshot is written; exit status 3.
    !> moved: the step's largest displacement, checked against the box (check_displacement).
    subroutine check_health(sim, env, moved)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        real(wp), intent(in), optional :: moved
        type(health_problem_t) :: problem
        character(len=:), allocatable :: message, path, errmsg
        character(len=256) :: where
        integer :: reporter, stat
        type(h5_file_t) :: file
        ! a step shortened to land on an output time is not a collapse: the check watches the
        ! step the limits asked for
        if (sim%first_dt <= 0.0_wp) sim%first_dt = sim%uncapped_dt
        call check_particles(sim%cfg%health, sim%phys%rho0, sim%solids, sim%p, problem, &
            fastest_sound(sim))
        call check_timestep(sim%cfg%health, sim%first_dt, sim%uncapped_dt, problem, sim%time)
        ! a runaway step names itself rather than the first particle it threw into a wall
        if (present(moved) .and. problem%code /= HEALTH_NONFINITE) then
            problem = health_problem_t()
            call check_displacement(moved, maxval(sim%cfg%domain%box_hi(1: &
                sim%cfg%domain%dimension) - sim%cfg%domain%box_lo(1:sim%cfg%domain%dimension)), &
                problem)
        end if
        if (global_max(env, int(problem%code, i8)) == HEALTH_OK) return
        reporter = int(-global_max(env, int(merge(-env%rank, -huge(0), &
            problem%code /= HEALTH_OK), i8)))
        write(where, '(a,i0,a,i0,a)') ' at step ', sim%step, ', t = ' // &
            sci_text(sim%time, 5) // ' s (particle ', problem%id, ' at ' // &
            sci_text(problem%x(1), 5) // ' ' // sci_text(problem%x(2), 5) // ' ' // &
            sci_text(problem%x(3), 5) // ' m)'
        if (problem%id == 0) write(where, '(a,i0,a)') ' at step ', sim%step, &
            ', t = ' // sci_text(sim%time, 5) // ' s'
        message = problem%what // trim(where)
        call broadcast_text(env, message, reporter)
        path = snapshot_filename(trim(sim%cfg%output%output_dir), &
            trim(sim%cfg%run%case_name) // '_failure', sim%step)
        call snapshot_begin(env, sim%p, path, sim%time, sim%step, sim%cfg%domain%dimension, &
            code_version, sim%input_text, file, stat, errmsg)
        if (stat == 0) then
            call h5_write_attribute(file, 'failure', message)
            call snapshot_end(env, path, file, stat, errmsg)
        end if
        if (stat == 0) then
            message = message // '; failure snapshot ' // path
        else
            message = message // '; the failure snapshot could not be written: ' // errmsg
        end if
        call fatal_collective('health check', message, status=3, &
            abort=stat == SNAPSHOT_NOT_CLOSED)
    end subroutine check_health

    !> Density is integrated (continuity) unless it is summed from the neighbours.
    logical function integrated_density(sim)
        type(simulation_t), intent(in) :: sim
        integrated_density = sim%phys%density_method /= DENSITY_SUMMATION
    end function integrated_density

    !> Rebalance when the load imbalance passes the threshold from the input (collective).
    !> The load is the sum of the particles' weights (particle_loads).
    subroutine simulation_rebalance(sim, env)
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        real(wp) :: before, after
        character(len=128) :: line
        if (env%nranks == 1) return
        if (mod(sim%step, int(sim%cfg%parallel%rebalance_check_interval, i8)) /= 0) return
        before = domain_imbalance(env, sim%p%n_owned, sum(particle_loads(sim)))
        if (before <= sim%cfg%parallel%rebalance_threshold) return
        call synchronise(sim, env)
        call domain_partition(sim%domain, env, sim%p%x, sim%p%n_owned, particle_loads(sim))
        call halo_setup(sim%halo, sim%domain, halo_reach(sim))
        call migrate(sim, env)
        call simulation_prepare_neighbours(sim, env)
        after = domain_imbalance(env, sim%p%n_owned, sum(particle_loads(sim)))
        write(line, '(a,i0,a,f6.3,a,f6.3)') 'step ', sim%step, ': rebalanced, imbalance ', &
            before, ' -> ', after
        call log_info(trim(line))
    end subroutine simulation_rebalance
end module sph_stepper
