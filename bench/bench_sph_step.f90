!> Benchmark: wall time per step per particle of the whole solver, and of the neighbour search
!> alone, on periodic boxes of growing size in 2D and 3D. Prints one line per case. The
!> last two columns use the processor time of the slowest rank (cpu_time) instead of the
!> wall clock: on a shared machine they are the steadier figures.
!>   mpirun -np N build/bin/sphremesh_bench [steps]
program bench_sph_step
    use sph_kinds, only: wp, i8
    use sph_mpi_env, only: mpi_env_t, mpi_env_free, global_sum, global_max
    use bench_support, only: bench_start, bench_case
    use sph_stepper, only: simulation_t, simulation_step
    use sph_cell_list, only: neighbour_list_t, build_neighbour_list
    use mpi_f08, only: MPI_Finalize, MPI_Barrier, MPI_Wtime
    implicit none

    type(mpi_env_t) :: env
    integer :: steps, ierr, k
    integer, parameter :: sizes_2d(3) = [64, 128, 256], sizes_3d(2) = [16, 32]

    steps = 20
    call bench_start(env, steps)
    if (env%rank == 0) then
        write(*, '(a,i0,a)') '# sphremesh benchmark, ', env%nranks, ' rank(s)'
        write(*, '(a)') '# case            particles  neighbours/particle  step[s]' // &
            '  us/(particle step)  search us/particle  cpu: step  search'
    end if
    do k = 1, size(sizes_2d)
        call run_case(2, sizes_2d(k))
    end do
    do k = 1, size(sizes_3d)
        call run_case(3, sizes_3d(k))
    end do
    call mpi_env_free(env)
    call MPI_Finalize(ierr)

contains

    subroutine run_case(dim, n)
        integer, intent(in) :: dim, n
        type(simulation_t) :: sim
        type(neighbour_list_t) :: nl
        integer :: s
        character(len=:), allocatable :: text
        character(len=32) :: dim_text, dx_text
        real(wp) :: t0, t_step, t_search, pairs, c0, c_step, c_search
        integer(i8) :: n_total
        write(dim_text, '(i0)') dim
        write(dx_text, '(es24.16)') 1.0_wp / n
        text = "&run case_name='bench' /" // new_line('a') // "&domain dimension=" // &
            trim(dim_text) // ", box_hi=1.0, 1.0, 1.0, dx=" // trim(dx_text) // " /" // &
            new_line('a') // "&fluid nu=1.0e-2, sound_speed=1.0 /" // new_line('a')
        call bench_case(env, text, sim)
        t0 = MPI_Wtime()
        call cpu_time(c0)
        do s = 1, steps
            call simulation_step(sim, env)
        end do
        t_step = global_max(env, (MPI_Wtime() - t0) / steps)
        c_step = cpu_seconds_since(c0) / steps
        t0 = MPI_Wtime()
        call cpu_time(c0)
        do s = 1, steps
            call build_neighbour_list(sim%p%x, sim%p%n_total, sim%p%n_owned, dim, &
                sim%phys%kernel%support, nl)
        end do
        t_search = global_max(env, (MPI_Wtime() - t0) / steps)
        c_search = cpu_seconds_since(c0) / steps
        n_total = global_sum(env, int(sim%p%n_owned, i8))
        pairs = global_sum(env, real(nl%n_pairs, wp))
        if (env%rank == 0) write(*, '(a,i1,a,i4,i14,f14.1,es14.4,f14.3,f16.3,f16.3,f8.3)') &
            '  box', dim, 'd n=', n, n_total, pairs / n_total, t_step, &
            t_step / n_total * env%nranks * 1.0e6_wp, &
            t_search / n_total * env%nranks * 1.0e6_wp, &
            c_step / n_total * env%nranks * 1.0e6_wp, c_search / n_total * env%nranks * 1.0e6_wp
    end subroutine run_case

    !> Processor seconds of the slowest rank since cpu_time gave `start`.
    real(wp) function cpu_seconds_since(start)
        real(wp), intent(in) :: start
        real(wp) :: now
        call cpu_time(now)
        cpu_seconds_since = global_max(env, now - start)
    end function cpu_seconds_since
end program bench_sph_step
