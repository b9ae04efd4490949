!> sphremesh: mpirun -np N sphremesh INPUT.nml [--restart CHECKPOINT | --continue]
program sphremesh_main
    use sph_mpi_env, only: mpi_env_t, mpi_env_init_world, mpi_env_free, rank0_flag
    use sph_errors, only: fatal_collective, check_mpi, exit_process
    use sph_logger, only: logger_init, log_info, log_warning_summary
    use sph_command_line, only: options_t, parse_command_line, usage_text
    use sph_config, only: config_t, config_to_text
    use sph_input, only: load_config
    use sph_version, only: code_version, build_options
    use sph_simulation, only: simulation_run
    use sph_checkpoint, only: has_checkpoint
    use sph_stepper, only: simulation_t, simulation_setup, simulation_check_report, &
        simulation_remesh_file, simulation_refine_regions_file
    use sph_signals, only: signals_install
    use sph_memory, only: keep_freed_memory, note_startup_memory
    use mpi_f08, only: MPI_Finalize
    implicit none

    type(mpi_env_t) :: env
    type(options_t) :: opts
    type(config_t) :: cfg
    type(simulation_t) :: sim
    integer :: stat, ierr, status
    character(len=:), allocatable :: errmsg
    character(len=16) :: nranks_text

    call keep_freed_memory()
    call mpi_env_init_world(env)
    call note_startup_memory()
    call logger_init(env%rank)
    call parse_command_line(opts, stat, errmsg)
    if (stat /= 0) call fatal_collective('command line', errmsg)
    if (opts%show_help .or. opts%show_version) then
        if (opts%show_help) call log_info(usage_text())
        if (opts%show_version) then
            call log_info(code_version)
            call log_info('build: ' // build_options)
        end if
        call finish(0)
    end if

    write(nranks_text, '(i0)') env%nranks
    call log_info(code_version // ' on ' // trim(nranks_text) // ' MPI rank(s)')
    call log_info('build: ' // build_options)
    if (len(opts%regions_input) > 0) then
        ! --remesh refine IN OUT --regions INPUT.nml: INPUT.nml checked as for a run
        call load_config(env, opts%regions_input, cfg, stat, errmsg)
        if (stat /= 0) call fatal_collective('input', errmsg)
        call simulation_refine_regions_file(env, cfg, opts%regions_input, opts%remesh_in, &
            opts%remesh_out)
        call finish(0)
    else if (len(opts%remesh_mode) > 0) then
        call simulation_remesh_file(env, opts%remesh_mode, opts%remesh_in, opts%remesh_out)
        call finish(0)
    end if
    call load_config(env, opts%input_file, cfg, stat, errmsg)
    if (stat /= 0) call fatal_collective('input', errmsg)
    call log_info('resolved configuration (' // opts%input_file // '):')
    call log_info(config_to_text(cfg))
    if (len(cfg%notes) > 0) call log_info(cfg%notes)

    if (opts%check_only) then
        ! the input is valid (load_config stopped otherwise): set up and report, write nothing
        call simulation_setup(sim, env, cfg)
        call simulation_check_report(sim, env)
        call log_info('check: the input is valid')
        call finish(0)
    end if
    ! a scheduler's SIGTERM/SIGUSR1 asks a run for a checkpoint and a clean stop
    ! (sph_schedule); --remesh and --check, which write no checkpoint to stop at, keep the
    ! signals' default: they end there (they ran on to the end and exited 0, a remesh writing
    ! OUT after the signal; fz40)
    call signals_install(stat)
    if (stat /= 0) call log_info('warning: cannot install the SIGTERM/SIGUSR1 handlers')
    if (opts%continue_run) call continue_from(cfg%output%output_dir, cfg%run%case_name)
    call simulation_run(env, cfg, opts%restart_from, status, opts%continue_run)

    call log_warning_summary()
    call finish(status)

contains

    !> --continue: from the newest complete checkpoint of the case in its output folder when
    !> that holds a checkpoint file of the case (complete or not: none complete is the
    !> restart's error, not a silent start from t = 0), else a fresh start. A folder that
    !> exists but cannot be listed stops the run: a fresh start there would write over the
    !> earlier run's files.
    subroutine continue_from(folder, case_name)
        character(len=*), intent(in) :: folder, case_name
        logical :: exists, found
        integer :: list_stat
        found = .false.
        exists = .false.
        if (env%rank == 0) inquire(file=trim(folder) // '/.', exist=exists)
        ! (one answer for all: has_checkpoint is collective)
        exists = rank0_flag(env, exists)
        if (exists) then
            call has_checkpoint(env, trim(folder), trim(case_name), found, list_stat)
            if (list_stat /= 0) call fatal_collective('continue', "cannot list the " // &
                "&output output_dir '" // trim(folder) // "' for the checkpoints of case '" // &
                trim(case_name) // "'")
        end if
        if (found) then
            opts%restart_from = trim(folder)
        else
            call log_info("continue: no checkpoint of case '" // trim(case_name) // "' in '" // &
                trim(folder) // "': the run starts")
        end if
    end subroutine continue_from

    !> Leave with a status: 0 done, 75 stopped early with a checkpoint (resubmit).
    subroutine finish(exit_status)
        integer, intent(in) :: exit_status
        call mpi_env_free(env)
        call MPI_Finalize(ierr)
        call check_mpi(ierr, 'MPI_Finalize')
        call exit_process(exit_status)
    end subroutine finish
end program sphremesh_main
