!> What the benchmark programs share: the world communicator with a quiet logger, the
!> optional integer argument, and a case set up from namelist text and stepped once.
module bench_support
    use sph_kinds, only: wp
    use sph_mpi_env, only: mpi_env_t, mpi_env_init_world
    use sph_config, only: config_t, config_parse
    use sph_stepper, only: simulation_t, simulation_setup, simulation_step
    use sph_logger, only: logger_init, VERBOSITY_QUIET
    use sph_memory, only: keep_freed_memory
    use mpi_f08, only: MPI_Barrier
    implicit none
    private
    public :: bench_start, bench_case

contains

    !> MPI and a quiet logger; `value` is the first command-line argument when there is one.
    subroutine bench_start(env, value)
        type(mpi_env_t), intent(out) :: env
        integer, intent(inout) :: value
        character(len=32) :: arg
        ! as the main program does (sph_memory)
        call keep_freed_memory()
        call mpi_env_init_world(env)
        call logger_init(env%rank, VERBOSITY_QUIET)
        if (command_argument_count() >= 1) then
            call get_command_argument(1, arg)
            read(arg, *) value
        end if
    end subroutine bench_start

    !> The case of namelist `text`, set up, stepped once (warm-up) and synchronised.
    subroutine bench_case(env, text, sim)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: text
        type(simulation_t), intent(out) :: sim
        type(config_t) :: cfg
        integer :: stat
        character(len=:), allocatable :: msg
        call config_parse(cfg, text, 'bench', stat, msg)
        if (stat /= 0) then
            write(*, '(a)') msg
            error stop 1
        end if
        call simulation_setup(sim, env, cfg)
        call simulation_step(sim, env)
        call MPI_Barrier(env%comm)
    end subroutine bench_case
end module bench_support
