!> Full-domain remeshing during a run as read from input (&remesh); used by sph_stepper with
!> sph_remesh_driver. Without the group (mode = 'none') a run never remeshes.
module sph_remesh_input
    use sph_kinds, only: wp
    use sph_namelist, only: nml_group_t
    implicit none
    private
    public :: remesh_input_t, read_remesh_input

    type :: remesh_input_t
        character(len=8) :: mode = 'none'   !< 'none', 'refine', 'coarsen', 'same'
        integer :: every_steps = 0          !< remesh every this many steps; 0 = off
        real(wp) :: every_time = 0.0_wp     !< remesh every this much simulated time; 0 = off
    end type remesh_input_t

contains

    !> Read the &remesh group (mode; every_steps or every_time).
    subroutine read_remesh_input(grp, rem)
        type(nml_group_t), intent(inout) :: grp
        type(remesh_input_t), intent(out) :: rem
        call grp%get_string('mode', rem%mode, 'none', &
            choices=[character(len=8) :: 'none', 'refine', 'coarsen', 'same'], &
            doc='full-domain remeshing: none, refine (dx/2), coarsen (2 dx), same (same dx)')
        call grp%get_int('every_steps', rem%every_steps, 0, min=0, unit='steps', &
            doc='remesh every this many steps; 0 = off')
        call grp%get_real('every_time', rem%every_time, 0.0_wp, min=0.0_wp, unit='s', &
            doc='remesh every this much simulated time; 0 = off')
        if (trim(rem%mode) /= 'none' .and. rem%every_steps == 0 .and. &
            rem%every_time <= 0.0_wp) call grp%error('mode', &
            "'" // trim(rem%mode) // "' needs every_steps > 0 or every_time > 0")
    end subroutine read_remesh_input
end module sph_remesh_input
