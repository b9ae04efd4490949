!> Benchmark of full-domain remeshing (issue 10): refine, coarsen and same-level passes of a
!> 2D periodic box of about 10^5 fluid particles (a lattice, stepped a few times), against the
!> time step of the same particles before the pass and of the new particles after it. Each
!> mode runs REPS times on a fresh set; the table gives medians (the pass's range in
!> brackets): seconds, microseconds per particle and the pass in steps before (the target:
!> at most 3 steps) and after; then the pass's stages (simulation_t's remesh_stages, in
!> seconds): new positions, transfer, and the walls and neighbours rebuilt after them.
!>   mpirun -np N build/bin/sphremesh_bench_remesh [n [mode [jitter]]]
!> n x n particles (default 316); mode refine, coarsen or same runs that pass alone (for a
!> profile of one pass), all three by default (mode all). jitter (default 0, at most 0.9):
!> each particle moved by up to +-jitter/2 dx per axis before the first step, so that the
!> passes meet a disordered set as a developed flow's remesh does, not a lattice (0.8:
!> nearest distances 0.68 dx on average, coefficient of variation 0.27; the developed
!> cylinder flow of doc/validation.md: 0.69-0.75 dx, 0.21-0.25).
program bench_remesh
    use sph_kinds, only: wp, i8
    use sph_mpi_env, only: mpi_env_t, mpi_env_free, global_sum, global_max
    use bench_support, only: bench_start, bench_case
    use sph_stepper, only: simulation_t, simulation_step, simulation_remesh, &
        simulation_prepare_neighbours
    use sph_remesh_driver, only: REMESH_REFINE, REMESH_COARSEN, REMESH_SAME
    use sph_coarsen, only: id_hash
    use sph_particles, only: KIND_FLUID
    use mpi_f08, only: MPI_Finalize, MPI_Barrier, MPI_Wtime
    implicit none

    integer, parameter :: REPS = 3
    character(len=*), parameter :: ROW = '(a,a8,i12,a,i10,es14.3,es14.3,a,es9.2,a,es9.2,a,' // &
        'f11.3,2f17.2,f11.4,2f10.4)'
    type(mpi_env_t) :: env
    integer :: n, ierr, mode, rep, first_mode, last_mode
    character(len=16) :: mode_arg
    real(wp) :: jitter
    character(len=8), parameter :: names(3) = [character(len=8) :: 'refine', 'coarsen', 'same']
    real(wp) :: before(REPS), pass(REPS), after(REPS), stages(3, REPS)
    integer(i8) :: n_before, n_after

    n = 316
    call bench_start(env, n)
    first_mode = REMESH_REFINE
    last_mode = REMESH_SAME
    jitter = 0.0_wp
    if (command_argument_count() >= 2) then
        call get_command_argument(2, mode_arg)
        if (trim(mode_arg) /= 'all') then
            first_mode = findloc(names, trim(mode_arg), 1)
            if (first_mode == 0) then
                if (env%rank == 0) write(*, '(a)') 'bench_remesh: mode must be refine, ' // &
                    'coarsen, same or all, not ' // trim(mode_arg)
                error stop 1
            end if
            last_mode = first_mode
        end if
    end if
    if (command_argument_count() >= 3) then
        call get_command_argument(3, mode_arg)
        read(mode_arg, *) jitter
        if (jitter < 0.0_wp .or. jitter > 0.9_wp) then
            if (env%rank == 0) write(*, '(a)') 'bench_remesh: jitter must lie in [0, 0.9]'
            error stop 1
        end if
    end if
    if (env%rank == 0) then
        write(*, '(a,i0,a,i0,a,f4.2,a)') '# sphremesh remeshing benchmark, ', env%nranks, &
            ' rank(s), medians of ', REPS, ' passes, jitter ', jitter, ' dx'
        write(*, '(a)') '# pass      particles before -> after   step before [s]   pass [s] ' // &
            '[range]          us/particle  pass/step before  pass/step after' // &
            '  positions  transfer  rebuild [s]'
    end if
    do mode = first_mode, last_mode
        do rep = 1, REPS
            call run(mode, before(rep), pass(rep), after(rep), stages(:, rep), n_before, &
                n_after)
        end do
        if (env%rank == 0) write(*, ROW) '  ', names(mode), n_before, ' -> ', n_after, &
            median(before), median(pass), ' [', minval(pass), '-', maxval(pass), ']', &
            1.0e6_wp * median(pass) / real(max(n_before, n_after), wp), &
            median(pass) / median(before), median(pass) / median(after), &
            median(stages(1, :)), median(stages(2, :)), median(stages(3, :))
    end do
    call mpi_env_free(env)
    call MPI_Finalize(ierr)

