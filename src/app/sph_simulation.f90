!> The run: set-up (or restart), the time loop (one step, rebalancing, then whatever the
!> schedule says is due: snapshot, checkpoint, log line) and the final report. The state and
!> the step are in sph_stepper, the bookkeeping of when things are due in sph_schedule.
module sph_simulation
    use sph_kinds, only: wp, i8
    use sph_config, only: config_t
    use sph_mpi_env, only: mpi_env_t
    use sph_errors, only: fatal_collective, STATUS_OUTPUT_FAILED
    use sph_stepper, only: simulation_t, simulation_setup, simulation_restart, &
        simulation_step, simulation_rebalance, simulation_write_snapshot
    use sph_schedule, only: schedule_t, schedule_init, schedule_dt_cap, schedule_after_step, &
        schedule_final_report, log_progress_header
    use sph_earlier_output, only: set_aside_earlier_output
    use sph_logger, only: log_warn, int_text
    use sph_step_timers, only: timers_start, timers_stop, timers_enter, timers_leave, &
        TIMER_OTHER, TIMER_OUTPUT
    implicit none
    private
    public :: simulation_run

contains

    !> The whole run, to t_end or max_steps (collective). status: 0, or 75 when a signal or
    !> the wall-time limit stopped it early after a checkpoint (a job script resubmits).
    subroutine simulation_run(env, cfg, restart_from, status)
        type(mpi_env_t), intent(in) :: env
        type(config_t), intent(in) :: cfg
        character(len=*), intent(in) :: restart_from
        integer, intent(out) :: status
        type(simulation_t) :: sim
        type(schedule_t) :: sched
        integer :: previous

        if (len(restart_from) > 0) then
            call simulation_restart(sim, env, cfg, restart_from)
            if (sim%time >= cfg%run%t_end * (1.0_wp - 1.0e-12_wp)) &
                call fatal_collective('restart', &
                'the checkpoint is already at the end time; raise &run t_end to continue the run')
            ! (max_steps counts from the run's start: a restart at or past it took a step all
            ! the same, its remaining time negative)
            if (sim%step >= cfg%run%max_steps) call fatal_collective('restart', &
                'the checkpoint is at step ' // int_text(sim%step) // ', at or past &run ' // &
                'max_steps = ' // int_text(int(cfg%run%max_steps, i8)) // ' (steps count ' // &
                'from the start of the run); raise max_steps to continue the run')
            call keep_earlier_output(env, cfg, sim%step)
        else
            call simulation_setup(sim, env, cfg)
            call keep_earlier_output(env, cfg, -1_i8)
            call simulation_write_snapshot(sim, env)
        end if
        call schedule_init(sched, cfg, sim%time, sim%step)
        call log_progress_header()
        call timers_start(sim%timers)
        do while (.not. sched%finished)
            call simulation_step(sim, env, schedule_dt_cap(sched, sim%time))
            call timers_enter(sim%timers, TIMER_OTHER, previous)
            call simulation_rebalance(sim, env)
            call timers_leave(sim%timers, previous)
            call timers_enter(sim%timers, TIMER_OUTPUT, previous)
            call schedule_after_step(sched, sim, env)
            call timers_leave(sim%timers, previous)
        end do
        call timers_stop(sim%timers)
        call schedule_final_report(sched, sim, env)
        status = merge(75, 0, len(sched%stopped_by) > 0)
    end subroutine simulation_run

    !> The files of an earlier run that this one could overwrite set aside before its first
    !> output (sph_earlier_output): after_step < 0 for a fresh run, else the restart's step.
    subroutine keep_earlier_output(env, cfg, after_step)
        type(mpi_env_t), intent(in) :: env
        type(config_t), intent(in) :: cfg
        integer(i8), intent(in) :: after_step
        character(len=:), allocatable :: folder, errmsg
        character(len=16) :: count_text
        integer :: moved, stat
        call set_aside_earlier_output(env, trim(cfg%output%output_dir), &
            trim(cfg%run%case_name), after_step, moved, folder, stat, errmsg)
        if (stat /= 0) call fatal_collective('output', errmsg // '; nothing was ' // &
            'overwritten: move the earlier files away or choose another &output output_dir', &
            STATUS_OUTPUT_FAILED)
        if (moved == 0) return
        write(count_text, '(i0)') moved
        if (after_step < 0) then
            call log_warn("output: '" // trim(cfg%output%output_dir) // "' held " // &
                trim(count_text) // " file(s) of an earlier run of case '" // &
                trim(cfg%run%case_name) // "'; moved to '" // folder // "' (nothing is " // &
                'overwritten)')
        else
            call log_warn("output: '" // trim(cfg%output%output_dir) // "' held " // &
                trim(count_text) // ' file(s) of steps after the checkpoint (an earlier ' // &
                "continuation); moved to '" // folder // "' (nothing is overwritten)")
        end if
    end subroutine keep_earlier_output
end module sph_simulation
