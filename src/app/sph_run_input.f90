!> The run's schedule as read from input: &run (end time, step limit, log cadence, analytic
!> reference) and &output (where and when snapshots are written). Read by sph_config; used by
!> the driver (sph_schedule, sph_stepper).
module sph_run_input
    use sph_kinds, only: wp
    use sph_namelist, only: nml_group_t
    use sph_filesystem, only: MAX_FILE_PATH
    use sph_logger, only: sci_text
    implicit none
    private
    public :: run_input_t, output_input_t, read_run_input, read_output_input

    integer, parameter :: name_len = 32, path_len = 512, max_output_times = 256
    !> snapshots that &output output_interval may ask for up to t_end: a typo in its
    !> exponent (1.0e-9 for 1.0e-2) wrote a snapshot at every step, each step cut short to
    !> land on the next one, over a thousand files in 15 s
    real(wp), parameter :: max_interval_snapshots = 1.0e5_wp

    type :: run_input_t
        character(len=name_len) :: case_name
        real(wp) :: t_end
        integer :: max_steps
        integer :: log_interval          !< steps between log lines; 0 = automatic
        character(len=name_len) :: analytic
        real(wp) :: wall_time_limit      !< s of wall time; 0 = none
    end type run_input_t

    type :: output_input_t
        character(len=path_len) :: output_dir
        real(wp) :: output_interval       !< 0 = first and last state only
        real(wp), allocatable :: output_times(:)   !< exact snapshot times, increasing
    end type output_input_t