contains

    !> One pass of `mode` on a fresh set: the mean step before it (5 steps) and after it
    !> (3 steps of the new set), and the pass (wall seconds, slowest rank) with its stages.
    subroutine run(mode, step_before, pass_seconds, step_after, stages, n_before, n_after)
        integer, intent(in) :: mode
        real(wp), intent(out) :: step_before, pass_seconds, step_after, stages(3)
        integer(i8), intent(out) :: n_before, n_after
        type(simulation_t) :: sim
        character(len=:), allocatable :: text
        character(len=32) :: dx_text
        write(dx_text, '(es24.16)') 1.0e-3_wp / n
        text = "&run case_name='bench' /" // new_line('a') // &
            "&domain dimension=2, box_hi=1.0e-3, 1.0e-3, dx=" // trim(dx_text) // " /" // &
            new_line('a') // "&fluid rho0=1000.0, nu=1.0e-6, sound_speed=1.0e-2 /" // &
            new_line('a')
        call bench_case(env, text, sim)
        if (jitter > 0.0_wp) call disorder(sim, 1.0e-3_wp / n)
        step_before = timed_steps(sim, 5)
        n_before = global_sum(env, int(sim%p%n_owned, i8))
        call MPI_Barrier(env%comm)
        pass_seconds = MPI_Wtime()
        call simulation_remesh(sim, env, mode)
        pass_seconds = global_max(env, MPI_Wtime() - pass_seconds)
        stages = sim%remesh_stages
        n_after = global_sum(env, int(sim%p%n_owned, i8))
        step_after = timed_steps(sim, 3)
    end subroutine run

    !> Each fluid particle moved by up to +-jitter/2 dx per axis, from a hash of its id (the
    !> same set on any rank count); the lattice's sites lie half a spacing inside the box,
    !> so every particle stays in it. Then the neighbours anew and the rates re-evaluated.
    subroutine disorder(sim, dx)
        type(simulation_t), intent(inout) :: sim
        real(wp), intent(in) :: dx
        integer :: i, a
        integer(i8) :: z
        do i = 1, sim%p%n_owned
            if (sim%p%kind(i) /= KIND_FLUID) cycle
            z = sim%p%id(i)
            do a = 1, 2
                z = id_hash(z)
                ! the top 52 bits as a fraction in [0, 1)
                sim%p%x(a, i) = sim%p%x(a, i) + jitter * dx * &
                    (real(shiftr(z, 12), wp) * 2.0_wp**(-52) - 0.5_wp)
            end do
        end do
        call simulation_prepare_neighbours(sim, env)
        sim%rates_stale = .true.
    end subroutine disorder

    !> Mean wall seconds (slowest rank) of `steps` steps of sim.
    real(wp) function timed_steps(sim, steps) result(seconds)
        type(simulation_t), intent(inout) :: sim
        integer, intent(in) :: steps
        integer :: s
        real(wp) :: t0
        call MPI_Barrier(env%comm)
        t0 = MPI_Wtime()
        do s = 1, steps
            call simulation_step(sim, env)
        end do
        seconds = global_max(env, (MPI_Wtime() - t0) / steps)
    end function timed_steps

    !> Median of a few values.
    pure real(wp) function median(values)
        real(wp), intent(in) :: values(:)
        real(wp) :: s(size(values)), t
        integer :: i, j
        s = values
        do i = 2, size(s)
            t = s(i)
            j = i - 1
            do while (j >= 1)
                if (s(j) <= t) exit
                s(j + 1) = s(j)
                j = j - 1
            end do
            s(j + 1) = t
        end do
        if (mod(size(s), 2) == 1) then
            median = s((size(s) + 1) / 2)
        else
            median = 0.5_wp * (s(size(s) / 2) + s(size(s) / 2 + 1))
        end if
    end function median
end program bench_remesh
