!> The run loop's bookkeeping: when snapshots are due (multiples of &output output_interval
!> and the listed output_times, landed on exactly), when checkpoints are due (every
!> &restart checkpoint_interval_steps steps, every checkpoint_interval_wall seconds of rank 0's
!> wall clock, and at the end), the log cadence with the progress line and its remaining-time
!> estimate, and the final report against the analytic reference. The decisions are plain
!> functions of the schedule (testable without MPI); the actions act on the simulation.
module sph_schedule
    use sph_kinds, only: wp, i8
    use sph_config, only: config_t
    use sph_mpi_env, only: mpi_env_t, global_max, global_sum
    use sph_memory, only: peak_resident_bytes
    use sph_logger, only: log_info, fixed_text, int_text, sci_text
    use sph_rates, only: local_max_speed
    use sph_reference, only: steady_after, error_percent_text
    use sph_stepper, only: simulation_t, simulation_write_snapshot, &
        simulation_write_checkpoint, simulation_analytic_error, fluid_density_range, &
        simulation_write_forces, simulation_log_forces, simulation_log_levels, &
        simulation_neighbours_per_particle, simulation_synchronised
    use sph_step_timers, only: timers_split_line
    use sph_signals, only: signal_received, signal_name
    implicit none
    private
    public :: schedule_t, schedule_init, schedule_dt_cap, schedule_after_step
    public :: schedule_final_report, log_progress_header
    public :: advance_output_time, run_finished, output_due, checkpoint_due_by_steps
    public :: checkpoint_due_by_wall

    !> Relative tolerance for reaching a time (t_end, an output time).
    real(wp), parameter :: time_tol = 1.0e-12_wp

    type :: schedule_t
        real(wp) :: t_end = 0.0_wp
        integer(i8) :: max_steps = 0
        real(wp) :: output_interval = 0.0_wp     !< 0 = listed times and the end only
        real(wp), allocatable :: output_times(:) !< listed snapshot times, increasing
        integer(i8) :: interval_index = 0        !< output_interval multiples passed
        integer :: next_listed = 1               !< first listed time not yet passed
        real(wp) :: next_output = 0.0_wp         !< the next snapshot time
        integer(i8) :: checkpoint_steps = 0      !< steps between checkpoints; 0 = off
        real(wp) :: checkpoint_wall = 0.0_wp     !< wall seconds between checkpoints; 0 = off
        integer(i8) :: log_every = 0             !< steps between log lines; 0 = not yet chosen
        integer(i8) :: steps_since_log = 0
        integer(i8) :: first_step = 0            !< the step the run (re)started from
        !> the last step after which every level was at the end of its step (sub-cycling)
        integer(i8) :: last_synchronised = 0
        real(wp) :: wall_start = 0.0_wp          !< wall clock at the start, last log line and
        real(wp) :: wall_last = 0.0_wp           !< last checkpoint (s)
        real(wp) :: wall_checkpoint = 0.0_wp
        logical :: finished = .false.
        logical :: forces_started = .false.      !< the forces file has this run's header
        real(wp) :: wall_limit = 0.0_wp          !< s of wall time before stopping; 0 = none
        character(len=:), allocatable :: stopped_by !< why the run stopped early ('' = it did not)
    end type schedule_t

