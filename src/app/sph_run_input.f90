!> The run's schedule as read from input: &run (end time, step limit, log cadence, analytic
!> reference) and &output (where and when snapshots are written). Read by sph_config; used by
!> the driver (sph_schedule, sph_stepper).
module sph_run_input
    use sph_kinds, only: wp
    use sph_namelist, only: nml_group_t
    implicit none
    private
    public :: run_input_t, output_input_t, read_run_input, read_output_input

    integer, parameter :: name_len = 32, path_len = 512, max_output_times = 256

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

    subroutine read_run_input(grp, run)
        type(nml_group_t), intent(inout) :: grp
        type(run_input_t), intent(out) :: run
        call grp%get_string('case_name', run%case_name, 'sphremesh', &
            doc='name used in output file names (letters, digits, _ - .)')
        if (len_trim(run%case_name) == 0 .or. verify(trim(run%case_name), &
            'abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789_-.') /= 0) &
            call grp%error('case_name', &
                'letters, digits, "_", "-" and "." only (used in file names)')
        call grp%get_real('t_end', run%t_end, 1.0_wp, min_exclusive=0.0_wp, unit='s', &
            doc='end time')
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

    !> &output; the listed times must lie in [0, t_end] and increase.
    subroutine read_output_input(grp, t_end, out)
        type(nml_group_t), intent(inout) :: grp
        real(wp), intent(in) :: t_end
        type(output_input_t), intent(out) :: out
        integer :: k
        call grp%get_string('output_dir', out%output_dir, 'output', &
            doc='directory for snapshots (created if missing)')
        if (len_trim(out%output_dir) == 0) call grp%error('output_dir', 'must not be empty')
        call grp%get_real('output_interval', out%output_interval, 0.0_wp, min=0.0_wp, &
            unit='s', doc='simulated time between snapshots; 0 = first, last and listed only')
        call grp%get_real_list('output_times', out%output_times, max_output_times, &
            min=0.0_wp, unit='s', doc='times at which a snapshot is written exactly')
        do k = 1, size(out%output_times)
            if (out%output_times(k) > t_end) then
                call grp%error('output_times', 'every entry must lie in [0, t_end]')
                exit
            end if
            if (k > 1) then
                if (out%output_times(k) <= out%output_times(k - 1)) then
                    call grp%error('output_times', 'must be strictly increasing')
                    exit
                end if
            end if
        end do
    end subroutine read_output_input
end module sph_run_input
