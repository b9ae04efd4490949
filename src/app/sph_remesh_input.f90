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
        !> remesh when the disorder measure (sph_disorder_measure) exceeds this; 0 = off
        real(wp) :: disorder_threshold = 0.0_wp
        integer :: disorder_check_steps = 100   !< steps between measurements of the disorder
    end type remesh_input_t

contains

    !> Read the &remesh group (mode; every_steps, every_time or a disorder threshold).
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
        call grp%get_real('disorder_threshold', rem%disorder_threshold, 0.0_wp, min=0.0_wp, &
            doc='same-level remesh when the coefficient of variation of the fluid ' // &
            "particles' nearest-neighbour distances exceeds this (a lattice: 0, a " // &
            'developed channel flow: about 0.005, particles gathered in pairs: 0.2); 0 = off')
        call grp%get_int('disorder_check_steps', rem%disorder_check_steps, 100, min=1, &
            unit='steps', doc='steps between two measurements of the disorder')
        if (trim(rem%mode) /= 'none' .and. rem%every_steps == 0 .and. &
            rem%every_time <= 0.0_wp .and. rem%disorder_threshold <= 0.0_wp) &
            call grp%error('mode', "'" // trim(rem%mode) // "' needs every_steps > 0, " // &
            'every_time > 0 or disorder_threshold > 0')
        if (rem%disorder_threshold > 0.0_wp .and. trim(rem%mode) /= 'same') &
            call grp%error('disorder_threshold', "works with mode = 'same' only (a " // &
            "disordered flow is remeshed at its own spacing), not with mode = '" // &
            trim(rem%mode) // "'")
        if (trim(rem%mode) == 'none') then
            call grp%note_if_given('every_steps', "a run remeshes only with mode /= 'none'")
            call grp%note_if_given('every_time', "a run remeshes only with mode /= 'none'")
        end if
        if (.not. (rem%disorder_threshold > 0.0_wp)) call grp%note_if_given( &
            'disorder_check_steps', 'it spaces the disorder measurements, which run ' // &
            'with disorder_threshold > 0 only')
    end subroutine read_remesh_input
end module sph_remesh_input
