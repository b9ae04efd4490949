!> The simulated box as read from input (&domain): dimension, extent, the boundary of each
!> face, wall velocities and the lattice spacing; and the checks that tie the case together
!> (the lattice fills the box; an analytic reference needs its channel). Read by sph_config;
!> used by the set-up (sph_initial, sph_walls, sph_physics, sph_reference, sph_stepper).
module sph_domain_input
    use sph_kinds, only: wp
    use sph_namelist, only: nml_group_t, real_text
    implicit none
    private
    public :: domain_input_t, read_domain_input, check_analytic_channel
    public :: channel_t, find_analytic_channel
    public :: n_faces, face_names, misfit_axis, lattice_coordinate_text

    integer, parameter :: n_faces = 6, name_len = 32, path_len = 512
    !> Smallest dx as a fraction of a box length (10^9 particles along an axis).
    real(wp), parameter :: MIN_DX_FRACTION = 1.0e-9_wp
    !> Faces in input order: boundary(f), wall_velocity(:, f).
    character(len=4), parameter :: face_names(n_faces) = &
        ['xlo ', 'xhi ', 'ylo ', 'yhi ', 'zlo ', 'zhi ']

    type :: domain_input_t
        integer :: dimension
        real(wp) :: box_lo(3), box_hi(3)
        character(len=name_len) :: boundary(n_faces)
        real(wp) :: wall_velocity(3, n_faces)
        real(wp) :: dx
        character(len=path_len) :: initial_particles   !< '' = the lattice
    contains
        procedure :: is_wall, is_periodic, corner_velocity_jump
    end type domain_input_t

    !> The channel an analytic reference describes (find_analytic_channel).
    type :: channel_t
        integer :: normal_axis = 0   !< the axis whose two faces are walls
        integer :: flow_axis = 0     !< the axis the flow runs along
        integer :: moving_face = 0   !< the moving wall's face; 0 when both rest
    end type channel_t

