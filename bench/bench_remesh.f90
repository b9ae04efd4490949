!> Benchmark of full-domain remeshing (issue 10): one refine and one coarsen pass of a 2D
!> periodic box of about 10^5 fluid particles (a lattice, stepped a few times), against
!> the time step of the same particles. Prints seconds, microseconds per particle and the
!> ratio to one step (target: at most 3 steps per pass).
!>   mpirun -np N build/bin/sphremesh_bench_remesh [n]    (n x n particles, default 316)
program bench_remesh
    use sph_kinds, only: wp, i8
    use sph_mpi_env, only: mpi_env_t, mpi_env_free, global_sum, global_max
    use bench_support, only: bench_start, bench_case
    use sph_stepper, only: simulation_t, simulation_step, simulation_remesh
    use sph_remesh_driver, only: REMESH_REFINE, REMESH_COARSEN, REMESH_SAME
    use mpi_f08, only: MPI_Finalize, MPI_Barrier, MPI_Wtime
    implicit none

    type(mpi_env_t) :: env
    integer :: n, ierr, mode
    character(len=8), parameter :: names(3) = [character(len=8) :: 'refine', 'coarsen', 'same']
    real(wp) :: step_seconds, pass_seconds
    integer(i8) :: n_before, n_after

    n = 316
    call bench_start(env, n)
    if (env%rank == 0) then
        write(*, '(a,i0,a)') '# sphremesh remeshing benchmark, ', env%nranks, ' rank(s)'
        write(*, '(a)') '# pass      particles before -> after   step [s]   pass [s]' // &
            '   us/particle   pass/step'
    end if
    do mode = REMESH_REFINE, REMESH_SAME
        call run(mode, step_seconds, pass_seconds, n_before, n_after)
        if (env%rank == 0) write(*, '(a,a8,i12,a,i10,2es11.3,f14.3,f12.2)') '  ', &
            names(mode), n_before, ' -> ', n_after, step_seconds, pass_seconds, &
            1.0e6_wp * pass_seconds / real(max(n_before, n_after), wp), &
            pass_seconds / step_seconds
    end do
    call mpi_env_free(env)
    call MPI_Finalize(ierr)

contains

    subroutine run(mode, step_seconds, pass_seconds, n_before, n_after)
        integer, intent(in) :: mode
        real(wp), intent(out) :: step_seconds, pass_seconds
        integer(i8), intent(out) :: n_before, n_after
        type(simulation_t) :: sim
        integer :: s
        character(len=:), allocatable :: text
        character(len=32) :: dx_text
        real(wp) :: t0
        integer, parameter :: steps = 5
        write(dx_text, '(es24.16)') 1.0e-3_wp / n
        text = "&run case_name='bench' /" // new_line('a') // &
            "&domain dimension=2, box_hi=1.0e-3, 1.0e-3, dx=" // trim(dx_text) // " /" // &
            new_line('a') // "&fluid rho0=1000.0, nu=1.0e-6, sound_speed=1.0e-2 /" // &
            new_line('a')
        call bench_case(env, text, sim)
        t0 = MPI_Wtime()
        do s = 1, steps
            call simulation_step(sim, env)
        end do
        step_seconds = global_max(env, (MPI_Wtime() - t0) / steps)
        n_before = global_sum(env, int(sim%p%n_owned, i8))
        call MPI_Barrier(env%comm)
        t0 = MPI_Wtime()
        call simulation_remesh(sim, env, mode)
        pass_seconds = global_max(env, MPI_Wtime() - t0)
        n_after = global_sum(env, int(sim%p%n_owned, i8))
    end subroutine run
end program bench_remesh
