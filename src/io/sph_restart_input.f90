!> Checkpointing as read from input (&restart); used by the driver with sph_checkpoint.
module sph_restart_input
    use sph_kinds, only: wp
    use sph_namelist, only: nml_group_t
    implicit none
    private
    public :: restart_input_t, read_restart_input

    type :: restart_input_t
        integer :: checkpoint_interval_steps     !< 0 = only at the end
        real(wp) :: checkpoint_interval_wall     !< s of wall time; 0 = off
        integer :: checkpoints_kept
    end type restart_input_t

contains

    !> Read the &restart group (checkpoint intervals in steps and wall seconds, how many kept).
    subroutine read_restart_input(grp, rst)
        type(nml_group_t), intent(inout) :: grp
        type(restart_input_t), intent(out) :: rst
        call grp%get_int('checkpoint_interval_steps', rst%checkpoint_interval_steps, 0, &
            min=0, unit='steps', doc='steps between checkpoints; 0 = only at the end')
        call grp%get_real('checkpoint_interval_wall', rst%checkpoint_interval_wall, 0.0_wp, &
            min=0.0_wp, unit='s', doc='wall-clock time between checkpoints; 0 = off')
        call grp%get_int('checkpoints_kept', rst%checkpoints_kept, 2, min=1, &
            doc='how many checkpoints are kept')
    end subroutine read_restart_input
end module sph_restart_input
