!> Benchmark of multi-resolution runs (the thesis' ch. 5, Figure 5-2): wall time per unit
!> simulated time of the channel of input/multires_cost.nml (4 L long, fine particles in a
!> quarter of it across its width, coarse elsewhere, two transition zones) against the same
!> channel uniformly fine, for growing particle counts. The transition zones' work (making
!> the virtual particles, conversions, the extra rebuild, the refresh of their fields) is
!> timed separately. Two pairs of runs per size:
!> - the predictor-corrector, every level at the fine level's time step;
!> - velocity Verlet, the uniform run against the multi-resolution run with sub-cycling
!>   (&refinement max_subcycles = 4: the coarse level steps once per four fine steps, as
!>   its viscous limit allows).
!> The machines it runs on vary in speed from minute to minute: the runs of a size
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
    !> alternations of the multi-resolution and the uniform runs per size
    integer, parameter :: REPS = 3
    !> the two comparisons: integrator, and the multi-resolution run's &refinement
    character(len=*), parameter :: integrators(2) = [character(len=19) :: &
        'predictor_corrector', 'verlet']
    character(len=*), parameter :: refinements(2) = [character(len=32) :: &
        '', '&refinement max_subcycles=4 /']
    real(wp) :: t_multi(2), t_zone(2), t_fine(2), t, z
    integer(i8) :: n_multi, n_virtual, n_fine, n_none
    integer :: rep, c

    steps = 20
    call bench_start(env, steps)
    if (env%rank == 0) then
        write(*, '(a,i0,a)') '# sphremesh multi-resolution benchmark (thesis Fig. 5-2), ', &
            env%nranks, ' rank(s); wall s per simulated s'
        write(*, '(a)') '#                                               ' // &
            '---- predictor-corrector, one time step ----   ' // &
            '---- Verlet, coarse level sub-cycled (4) ----'
        write(*, '(a)') '# dx fine   particles: uniform  multi (real + virtual)' // &
            '      uniform       multi    (zones) multi/uniform' // &
            '      uniform       multi    (zones) multi/uniform'
    end if
    do k = 1, size(coarse_across)
        t_multi = huge(1.0_wp)
        t_fine = huge(1.0_wp)
        do rep = 1, REPS
            do c = 1, 2
                call run(coarse_across(k), .true., c, t, z, n_multi, n_virtual)
                if (t < t_multi(c)) then
                    t_multi(c) = t
                    t_zone(c) = z
                end if
                call run(coarse_across(k), .false., c, t, z, n_fine, n_none)
                t_fine(c) = min(t_fine(c), t)
            end do
        end do
        if (env%rank == 0) write(*, '(a,i0,i20,i13,a,i0,2(es19.4,es12.4,es11.2,f12.3))') &
            '  L/', 2 * coarse_across(k), n_fine, n_multi, ' + ', n_virtual, &
            (t_fine(c), t_multi(c), t_zone(c), t_multi(c) / t_fine(c), c = 1, 2)
    end do
    call mpi_env_free(env)
    call MPI_Finalize(ierr)

contains

    !> Wall seconds per simulated second (slowest rank) after a warm-up step, the transition
    !> zones' part, and the real and virtual particle counts; comparison c (integrators,
    !> refinements).
    subroutine run(n_coarse, multi, c, seconds, zone_seconds, n_real, n_virtual)
        integer, intent(in) :: n_coarse, c
        logical, intent(in) :: multi
        real(wp), intent(out) :: seconds, zone_seconds
        integer(i8), intent(out) :: n_real, n_virtual
        type(simulation_t) :: sim
        integer :: s
        character(len=:), allocatable :: text
        character(len=32) :: dx_text
        real(wp) :: t0, z0, time0
        write(dx_text, '(es24.16)') 1.0e-3_wp / (n_coarse * merge(1, 2, multi))
        text = "&run case_name='bench' /" // new_line('a') // &
            "&domain dimension=2, box_hi=4.0e-3, 1.0e-3, dx=" // trim(dx_text) // &
            ", boundary='periodic','periodic','wall','wall' /" // new_line('a') // &
            "&fluid rho0=1000.0, nu=1.0e-6, body_force=2.0e-4, 0.0 /" // new_line('a') // &
            "&numerics integrator='" // trim(integrators(c)) // "' /" // new_line('a')
        if (multi) text = text // "&region lo=1.5e-3, -1.0e-3, hi=2.5e-3, 2.0e-3 /" // &
            new_line('a') // trim(refinements(c)) // new_line('a')
        call bench_case(env, text, sim)
        t0 = MPI_Wtime()
        z0 = sim%transition_seconds
        time0 = sim%time
        do s = 1, steps
            call simulation_step(sim, env)
        end do
        seconds = global_max(env, MPI_Wtime() - t0) / (sim%time - time0)
        zone_seconds = global_max(env, sim%transition_seconds - z0) / (sim%time - time0)
        n_real = global_sum(env, int(count(sim%p%id(1:sim%p%n_owned) >= 0), i8))
        n_virtual = global_sum(env, int(count(sim%p%id(1:sim%p%n_owned) < 0), i8))
    end subroutine run
end program bench_multires
