!> The run: set-up (or restart), the time loop (one step, rebalancing, then whatever the
!> schedule says is due: snapshot, checkpoint, log line) and the final report. The state and
!> the step are in sph_stepper, the bookkeeping of when things are due in sph_schedule.
module sph_simulation
    use sph_kinds, only: wp, i8
    use sph_config, only: config_t
    use sph_mpi_env, only: mpi_env_t, broadcast_text, agreed_status
    use sph_filesystem, only: make_directories, lock_for_process, LOCK_HELD, LOCK_BUSY, &
        LOCK_UNSUPPORTED, LOCK_FAILED
    use sph_errors, only: fatal_collective, remove_at_exit, STATUS_OUTPUT_FAILED
    use sph_stepper, only: simulation_t, simulation_setup, simulation_restart, &
        simulation_step, simulation_rebalance, simulation_write_snapshot
    use sph_schedule, only: schedule_t, schedule_init, schedule_dt_cap, schedule_after_step, &
        schedule_final_report, log_progress_header
    use sph_earlier_output, only: set_aside_earlier_output
    use sph_logger, only: log_warn, log_info, int_text, sci_text
    use sph_step_timers, only: timers_start, timers_stop, timers_enter, timers_leave, &
        TIMER_OTHER, TIMER_OUTPUT
    implicit none
    private
    public :: simulation_run

