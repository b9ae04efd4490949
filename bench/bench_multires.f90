!> Benchmark of multi-resolution runs (the thesis' ch. 5, Figure 5-2): wall time per unit
!> simulated time of the channel of input/multires_cost.nml (4 L long, fine particles in a
!> quarter of it across its width, coarse elsewhere, two transition zones) against the same
!> channel uniformly fine, for growing particle counts. The transition zones' work (making
!> the virtual particles, conversions, the extra rebuild, the refresh of their fields) is
!> timed separately. Both runs
!> take the fine level's time step, so the ratio per step is the ratio per simulated time.
!> The machines it runs on vary in speed from minute to minute: the two runs of a size
!> alternate REPS times and each keeps its fastest (the zones' time is the fastest multi
!> run's). The flow is slow: the neighbour lists are rebuilt (and the zones made anew) about
!> every 4,000 steps at L/320 (2,000 in the uniform run), so neither run rebuilds within
!> `steps`, and the zones' time is the per-step refresh of the virtual particles' fields.
!> These are the figures of the steps between rebuilds, which are nearly all of them.
!>   mpirun -np N build/bin/sphremesh_bench_multires [steps]
program bench_multires
    use sph_kinds, only: wp, i8
    use sph_mpi_env, only: mpi_env_t, mpi_env_free, global_sum, global_max
    use bench_support, only: bench_start, bench_case
    use sph_stepper, only: simulation_t, simulation_step
    use mpi_f08, only: MPI_Finalize, MPI_Barrier, MPI_Wtime
    implicit none

    type(mpi_env_t) :: env
    integer :: steps, ierr, k
    !> particles across the channel at the coarse level
    integer, parameter :: coarse_across(5) = [10, 20, 40, 80, 160]
    !> alternations of the multi-resolution and the uniform run per size
    integer, parameter :: REPS = 3
    real(wp) :: t_multi, t_zone, t_fine, dt, t, z
    integer(i8) :: n_multi, n_virtual, n_fine, n_none
    integer :: rep

    steps = 20
    call bench_start(env, steps)
    if (env%rank == 0) then
        write(*, '(a,i0,a)') '# sphremesh multi-resolution benchmark (thesis Fig. 5-2), ', &
            env%nranks, ' rank(s)'
        write(*, '(a)') '# dx fine   particles: uniform  multi (real + virtual)' // &
            '   wall s per simulated s: uniform     multi  (zones)  multi/uniform'
    end if
    do k = 1, size(coarse_across)
        t_multi = huge(1.0_wp)
        t_fine = huge(1.0_wp)
        do rep = 1, REPS
            call run(coarse_across(k), .true., t, z, n_multi, n_virtual, dt)
            if (t < t_multi) then
                t_multi = t
                t_zone = z
            end if
            call run(coarse_across(k), .false., t, z, n_fine, n_none, dt)
            t_fine = min(t_fine, t)
        end do
        if (env%rank == 0) write(*, '(a,i0,i20,i13,a,i0,a,es22.4,es12.4,es10.2,f12.3)') &
            '  L/', 2 * coarse_across(k), n_fine, n_multi, ' + ', n_virtual, '', &
            t_fine / dt, t_multi / dt, t_zone / dt, t_multi / t_fine
    end do
    call mpi_env_free(env)
    call MPI_Finalize(ierr)

contains

    !> Mean wall seconds per step (slowest rank) after a warm-up, the transition zones' part,
    !> the real and virtual particle counts and the time step.
    subroutine run(n_coarse, multi, seconds, zone_seconds, n_real, n_virtual, dt)
        integer, intent(in) :: n_coarse
        logical, intent(in) :: multi
        real(wp), intent(out) :: seconds, zone_seconds, dt
        integer(i8), intent(out) :: n_real, n_virtual
        type(simulation_t) :: sim
        integer :: s
        character(len=:), allocatable :: text
        character(len=32) :: dx_text
        real(wp) :: t0, z0
        write(dx_text, '(es24.16)') 1.0e-3_wp / (n_coarse * merge(1, 2, multi))
        text = "&run case_name='bench' /" // new_line('a') // &
            "&domain dimension=2, box_hi=4.0e-3, 1.0e-3, dx=" // trim(dx_text) // &
            ", boundary='periodic','periodic','wall','wall' /" // new_line('a') // &
            "&fluid rho0=1000.0, nu=1.0e-6, body_force=2.0e-4, 0.0 /" // new_line('a')
        if (multi) text = text // "&region lo=1.5e-3, -1.0e-3, hi=2.5e-3, 2.0e-3 /" // &
            new_line('a')
        call bench_case(env, text, sim)
        t0 = MPI_Wtime()
        z0 = sim%transition_seconds
        do s = 1, steps
            call simulation_step(sim, env)
        end do
        seconds = global_max(env, (MPI_Wtime() - t0) / steps)
        zone_seconds = global_max(env, (sim%transition_seconds - z0) / steps)
        dt = sim%last_limits%dt
        n_real = global_sum(env, int(count(sim%p%id(1:sim%p%n_owned) >= 0), i8))
        n_virtual = global_sum(env, int(count(sim%p%id(1:sim%p%n_owned) < 0), i8))
    end subroutine run
end program bench_multires
