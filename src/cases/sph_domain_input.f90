!> The simulated box as read from input (&domain): dimension, extent, the boundary of each
!> face, wall velocities and the lattice spacing; and the checks that tie the case together
!> (the lattice fills the box; an analytic reference needs its channel). Read by sph_config;
!> used by the set-up (sph_initial, sph_walls, sph_physics, sph_simulation).
module sph_domain_input
    use sph_kinds, only: wp
    use sph_namelist, only: nml_group_t
    implicit none
    private
    public :: domain_input_t, read_domain_input, check_analytic_channel
    public :: n_faces, face_names

    integer, parameter :: n_faces = 6, name_len = 32
    !> Faces in input order: boundary(f), wall_velocity(:, f).
    character(len=4), parameter :: face_names(n_faces) = &
        ['xlo ', 'xhi ', 'ylo ', 'yhi ', 'zlo ', 'zhi ']

    type :: domain_input_t
        integer :: dimension
        real(wp) :: box_lo(3), box_hi(3)
        character(len=name_len) :: boundary(n_faces)
        real(wp) :: wall_velocity(3, n_faces)
        real(wp) :: dx
    contains
        procedure :: is_wall, is_periodic
    end type domain_input_t

contains

    logical pure function is_wall(self, face)
        class(domain_input_t), intent(in) :: self
        integer, intent(in) :: face
        is_wall = trim(self%boundary(face)) == 'wall'
    end function is_wall

    logical pure function is_periodic(self, axis)
        class(domain_input_t), intent(in) :: self
        integer, intent(in) :: axis
        is_periodic = trim(self%boundary(2*axis - 1)) == 'periodic'
    end function is_periodic

    subroutine read_domain_input(grp, dom)
        type(nml_group_t), intent(inout) :: grp
        type(domain_input_t), intent(out) :: dom
        integer :: axis
        real(wp) :: length, cells
        character(len=1) :: axis_text

        call grp%get_int('dimension', dom%dimension, 2, min=2, max=3, doc='2 or 3')
        call grp%get_real_array('box_lo', dom%box_lo, 0.0_wp, unit='m', &
            doc='lower corner of the fluid box')
        call grp%get_real_array('box_hi', dom%box_hi, 1.0_wp, unit='m', &
            doc='upper corner of the fluid box; each side a whole multiple of dx')
        call grp%get_string_array('boundary', dom%boundary, 'periodic', &
            choices=[character(len=8) :: 'periodic', 'wall'], &
            doc='per face xlo, xhi, ylo, yhi, zlo, zhi')
        call grp%get_real_matrix('wall_velocity', dom%wall_velocity, 0.0_wp, unit='m/s', &
            doc='velocity (3 components) of each face''s wall particles')
        call grp%get_real('dx', dom%dx, 0.05_wp, min_exclusive=0.0_wp, unit='m', &
            doc='particle spacing of the coarsest level')

        do axis = 1, min(max(dom%dimension, 2), 3)
            axis_text = achar(iachar('0') + axis)
            length = dom%box_hi(axis) - dom%box_lo(axis)
            if (.not. (length > 0.0_wp)) then
                call grp%error('box_hi(' // axis_text // ')', &
                    'must exceed box_lo on every axis in use')
                cycle
            end if
            if ((dom%boundary(2*axis - 1) == 'periodic') .neqv. &
                (dom%boundary(2*axis) == 'periodic')) &
                call grp%error('boundary(' // trim(face_names(2*axis - 1)) // ', ' // &
                    trim(face_names(2*axis)) // ')', &
                    'both faces of an axis are periodic or neither is')
            if (dom%dx > 0.0_wp) then
                cells = length / dom%dx
                if (abs(cells - nint(cells)) > 1.0e-6_wp * cells .or. nint(cells) < 1) &
                    call grp%error('dx', 'box length on axis ' // axis_text // &
                        ' must be a whole multiple of dx (the lattice must close ' // &
                        'periodically and sit symmetrically between walls)')
            end if
        end do
    end subroutine read_domain_input

    !> The analytic reference (&run analytic) only makes sense for the channel it describes;
    !> errors are reported against &run analytic in run_grp.
    subroutine check_analytic_channel(run_grp, analytic, dom, body_force)
        type(nml_group_t), intent(inout) :: run_grp
        character(len=*), intent(in) :: analytic
        type(domain_input_t), intent(in) :: dom
        real(wp), intent(in) :: body_force(3)
        if (analytic == 'none') return
        if (dom%boundary(1) /= 'periodic' .or. dom%boundary(3) /= 'wall' .or. &
            dom%boundary(4) /= 'wall') &
            call run_grp%error('analytic', "'" // trim(analytic) // &
                "' needs periodic x faces and walls at ylo and yhi")
        if (dom%dimension == 3 .and. dom%boundary(5) /= 'periodic') &
            call run_grp%error('analytic', 'in 3D the z faces must be periodic')
        if (any(dom%wall_velocity(:, 3) /= 0.0_wp)) &
            call run_grp%error('analytic', 'the analytic channel has a resting lower wall')
        if (analytic == 'poiseuille' .and. any(dom%wall_velocity(:, 4) /= 0.0_wp)) &
            call run_grp%error('analytic', "'poiseuille' needs a resting upper wall")
        if (analytic == 'couette' .and. any(dom%wall_velocity(2:3, 4) /= 0.0_wp)) &
            call run_grp%error('analytic', "'couette' needs the upper wall to move along x only")
        if (any(body_force(2:3) /= 0.0_wp)) &
            call run_grp%error('analytic', 'the analytic channel has a body force along x only')
    end subroutine check_analytic_channel
end module sph_domain_input