contains

    !> The whole run, to t_end or max_steps (collective). status: 0, or 75 when a signal or
    !> the wall-time limit stopped it early after a checkpoint (a job script resubmits).
    !> continuing (sphremesh --continue): a checkpoint at or past the run's end means the run
    !> is done (status 0, nothing written), not an error: a chain's link started after the
    !> run ended (a job submitted again, a link whose checkpoint fell on t_end) reports done.
    subroutine simulation_run(env, cfg, restart_from, status, continuing)
        type(mpi_env_t), intent(in) :: env
        type(config_t), intent(in) :: cfg
        character(len=*), intent(in) :: restart_from
        integer, intent(out) :: status
        logical, intent(in), optional :: continuing
        type(simulation_t) :: sim
        type(schedule_t) :: sched
        integer :: previous
        logical :: done_is_success
        character(len=:), allocatable :: why_done

        done_is_success = .false.
        if (present(continuing)) done_is_success = continuing
        status = 0

        if (len(restart_from) > 0) then
            ! (before the checkpoint is read: a run of the case that is writing could remove
            ! it meanwhile, and the refusal named the checkpoint instead of that run; not when
            ! there is nothing to read: the lock's folder, made first, turned a missing
            ! --restart folder into an empty one, and the restart's message with it)
            if (restart_source_exists(env, restart_from)) call lock_case_output(env, cfg)
            call simulation_restart(sim, env, cfg, restart_from)
            call lock_case_output(env, cfg)
            why_done = ''
            if (sim%time >= cfg%run%t_end * (1.0_wp - 1.0e-12_wp)) then
                why_done = "the checkpoint ('" // restart_from // "') is at t = " // &
                    sci_text(sim%time, 6) // ' s, at or past &run t_end = ' // &
                    sci_text(cfg%run%t_end, 6) // ' s: the run is done'
                if (.not. done_is_success) why_done = why_done // '; raise t_end to continue it'
            ! (max_steps counts from the run's start: a restart at or past it took a step all
            ! the same, its remaining time negative)
            else if (sim%step >= cfg%run%max_steps) then
                why_done = 'the checkpoint is at step ' // int_text(sim%step) // &
                    ', at or past &run max_steps = ' // int_text(int(cfg%run%max_steps, i8)) // &
                    ' (steps count from the start of the run): the run is done'
                if (.not. done_is_success) why_done = why_done // &
                    '; raise max_steps to continue it'
            end if
            if (len(why_done) > 0) then
                if (.not. done_is_success) call fatal_collective('restart', why_done)
                call log_info('continue: nothing to do: ' // why_done // &
                    ' (raise &run t_end or max_steps to go on)')
                return
            end if
            call keep_earlier_output(env, cfg, sim%step)
        else
            call simulation_setup(sim, env, cfg)
            call lock_case_output(env, cfg)
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

    !> Whether the file or folder a restart reads exists (rank 0 looks; collective).
    logical function restart_source_exists(env, from)
        type(mpi_env_t), intent(in) :: env
        character(len=*), intent(in) :: from
        logical :: is_file, is_folder
        integer :: found
        found = 0
        if (env%rank == 0) then
            inquire(file=from, exist=is_file)
            inquire(file=from // '/.', exist=is_folder)
            if (is_file .or. is_folder) found = 1
        end if
        restart_source_exists = agreed_status(env, found) == 1
    end function restart_source_exists

    !> One run of a case at a time in its output folder (collective): rank 0 holds the lock
    !> `<output_dir>/<case>.lock` for the life of the run (taken after a fresh run's set-up,
    !> before its first change to the folder, so that bad input leaves nothing there; before a
    !> restart reads its checkpoint; removed when the process leaves). A second run of the
    !> same input (a job submitted twice, a chain's link started while the one before ran) set the
    !> first run's files aside while it wrote them, and both then wrote over each other's
    !> snapshots, .xdmf and forces file. The system drops the lock when the run ends, however
    !> it ends, so none is left behind; where the file system has no locks (some parallel
    !> file systems are mounted without them) the run goes on with a warning.
    subroutine lock_case_output(env, cfg)
        type(mpi_env_t), intent(in) :: env
        type(config_t), intent(in) :: cfg
        character(len=:), allocatable :: path, about, text, made
        integer :: stat, dir_stat
        logical, save :: lock_taken = .false.
        ! (once a run: a restart takes it before and, when it did not, after its read)
        if (lock_taken) return
        lock_taken = .true.
        path = trim(cfg%output%output_dir) // '/' // trim(cfg%run%case_name) // '.lock'
        text = ''
        stat = LOCK_HELD
        if (env%rank == 0) then
            made = missing_folders(trim(cfg%output%output_dir))
            call make_directories(trim(cfg%output%output_dir), dir_stat)
            call lock_for_process(path, stat, about)
            if (dir_stat /= 0) then
                stat = LOCK_FAILED
                about = 'the folder cannot be made'
            end if
            if (stat == LOCK_BUSY .and. len(about) == 0) about = 'which has not said who it is'
            select case (stat)
            case (LOCK_BUSY)
                text = "another run of case '" // trim(cfg%run%case_name) // "' is " // &
                    "writing to '" // trim(cfg%output%output_dir) // "' (" // about // &
                    "; lock file '" // path // "'): two runs of a case in one folder " // &
                    'would write over each other''s files. Wait for it to end, or give ' // &
                    'this one another &output output_dir or &run case_name'
            case (LOCK_FAILED)
                text = "cannot make the lock file '" // path // "': " // about // &
                    ' (&output output_dir)'
            end select
        end if
        call broadcast_text(env, text)
        stat = agreed_status(env, stat)
        ! (the lock file goes when the run leaves, however it leaves but killed)
        if (env%rank == 0 .and. stat == LOCK_HELD) call remove_at_exit(path, made)
        if (stat == LOCK_BUSY) call fatal_collective('output', text)
        if (stat == LOCK_FAILED) call fatal_collective('output', text, STATUS_OUTPUT_FAILED)
        if (stat == LOCK_UNSUPPORTED) call log_warn("output: the file system of '" // &
            trim(cfg%output%output_dir) // "' has no file locks: a second run of case '" // &
            trim(cfg%run%case_name) // "' into it at the same time would not be noticed")
    contains
        !> The folders of `folder` and above it that do not exist yet, deepest first, one per
        !> line (what make_directories will make).
        function missing_folders(folder) result(list)
            character(len=*), intent(in) :: folder
            character(len=:), allocatable :: list
            logical :: exists
            integer :: k
            list = ''
            do k = len(folder), 1, -1
                if (k < len(folder)) then
                    if (folder(k + 1:k + 1) /= '/') cycle
                end if
                if (folder(k:k) == '/') cycle
                ! (a '.' or '..' component is no folder of its own to remove)
                if (folder(k:k) == '.') then
                    if (k == 1) cycle
                    if (folder(k - 1:k - 1) == '/') cycle
                    if (folder(k - 1:k - 1) == '.') then
                        if (k == 2) cycle
                        if (folder(k - 2:k - 2) == '/') cycle
                    end if
                end if
                inquire(file=folder(1:k) // '/.', exist=exists)
                if (exists) exit
                list = list // folder(1:k) // new_line('a')
            end do
        end function missing_folders
    end subroutine lock_case_output

    !> The files of an earlier run that this one could overwrite set aside before its first
    !> output (sph_earlier_output): after_step < 0 for a fresh run, else the restart's step.
    subroutine keep_earlier_output(env, cfg, after_step)
        type(mpi_env_t), intent(in) :: env
        type(config_t), intent(in) :: cfg
        integer(i8), intent(in) :: after_step
        character(len=:), allocatable :: folder, errmsg
        character(len=16) :: count_text
        integer :: moved, stat, dropped
        call set_aside_earlier_output(env, trim(cfg%output%output_dir), &
            trim(cfg%run%case_name), after_step, moved, folder, stat, errmsg, dropped)
        if (stat /= 0) call fatal_collective('output', errmsg // '; nothing was ' // &
            'overwritten: free space or move the earlier files away (or choose another ' // &
            '&output output_dir), then run again', STATUS_OUTPUT_FAILED)
        if (dropped > 0) then
            write(count_text, '(i0)') dropped
            call log_warn("output: dropped " // trim(count_text) // " row(s) cut short (a " // &
                "crash or a full disk of an earlier run) from '" // &
                trim(cfg%output%output_dir) // '/' // trim(cfg%run%case_name) // "_forces.csv'")
        end if
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