contains

    logical pure function is_wall(self, face)
        class(domain_input_t), intent(in) :: self
        integer, intent(in) :: face
        is_wall = trim(self%boundary(face)) == 'wall'
    end function is_wall

    !> The largest velocity difference between two walls that meet at a corner (faces on
    !> different axes, as a lid and a side wall of a cavity); 0 without such a corner.
    pure real(wp) function corner_velocity_jump(self) result(jump)
        class(domain_input_t), intent(in) :: self
        integer :: f, g
        jump = 0.0_wp
        do f = 1, 2 * self%dimension
            do g = f + 1, 2 * self%dimension
                if ((f + 1) / 2 == (g + 1) / 2) cycle
                if (self%is_wall(f) .and. self%is_wall(g)) jump = max(jump, &
                    norm2(self%wall_velocity(:, f) - self%wall_velocity(:, g)))
            end do
        end do
    end function corner_velocity_jump

    logical pure function is_periodic(self, axis)
        class(domain_input_t), intent(in) :: self
        integer, intent(in) :: axis
        is_periodic = trim(self%boundary(2*axis - 1)) == 'periodic'
    end function is_periodic

    !> Read the &domain group (dimension, box, boundaries, dx) and check the box holds whole
    !> lattice cells and a kernel support.
    subroutine read_domain_input(grp, dom)
        type(nml_group_t), intent(inout) :: grp
        type(domain_input_t), intent(out) :: dom
        integer :: axis
        real(wp) :: length
        character(len=1) :: axis_text
        logical :: dx_refused
        integer :: errors_before

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
        errors_before = grp%n_errors
        call grp%get_real('dx', dom%dx, 0.05_wp, min_exclusive=0.0_wp, unit='m', &
            doc='particle spacing of the coarsest level')
        ! a dx refused above is not checked against the box (its default would be)
        dx_refused = grp%n_errors > errors_before
        call grp%get_string('initial_particles', dom%initial_particles, '', &
            doc='HDF5 file of initial particles (doc/output.md); empty = the lattice')

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
            ! a velocity given to a face without a wall moves nothing
            if (dom%boundary(2*axis - 1) == 'periodic') then
                if (any(dom%wall_velocity(:, 2*axis - 1:2*axis) /= 0.0_wp)) &
                    call grp%error('wall_velocity(:, ' // trim(face_names(2*axis - 1)) // &
                        ', ' // trim(face_names(2*axis)) // ')', 'given for periodic ' // &
                        'faces, which have no wall particles to move')
            end if
            if (dom%dx > 0.0_wp .and. dom%dx < MIN_DX_FRACTION * length) then
                ! (length / dx would overflow the whole-multiple test; no machine holds the
                ! lattice anyway) once, on the first such axis
                if (.not. dx_refused) call grp%error('dx', real_text(dom%dx) // &
                    ' m is below ' // real_text(MIN_DX_FRACTION) // ' of the box length on ' // &
                    'axis ' // axis_text // ' (' // real_text(length) // ' m): more than ' // &
                    '10^9 particles along it')
                dx_refused = .true.
            else if (dom%dx > 0.0_wp .and. .not. dx_refused) then
                if (.not. spacing_fits_axis(dom, dom%dx, axis)) &
                    call grp%error('dx', 'box length on axis ' // axis_text // &
                        ' must be a whole multiple of dx (the lattice must close ' // &
                        'periodically and sit symmetrically between walls): ' // &
                        misfit_text(dom, axis))
            end if
        end do
        call check_wall_velocities(grp, dom)
    end subroutine read_domain_input

    !> The walls keep their place: a wall's particles may move only along its face (a
    !> velocity across it drove the fluid of a closed channel through both plates at the
    !> plate's speed, without a word). In 2D the third components and the z faces are not
    !> there: a velocity given to them moved nothing.
    subroutine check_wall_velocities(grp, dom)
        type(nml_group_t), intent(inout) :: grp
        type(domain_input_t), intent(in) :: dom
        integer :: face, axis, dim
        character(len=:), allocatable :: key
        dim = min(max(dom%dimension, 2), 3)
        do face = 1, n_faces
            do axis = 1, 3
                if (.not. abs(dom%wall_velocity(axis, face)) > 0.0_wp) cycle
                key = 'wall_velocity(' // achar(iachar('0') + axis) // ',' // &
                    achar(iachar('0') + face) // ')'
                if (face > 2 * dim) then
                    call grp%error(key, 'must be 0: a 2D run (dimension = 2) has no face ' // &
                        trim(face_names(face)))
                    exit
                end if
                ! (a periodic face's velocity is refused above)
                if (dom%is_periodic((face + 1) / 2)) exit
                if (axis > dim) then
                    call grp%error(key, 'must be 0: a 2D run (dimension = 2) has no ' // &
                        'third velocity component')
                else if (axis == (face + 1) / 2) then
                    call grp%error(key, 'must be 0: the wall of face ' // &
                        trim(face_names(face)) // ' keeps its place, so it may move only ' // &
                        'along itself (a velocity across it would push the fluid through it)')
                end if
            end do
        end do
    end subroutine check_wall_velocities

    !> Whether the box length on `axis` is a whole multiple of the spacing dx: a lattice of
    !> that spacing must close periodically and sit symmetrically between walls (the set-up's
    !> lattice, a remesh's new spacing).
    !> The left-over may be round-off only: at most 1e-6 of a spacing per spacing, and never
    !> more than 1e-3 of one (a tolerance of 1e-6 of the count let a box 200000.15 spacings
    !> long through, whose lattice left a gap of 1.15 dx at its periodic seam, fz32). The
    !> round-off of the input itself stays far below (about 1e-7 dx a box 10^9 spacings from
    !> the origin).
    pure logical function spacing_fits_axis(dom, dx, axis) result(fits)
        type(domain_input_t), intent(in) :: dom
        real(wp), intent(in) :: dx
        integer, intent(in) :: axis
        real(wp) :: cells
        cells = (dom%box_hi(axis) - dom%box_lo(axis)) / dx
        fits = abs(cells - nint(cells)) <= 1.0e-6_wp * min(max(cells, 1.0_wp), 1.0e3_wp) &
            .and. nint(cells) >= 1
    end function spacing_fits_axis

    !> What a box length that is no whole multiple of dx is, and the box_hi values that fit;
    !> for a box so far from the origin that its positions cannot resolve the spacing, that.
    function misfit_text(dom, axis) result(text)
        type(domain_input_t), intent(in) :: dom
        integer, intent(in) :: axis
        character(len=:), allocatable :: text
        character(len=24) :: ratio, grain
        character(len=1) :: a
        real(wp) :: cells, resolution, below, above
        a = achar(iachar('0') + axis)
        cells = (dom%box_hi(axis) - dom%box_lo(axis)) / dom%dx
        write(ratio, '(f0.6)') cells
        below = dom%box_lo(axis) + dom%dx * real(max(floor(cells), 1), wp)
        above = dom%box_lo(axis) + dom%dx * real(max(ceiling(cells), 2), wp)
        ! (each with the digits of the other too: the two read alike)
        text = 'it holds ' // trim(adjustl(ratio)) // ' spacings; box_hi(' // a // ') = ' // &
            lattice_coordinate_text(below, above, dom%dx) // ' or ' // &
            lattice_coordinate_text(above, below, dom%dx) // ' m fits'
        ! a position there is known to one unit in the last place of the box's coordinates
        resolution = spacing(max(abs(dom%box_lo(axis)), abs(dom%box_hi(axis)))) / dom%dx
        if (resolution > 1.0e-4_wp) then
            write(grain, '(es9.2)') resolution
            text = text // ' (the box lies so far from the origin that a position there is ' // &
                'known to ' // trim(adjustl(grain)) // ' dx only: move it nearer to 0)'
        end if
    end function misfit_text

    !> A coordinate x of a lattice of spacing dx, with as many digits as tell its planes apart
    !> at x and at the coordinate `near` (a box far from the origin: 1.00030000E+00, not
    !> 1.000E+00).
    function lattice_coordinate_text(x, near, dx) result(text)
        real(wp), intent(in) :: x, near, dx
        character(len=:), allocatable :: text
        character(len=32) :: buffer
        character(len=16) :: form
        integer :: digits
        digits = min(15, max(4, 3 + ceiling(log10(max(abs(near), abs(x), dx) / dx))))
        write(form, '(a,i0,a,i0,a)') '(es', digits + 8, '.', digits, ')'
        write(buffer, form) x
        text = trim(adjustl(buffer))
    end function lattice_coordinate_text

    !> The first axis in use whose box length is not a whole multiple of dx; 0 when none.
    pure integer function misfit_axis(dom, dx) result(axis)
        type(domain_input_t), intent(in) :: dom
        real(wp), intent(in) :: dx
        integer :: a
        axis = 0
        do a = 1, min(max(dom%dimension, 2), 3)
            if (spacing_fits_axis(dom, dx, a)) cycle
            axis = a
            return
        end do
    end function misfit_axis

    !> The analytic reference (&run analytic) only makes sense for the channel it describes
    !> (find_analytic_channel); errors are reported against &run analytic in run_grp.
    subroutine check_analytic_channel(run_grp, analytic, dom, body_force)
        type(nml_group_t), intent(inout) :: run_grp
        character(len=*), intent(in) :: analytic
        type(domain_input_t), intent(in) :: dom
        real(wp), intent(in) :: body_force(3)
        type(channel_t) :: channel
        character(len=:), allocatable :: errmsg
        if (analytic == 'none') return
        call find_analytic_channel(analytic, dom, body_force, channel, errmsg)
        if (len(errmsg) > 0) call run_grp%error('analytic', errmsg)
    end subroutine check_analytic_channel

    !> The channel of an analytic reference: walls on both faces of one axis (the wall
    !> normal), every other axis in use periodic, one resting wall, and the flow along one
    !> other axis: the body force's ('poiseuille', both walls resting) or the moving wall's
    !> ('couette'). errmsg is empty when the case is such a channel. The input check
    !> (check_analytic_channel) and the reference (sph_reference) both use this one rule.
    subroutine find_analytic_channel(analytic, dom, body_force, channel, errmsg)
        character(len=*), intent(in) :: analytic
        type(domain_input_t), intent(in) :: dom
        real(wp), intent(in) :: body_force(3)
        type(channel_t), intent(out) :: channel
        character(len=:), allocatable, intent(out) :: errmsg
        integer :: axis, n_walled, dim, side, face
        real(wp) :: drive(3)
        character(len=:), allocatable :: name

        errmsg = ''
        name = "'" // trim(analytic) // "'"
        dim = min(max(dom%dimension, 2), 3)
        n_walled = 0
        do axis = 1, dim
            if (dom%is_wall(2*axis - 1) .and. dom%is_wall(2*axis)) then
                n_walled = n_walled + 1
                channel%normal_axis = axis
            else if (.not. dom%is_periodic(axis)) then
                n_walled = n_walled + 2   ! a single wall face: not a channel
            end if
        end do
        if (n_walled /= 1) then
            errmsg = name // ' needs walls on both faces of one axis and periodic faces ' // &
                'on the others'
            return
        end if
        ! the moving wall, if any: at most one of the two
        channel%moving_face = 0
        do side = 1, 2
            face = 2*channel%normal_axis - 2 + side
            if (any(dom%wall_velocity(:, face) /= 0.0_wp)) then
                if (channel%moving_face /= 0) then
                    errmsg = name // ' needs one resting wall'
                    return
                end if
                channel%moving_face = face
            end if
        end do
        drive = body_force
        if (trim(analytic) == 'couette') then
            if (channel%moving_face /= 0) drive = dom%wall_velocity(:, channel%moving_face)
        else if (channel%moving_face /= 0) then
            errmsg = name // ' needs both walls at rest'
            return
        end if
        ! a reference of a fluid at rest is 0, and its 'relative' error was the velocities'
        ! norm in m/s, printed as a percentage
        if (all(drive == 0.0_wp)) then
            if (trim(analytic) == 'couette') then
                errmsg = name // ' needs a moving wall (&domain wall_velocity) or a body ' // &
                    'force along the flow (&fluid body_force); with neither the fluid stays ' // &
                    "at rest (or analytic = 'none')"
            else
                errmsg = name // ' needs a body force along the flow (&fluid body_force); ' // &
                    "without one the fluid stays at rest (or analytic = 'none')"
            end if
            return
        end if
        ! the flow axis: the one axis the drive points along, or the first other axis
        channel%flow_axis = 0
        do axis = 1, 3
            if (drive(axis) /= 0.0_wp) then
                if (channel%flow_axis /= 0) then
                    errmsg = name // ' needs the ' // trim(driver_name(analytic)) // &
                        ' along one axis'
                    return
                end if
                channel%flow_axis = axis
            end if
        end do
        if (channel%flow_axis == 0) channel%flow_axis = merge(2, 1, channel%normal_axis == 1)
        if (channel%flow_axis == channel%normal_axis .or. channel%flow_axis > dim) then
            errmsg = name // ' needs the ' // trim(driver_name(analytic)) // &
                ' along a periodic axis'
            return
        end if
        ! any body force must push along the flow (it drives the Poiseuille profile)
        do axis = 1, 3
            if (axis /= channel%flow_axis .and. body_force(axis) /= 0.0_wp) then
                errmsg = name // ' needs the body force along the flow only'
                return
            end if
        end do
    end subroutine find_analytic_channel

    pure function driver_name(analytic) result(name)
        character(len=*), intent(in) :: analytic
        character(len=:), allocatable :: name
        name = merge('moving wall''s velocity', 'body force            ', &
            trim(analytic) == 'couette')
    end function driver_name
end module sph_domain_input