contains

    !> Read the &run group (case name, end time, step limit, log interval, analytic reference,
    !> wall-time limit).
    subroutine read_run_input(grp, run)
        type(nml_group_t), intent(inout) :: grp
        type(run_input_t), intent(out) :: run
        call grp%get_string('case_name', run%case_name, 'sphremesh', &
            doc='name used in output file names (letters, digits, _ - .)')
        if (len_trim(run%case_name) == 0 .or. verify(trim(run%case_name), &
            'abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_-.') /= 0) &
            call grp%error('case_name', &
                'letters, digits, "_", "-" and "." only (used in file names)')
        ! (the snapshots of a case 'p_checkpoint' are named as the checkpoints of a case 'p',
        ! those of 'p_failure' as its failure snapshots: a run of 'p' in the folder took them
        ! for its own and set them aside)
        if (ends_with(trim(run%case_name), '_checkpoint') .or. &
            ends_with(trim(run%case_name), '_failure')) call grp%error('case_name', &
            'must not end in "_checkpoint" or "_failure": its snapshots would be named as ' // &
            'the checkpoints or failure snapshots of another case')
        ! (at most 1e20 s: counts of steps and snapshots up to it stay finite)
        call grp%get_real('t_end', run%t_end, 1.0_wp, min_exclusive=0.0_wp, max=1.0e20_wp, &
            unit='s', doc='end time')
        call grp%get_int('max_steps', run%max_steps, 100000000, min=1, &
            doc='stop after this many steps')
        call grp%get_int('log_interval', run%log_interval, 0, min=0, unit='steps', &
            doc='steps between log lines; 0 = about 40 lines per run')
        call grp%get_string('analytic', run%analytic, 'none', &
            choices=[character(len=10) :: 'none', 'poiseuille', 'couette'], &
            doc='report the L2 velocity error against this analytic channel solution')
        call grp%get_real('wall_time_limit', run%wall_time_limit, 0.0_wp, min=0.0_wp, &
            unit='s', doc='checkpoint and stop (status 75) after this much wall time; 0 = none')
    end subroutine read_run_input

    !> Whether `text` ends with `tail`.
    pure logical function ends_with(text, tail)
        character(len=*), intent(in) :: text, tail
        ends_with = .false.
        if (len(text) >= len(tail)) ends_with = text(len(text) - len(tail) + 1:) == tail
    end function ends_with

    !> &output; the listed times must lie in [0, t_end] and increase. Entries past t_end (a
    !> shortened run) are skipped with a note (the group's), not refused. The output folder must
    !> be creatable: its nearest existing ancestor must be a directory (nothing is made here).
    !> max_steps: &run's; a run writes at most one snapshot a step. check_paths = .false.
    !> (default .true.) leaves the file system alone (config_parse).
    subroutine read_output_input(grp, t_end, max_steps, case_name, out, check_paths)
        type(nml_group_t), intent(inout) :: grp
        real(wp), intent(in) :: t_end
        integer, intent(in) :: max_steps
        character(len=*), intent(in) :: case_name   !< &run case_name (in the file names)
        type(output_input_t), intent(out) :: out
        logical, intent(in), optional :: check_paths
        logical :: ask
        integer :: k, n_kept
        character(len=:), allocatable :: problem
        character(len=32) :: t_text, n_text
        call grp%get_string('output_dir', out%output_dir, 'output', &
            doc='directory for snapshots (created if missing)')
        if (len_trim(out%output_dir) == 0) then
            call grp%error('output_dir', 'must not be empty')
        else
            ask = .true.
            if (present(check_paths)) ask = check_paths
            problem = ''
            if (ask) call check_creatable(trim(out%output_dir), problem)
            if (len(problem) > 0) call grp%error('output_dir', "'" // &
                trim(out%output_dir) // "' cannot be created: " // problem)
            ! the longest file in it: DIR/CASE_checkpoint_<up to 9 digits>.h5.tmp
            k = len_trim(out%output_dir) + len_trim(case_name) + len('/_checkpoint_.h5.tmp') + 9
            if (k > MAX_FILE_PATH) then
                write(n_text, '(i0)') k
                write(t_text, '(i0)') MAX_FILE_PATH
                call grp%error('output_dir', 'with &run case_name its checkpoints'' paths ' // &
                    'would be up to ' // trim(n_text) // ' characters long; HDF5 over MPI-IO ' // &
                    'takes at most ' // trim(t_text) // ' (a shorter folder, or a symbolic link)')
            end if
        end if
        call grp%get_real('output_interval', out%output_interval, 0.0_wp, min=0.0_wp, &
            unit='s', doc='simulated time between snapshots; 0 = first, last and listed only')
        if (out%output_interval > 0.0_wp) then
            ! (t_end <= 1e20 and an interval of at least 1e-30 s keep the count finite; a
            ! run stopped by max_steps writes at most one a step: t_end = 1e6 s with
            ! max_steps = 150 was refused as 5e6 snapshots, fz37)
            if (min(t_end / out%output_interval, real(max_steps, wp)) > &
                max_interval_snapshots) then
                write(t_text, '(es10.3)') t_end
                call grp%error('output_interval', 'asks for about ' // &
                    sci_text(t_end / out%output_interval) // ' snapshots up to t_end = ' // &
                    trim(adjustl(t_text)) // ' s; at most 100000 a run (a longer interval, ' // &
                    'or the times listed in output_times)')
            end if
        end if
        call grp%get_real_list('output_times', out%output_times, max_output_times, &
            min=0.0_wp, unit='s', doc='times at which a snapshot is written exactly')
        do k = 2, size(out%output_times)
            if (out%output_times(k) <= out%output_times(k - 1)) then
                call grp%error('output_times', 'must be strictly increasing')
                exit
            end if
        end do
        n_kept = count(out%output_times <= t_end)
        if (n_kept < size(out%output_times)) then
            write(t_text, '(es10.3)') t_end
            write(n_text, '(i0)') size(out%output_times) - n_kept
            call grp%note('output_times', trim(n_text) // &
                trim(merge(' entry  ', ' entries', size(out%output_times) - n_kept == 1)) // &
                ' past t_end = ' // trim(adjustl(t_text)) // ' s skipped')
            out%output_times = pack(out%output_times, out%output_times <= t_end)
        end if
    end subroutine read_output_input

    !> Why a folder cannot be made with mkdir -p ('' if it can): an existing path component
    !> that is not a directory. Nothing is created.
    subroutine check_creatable(path, problem)
        character(len=*), intent(in) :: path
        character(len=:), allocatable, intent(out) :: problem
        !> the longest name of one component (the file systems' NAME_MAX)
        integer, parameter :: NAME_MAX = 255
        integer :: k, start
        logical :: is_dir, exists
        problem = ''
        start = 1
        do k = 1, len(path) + 1
            if (k <= len(path)) then
                if (path(k:k) /= '/') cycle
            end if
            if (k - start > NAME_MAX) then
                problem = 'a name in it is longer than 255 characters'
                return
            end if
            start = k + 1
        end do
        do k = 2, len(path) + 1
            if (k <= len(path)) then
                if (path(k:k) /= '/') cycle
            end if
            inquire(file=path(1:k - 1) // '/.', exist=is_dir)
            if (is_dir) cycle
            inquire(file=path(1:k - 1), exist=exists)
            if (exists) problem = path(1:k - 1) // ' is not a directory'
            return
        end do
    end subroutine check_creatable
end module sph_run_input