contains

    !> The schedule of a run that starts (or continues) at time and step.
    subroutine schedule_init(sched, cfg, time, step)
        type(schedule_t), intent(out) :: sched
        type(config_t), intent(in) :: cfg
        real(wp), intent(in) :: time
        integer(i8), intent(in) :: step
        sched%t_end = cfg%run%t_end
        sched%max_steps = cfg%run%max_steps
        sched%output_interval = cfg%output%output_interval
        sched%output_times = cfg%output%output_times
        sched%checkpoint_steps = cfg%restart%checkpoint_interval_steps
        sched%checkpoint_wall = cfg%restart%checkpoint_interval_wall
        sched%interval_index = 0
        sched%next_listed = 1
        call advance_output_time(sched, time)
        call wall_clock(sched%wall_start)
        sched%wall_last = sched%wall_start
        sched%wall_checkpoint = sched%wall_start
        sched%first_step = step
        sched%last_synchronised = step
        sched%log_every = cfg%run%log_interval
        sched%steps_since_log = 0
        sched%finished = .false.
        ! a restart appends to the forces file of the run it continues
        sched%forces_started = step > 0
        sched%wall_limit = cfg%run%wall_time_limit
        sched%stopped_by = ''
    end subroutine schedule_init

    !> Set next_output to the first snapshot time after time (interval multiples and listed
    !> times; t_end when none is left).
    subroutine advance_output_time(sched, time)
        type(schedule_t), intent(inout) :: sched
        real(wp), intent(in) :: time
        real(wp) :: t
        t = sched%t_end
        if (sched%output_interval > 0.0_wp) then
            do
                sched%interval_index = sched%interval_index + 1
                if (real(sched%interval_index, wp) * sched%output_interval > &
                    time * (1.0_wp + time_tol)) exit
            end do
            sched%interval_index = sched%interval_index - 1
            t = min(t, real(sched%interval_index + 1, wp) * sched%output_interval)
        end if
        do while (sched%next_listed <= size(sched%output_times))
            if (sched%output_times(sched%next_listed) > time * (1.0_wp + time_tol)) exit
            sched%next_listed = sched%next_listed + 1
        end do
        if (sched%next_listed <= size(sched%output_times)) &
            t = min(t, sched%output_times(sched%next_listed))
        sched%next_output = t
    end subroutine advance_output_time

    !> The longest next step that does not pass the next snapshot time or the end.
    pure real(wp) function schedule_dt_cap(sched, time) result(dt_cap)
        type(schedule_t), intent(in) :: sched
        real(wp), intent(in) :: time
        dt_cap = min(sched%next_output, sched%t_end) - time
    end function schedule_dt_cap

    !> Whether the run has reached t_end (to a relative tolerance) or its step limit.
    pure logical function run_finished(sched, time, step)
        type(schedule_t), intent(in) :: sched
        real(wp), intent(in) :: time
        integer(i8), intent(in) :: step
        run_finished = time >= sched%t_end * (1.0_wp - time_tol) .or. step >= sched%max_steps
    end function run_finished

    !> A snapshot is due at the next output time and at the end of the run.
    pure logical function output_due(sched, time)
        type(schedule_t), intent(in) :: sched
        real(wp), intent(in) :: time
        output_due = time >= sched%next_output * (1.0_wp - time_tol) .or. sched%finished
    end function output_due

    !> A checkpoint by step count (the one at the end is written regardless): step is a
    !> multiple of the interval, or (since: the last step a checkpoint could have been
    !> written at, sub-cycling) one was passed after since.
    pure logical function checkpoint_due_by_steps(sched, step, since)
        type(schedule_t), intent(in) :: sched
        integer(i8), intent(in) :: step
        integer(i8), intent(in), optional :: since
        checkpoint_due_by_steps = .false.
        if (sched%checkpoint_steps <= 0) return
        if (present(since)) then
            checkpoint_due_by_steps = step / sched%checkpoint_steps > &
                since / sched%checkpoint_steps
        else
            checkpoint_due_by_steps = mod(step, sched%checkpoint_steps) == 0
        end if
    end function checkpoint_due_by_steps

    !> A checkpoint by wall clock; elapsed is the same on every rank (rank 0's clock).
    pure logical function checkpoint_due_by_wall(sched, elapsed)
        type(schedule_t), intent(in) :: sched
        real(wp), intent(in) :: elapsed
        checkpoint_due_by_wall = sched%checkpoint_wall > 0.0_wp .and. &
            elapsed >= sched%checkpoint_wall
    end function checkpoint_due_by_wall

    !> Everything due after a step: snapshot, checkpoint, log line (collective). With
    !> sub-cycling (sph_stepper) snapshots, checkpoints and the end of the run wait for a step
    !> after which every level is at the end of its own step; output times and t_end end
    !> the levels' steps there, so only max_steps, checkpoints by step count or wall time and
    !> stop requests can come a few steps late.
    subroutine schedule_after_step(sched, sim, env)
        type(schedule_t), intent(inout) :: sched
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        character(len=256) :: line

        sched%steps_since_log = sched%steps_since_log + 1
        if (sched%log_every == 0) then
            ! about 40 lines per run, from the first step's time step (at most every 10^15
            ! steps: t_end = 1e308 s over the step would overflow)
            if (sched%t_end < 1.0e15_wp * 40.0_wp * sim%last_limits%dt) then
                sched%log_every = max(1_i8, int(sched%t_end / sim%last_limits%dt / 40.0_wp, &
                    i8))
            else
                sched%log_every = 10_i8**15
            end if
            if (sim%step == sched%first_step + 1) then
                write(line, '(a,es10.3,a,es10.3,a,es10.3,a,es10.3)') 'time step: dt = ', &
                    sim%last_limits%dt, ' s (limits: CFL ', sim%last_limits%cfl, &
                    ', viscous ', sim%last_limits%viscous, ', force ', sim%last_limits%force
                call log_info(trim(line) // ')')
            end if
        end if
        if (simulation_synchronised(sim)) then
            call after_synchronised_step(sched, sim, env)
            sched%last_synchronised = sim%step
        end if
        if (mod(sim%step, sched%log_every) == 0 .or. sched%finished) then
            call log_progress(sched, sim, env)
            call simulation_log_levels(sim, env)
        end if
    end subroutine schedule_after_step

    !> What schedule_after_step does once every level is at the end of its step: the end of
    !> the run, snapshots and checkpoints.
    subroutine after_synchronised_step(sched, sim, env)
        type(schedule_t), intent(inout) :: sched
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        real(wp) :: wall_now
        logical :: row_follows
        sched%finished = run_finished(sched, sim%time, sim%step)
        if (.not. sched%finished) call check_stop_request(sched, env)
        if (output_due(sched, sim%time)) then
            call simulation_write_snapshot(sim, env)
            call advance_output_time(sched, sim%time)
        end if
        ! (schedule_after_step's log line, with the forces row, comes after the checkpoint)
        row_follows = mod(sim%step, sched%log_every) == 0 .or. sched%finished
        call wall_clock(wall_now)
        if (sched%finished) then
            call simulation_write_checkpoint(sim, env, row_follows)
        else if (checkpoint_due_by_steps(sched, sim%step, sched%last_synchronised)) then
            call simulation_write_checkpoint(sim, env, row_follows)
            sched%wall_checkpoint = wall_now
        end if
        ! wall-clock interval: rank 0's clock decides for everybody
        if (.not. sched%finished .and. sched%checkpoint_wall > 0.0_wp) then
            if (checkpoint_due_by_wall(sched, global_max(env, &
                merge(wall_now - sched%wall_checkpoint, 0.0_wp, env%rank == 0)))) then
                call simulation_write_checkpoint(sim, env, row_follows)
                sched%wall_checkpoint = wall_now
            end if
        end if
    end subroutine after_synchronised_step

    !> A scheduler's SIGTERM or SIGUSR1 (or a Ctrl-C's SIGINT) on any rank, or the wall-time
    !> limit on rank 0's clock: the run ends after this step with a checkpoint (collective).
    subroutine check_stop_request(sched, env)
        type(schedule_t), intent(inout) :: sched
        type(mpi_env_t), intent(in) :: env
        integer(i8) :: signal
        real(wp) :: wall_now
        character(len=64) :: text
        signal = global_max(env, int(signal_received(), i8))
        if (signal > 0) then
            write(text, '(a,i0,a)') 'signal ', signal, ' ('
            sched%stopped_by = trim(text) // signal_name(int(signal)) // ')'
        else if (sched%wall_limit > 0.0_wp) then
            call wall_clock(wall_now)
            if (global_max(env, merge(wall_now - sched%wall_start, 0.0_wp, env%rank == 0)) &
                >= sched%wall_limit) sched%stopped_by = '&run wall_time_limit'
        end if
        if (len(sched%stopped_by) > 0) sched%finished = .true.
    end subroutine check_stop_request

    !> The column header of the progress lines (rank 0).
    subroutine log_progress_header()
        call log_info('     step     time [s]       dt [s]   max |v| [m/s]  ' // &
            'rho min..max [kg/m^3]        wall/step [s]  remaining [s]')
    end subroutine log_progress_header

    !> One progress line: step, time, dt, max speed, fluid density range, wall time per step
    !> since the last line and the estimated remaining wall time (collective).
    subroutine log_progress(sched, sim, env)
        type(schedule_t), intent(inout) :: sched
        type(simulation_t), intent(inout) :: sim
        type(mpi_env_t), intent(in) :: env
        real(wp) :: wall_now, rho(2), per_step, remaining, vmax
        character(len=256) :: line
        call wall_clock(wall_now)
        rho = fluid_density_range(sim, env)
        ! steps left: to t_end at the current time step, or to max_steps if that comes first
        per_step = (wall_now - sched%wall_start) / real(sim%step - sched%first_step, wp)
        ! (the steps to t_end capped at max_steps' before the division: t_end / dt can
        ! overflow; sub-cycled levels may run up to max_subcycles - 1 steps past max_steps to
        ! end a step together, which is no time left, not a negative one)
        remaining = per_step * real(max(sched%max_steps - sim%step, 0_i8), wp)
        if (sched%t_end - sim%time < real(sched%max_steps - sim%step, wp) * &
                sim%last_limits%dt) remaining = per_step * max(0.0_wp, (sched%t_end - &
                sim%time) / max(sim%last_limits%dt, tiny(1.0_wp)))
        vmax = global_max(env, local_max_speed(sim%p, sim%phys%transport_velocity))
        write(line, '(i9,es13.5,es13.5,es16.6,es14.6,a,es12.6,es14.4,es14.3)') sim%step, &
            sim%time, sim%last_limits%dt, vmax, &
            rho(1), '..', rho(2), (wall_now - sched%wall_last) / real(sched%steps_since_log, wp), &
            remaining
        call log_info(trim(line))
        sched%wall_last = wall_now
        sched%steps_since_log = 0
        ! the forces on walls and bodies: a row per solid at every log line
        call simulation_write_forces(sim, env, fresh=.not. sched%forces_started)
        sched%forces_started = .true.
    end subroutine log_progress

    !> Steps, simulated and wall time, and the error against the analytic reference (and
    !> against its steady profile once that is meaningful) (collective).
    subroutine schedule_final_report(sched, sim, env)
        type(schedule_t), intent(in) :: sched
        type(simulation_t), intent(in) :: sim
        type(mpi_env_t), intent(in) :: env
        real(wp) :: wall_now, error
        character(len=256) :: line
        call wall_clock(wall_now)
        write(line, '(a,i0,a,es12.5,a,f11.3,a)') 'finished: ', sim%step - sched%first_step, &
            ' steps to t = ', sim%time, ' s in ', wall_now - sched%wall_start, ' s wall'
        call log_info(trim(line))
        ! an intended limit (status 0), but the user may have meant t_end
        if (sim%step >= sched%max_steps .and. sim%time < sched%t_end * (1.0_wp - time_tol)) &
            call log_info('stopped at &run max_steps = ' // int_text(sched%max_steps) // &
            ' before t_end = ' // sci_text(sched%t_end, 5) // ' s')
        call log_peak_memory(sim, env)
        call log_time_split(sim, env)
        if (len(sched%stopped_by) > 0) call log_info('stopped early by ' // &
            sched%stopped_by // ' at the checkpoint above; continue with --restart ' // &
            trim(sim%cfg%output%output_dir) // ' (exit status 75)')
        call simulation_log_forces(sim, env)
        if (trim(sim%ref%name) == 'none') return
        error = simulation_analytic_error(sim, env)
        write(line, '(a,es12.5,a)') 'error against the analytic ' // &
            trim(sim%ref%name) // ' solution at t = ', sim%time, ' s: relative L2 = '
        call log_info(trim(line) // ' ' // error_percent_text(error, 9, 5))
        if (sim%time > steady_after(sim%ref)) then
            error = simulation_analytic_error(sim, env, steady=.true.)
            call log_info('error against the steady profile: relative L2 = ' // &
                error_percent_text(error, 9, 5))
        end if
    end subroutine schedule_final_report

    !> Peak resident memory of all ranks together and of the largest, and per particle
    !> (owned particles of the last state) (collective).
    subroutine log_peak_memory(sim, env)
        type(simulation_t), intent(in) :: sim
        type(mpi_env_t), intent(in) :: env
        integer(i8) :: mine, particles
        real(wp) :: total
        character(len=256) :: line
        mine = peak_resident_bytes()
        if (global_max(env, merge(1_i8, 0_i8, mine < 0)) > 0) return
        total = global_sum(env, real(mine, wp))
        particles = global_sum(env, int(sim%p%n_owned, i8))
        write(line, '(a,f10.1,a,f10.1,a,f8.1,a)') 'peak memory: ', total / 1.0e6_wp, &
            ' MB over all ranks (largest rank ', real(global_max(env, mine), wp) / 1.0e6_wp, &
            ' MB), ', total / real(max(particles, 1_i8), wp), ' bytes per particle'
        call log_info(trim(line))
    end subroutine log_peak_memory

    !> Where the step loop's wall time went, mean over the ranks (sph_step_timers), and the
    !> neighbours per particle within the support (collective).
    subroutine log_time_split(sim, env)
        type(simulation_t), intent(in) :: sim
        type(mpi_env_t), intent(in) :: env
        character(len=128) :: line
        call log_info(timers_split_line(global_sum(env, sim%timers%seconds) / &
            real(env%nranks, wp), global_max(env, sim%timers%rate_evaluations)))
        write(line, '(a,f0.2,a)') 'neighbours: ', simulation_neighbours_per_particle(sim, env), &
            ' per particle within the kernel support'
        call log_info(trim(line))
    end subroutine log_time_split

    !> Wall-clock seconds.
    subroutine wall_clock(seconds)
        real(wp), intent(out) :: seconds
        integer(i8) :: count, rate
        call system_clock(count, rate)
        seconds = real(count, wp) / real(rate, wp)
    end subroutine wall_clock
end module sph_schedule
