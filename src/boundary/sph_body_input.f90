!> Solid bodies inside the box as read from input: one &body group per body (the group may be
!> repeated; bodies are numbered in file order). Each body is a circle (2D), sphere (3D),
!> cylinder along a coordinate axis (3D), or an axis-aligned rectangle (2D) or box (3D),
!> translating at a constant velocity. Read by sph_config; turned into solids by sph_walls.
module sph_body_input
    use sph_kinds, only: wp
    use sph_namelist, only: nml_group_t, real_text
    use sph_domain_input, only: domain_input_t
    implicit none
    private
    public :: body_input_t, read_body_inputs, check_body_wall_model, body_shape_names

    integer, parameter :: name_len = 32
    character(len=9), parameter :: body_shape_names(5) = [character(len=9) :: &
        'circle', 'sphere', 'cylinder', 'rectangle', 'box']

    type :: body_input_t
        character(len=name_len) :: shape = 'circle'
        character(len=name_len) :: name = ''
        real(wp) :: centre(3) = 0.0_wp
        real(wp) :: radius = 0.0_wp
        character(len=1) :: axis = 'z'
        real(wp) :: lo(3) = 0.0_wp, hi(3) = 0.0_wp
        real(wp) :: velocity(3) = 0.0_wp
    end type body_input_t

contains

    !> Read every &body instance (grps, in file order) and check it against the box. Errors
    !> are recorded in the instance's group, which names the instance (`&body 2 radius: ...`).
    subroutine read_body_inputs(grps, dom, bodies)
        type(nml_group_t), intent(inout) :: grps(:)
        type(domain_input_t), intent(in) :: dom
        type(body_input_t), allocatable, intent(out) :: bodies(:)
        integer :: b
        allocate(bodies(size(grps)))
        do b = 1, size(grps)
            grps(b)%instance = b
            call read_body(grps(b), dom, bodies(b))
            ! forces, logs and &region body name a body: one name, one body
            if (b > 1) then
                if (any(bodies(1:b - 1)%name == bodies(b)%name)) call grps(b)%error('name', &
                    "'" // trim(bodies(b)%name) // "' names an earlier &body too")
            end if
        end do
    end subroutine read_body_inputs

    subroutine read_body(grp, dom, body)
        type(nml_group_t), intent(inout) :: grp
        type(domain_input_t), intent(in) :: dom
        type(body_input_t), intent(out) :: body
        integer :: dim, a
        logical :: round
        real(wp) :: lo(3), hi(3), length
        character(len=1) :: axis_text

        call grp%get_string('shape', body%shape, 'circle', choices=body_shape_names, &
            doc='circle, rectangle (2D); sphere, cylinder, box (3D)')
        call grp%get_string('name', body%name, '', doc='name in logs (default: body N)')
        call grp%get_real_array('centre', body%centre, 0.0_wp, unit='m', &
            doc='centre of a circle, sphere or cylinder')
        call grp%get_real('radius', body%radius, 0.0_wp, unit='m', &
            doc='radius of a circle, sphere or cylinder; > 0')
        call grp%get_string('axis', body%axis, 'z', choices=[character(len=1) :: 'x', 'y', 'z'], &
            doc='the axis a cylinder runs along (a periodic axis)')
        call grp%get_real_array('lo', body%lo, 0.0_wp, unit='m', &
            doc='lower corner of a rectangle or box')
        call grp%get_real_array('hi', body%hi, 0.0_wp, unit='m', &
            doc='upper corner of a rectangle or box')
        call grp%get_real_array('velocity', body%velocity, 0.0_wp, unit='m/s', &
            doc='velocity of the body''s wall particles (they keep their place): 0, ' // &
            'or along a cylinder''s axis')
        if (len_trim(body%name) == 0) body%name = 'body ' // itoa(grp%instance)
        ! the name is a column of the forces CSV and a line's label in the log (fz44: a comma
        ! shifted every column after it; 'wall ylo' gave two rows no reader could tell apart)
        if (scan(body%name, ',"' // achar(9) // achar(13) // achar(10)) > 0) &
            call grp%error('name', "'" // trim(body%name) // "' holds a comma, a double " // &
            "quote or a control character: the forces file (CSV) names the body with it")
        if (any(trim(body%name) == ['wall xlo', 'wall xhi', 'wall ylo', 'wall yhi', &
                'wall zlo', 'wall zhi'])) call grp%error('name', "'" // trim(body%name) // &
            "' is the name of a box wall in the logs and the forces file: choose another")

        dim = min(max(dom%dimension, 2), 3)
        select case (trim(body%shape))
        case ('circle', 'rectangle')
            if (dim /= 2) call grp%error('shape', "'" // trim(body%shape) // &
                "' is a 2D shape; in 3D use 'sphere', 'cylinder' or 'box'")
        case ('sphere', 'cylinder', 'box')
            if (dim /= 3) call grp%error('shape', "'" // trim(body%shape) // &
                "' is a 3D shape; in 2D use 'circle' or 'rectangle'")
        case default
            return   ! already reported
        end select
        round = any(trim(body%shape) == [character(len=9) :: 'circle', 'sphere', 'cylinder'])
        ! keys of other shapes are read but mean nothing here (fz44: a rectangle's radius of
        ! 5 m passed without a word)
        if (round) then
            call grp%note_if_given('lo', 'a ' // trim(body%shape) // ' is given by centre ' // &
                'and radius')
            call grp%note_if_given('hi', 'a ' // trim(body%shape) // ' is given by centre ' // &
                'and radius')
        else
            call grp%note_if_given('centre', 'a ' // trim(body%shape) // ' is given by lo ' // &
                'and hi')
            call grp%note_if_given('radius', 'a ' // trim(body%shape) // ' is given by lo ' // &
                'and hi')
        end if
        if (trim(body%shape) /= 'cylinder') call grp%note_if_given('axis', 'only a ' // &
            'cylinder has an axis')
        if (round) then
            if (.not. (body%radius > 0.0_wp)) then
                call grp%error('radius', 'must be > 0 (m) for a ' // trim(body%shape))
                return
            end if
            ! smaller, no lattice site falls inside: a body with no particles and no force
            if (body%radius < 0.5_wp * dom%dx) then
                call grp%error('radius', real_text(body%radius) // ' m is below half the ' // &
                    'spacing (&domain dx = ' // real_text(dom%dx) // ' m): the ' // &
                    trim(body%shape) // ' would hold no particle')
                return
            end if
            lo = body%centre - body%radius
            hi = body%centre + body%radius
        else
            lo = body%lo
            hi = body%hi
            do a = 1, dim
                if (.not. (body%lo(a) < body%hi(a))) then
                    call grp%error('lo(' // itoa(a) // ')', 'must be < hi(' // itoa(a) // &
                        ') (the corners of a ' // trim(body%shape) // ')')
                    return
                end if
            end do
        end if
        ! the body keeps its place: its wall particles may move only along its surface. No
        ! body but a cylinder (along its axis) has a direction all of its surface shares (a
        ! body is narrower than the box on every other axis): any other velocity would push
        ! fluid through the surface, which nothing supplies (a circle moving across the flow
        ! at 1e-4 m/s: densities 805..1416 kg/m^3 within 0.3 s under Verlet)
        do a = 1, dim
            if (trim(body%shape) == 'cylinder') then
                if (achar(iachar('x') + a - 1) == body%axis) cycle
            end if
            if (abs(body%velocity(a)) > 0.0_wp) then
                if (trim(body%shape) == 'cylinder') then
                    call grp%error('velocity(' // itoa(a) // ')', 'must be 0: the body ' // &
                        'keeps its place and its surface may move only along itself, so a ' // &
                        'cylinder may slide along its axis (' // body%axis // ') only')
                else if (dim == 3) then
                    call grp%error('velocity(' // itoa(a) // ')', 'must be 0: the body ' // &
                        'keeps its place and its surface may move only along itself; no ' // &
                        'direction runs along all of a ' // trim(body%shape) // &
                        "'s surface (a cylinder may slide along its axis)")
                else
                    call grp%error('velocity(' // itoa(a) // ')', 'must be 0: the body ' // &
                        'keeps its place and its surface may move only along itself; no ' // &
                        'direction runs along all of a ' // trim(body%shape) // "'s surface")
                end if
                exit   ! (one velocity message; the body's other checks go on)
            end if
        end do
        ! (a 2D flow has no third component: given, it moved nothing)
        if (dim == 2 .and. abs(body%velocity(3)) > 0.0_wp .and. .not. &
            any(abs(body%velocity(1:2)) > 0.0_wp)) call grp%error('velocity(3)', &
            'must be 0: a 2D run (&domain dimension = 2) has no third velocity component')
        ! the body in the box: across periodic faces only, never into a wall, never wider
        ! than its own periodic image's distance
        do a = 1, dim
            axis_text = achar(iachar('x') + a - 1)
            if (trim(body%shape) == 'cylinder') then
                if (axis_text == body%axis) then
                    if (.not. dom%is_periodic(a)) call grp%error('axis', &
                        'a cylinder runs the whole box along its axis, which must be ' // &
                        'periodic (&domain boundary)')
                    cycle
                end if
            end if
            length = dom%box_hi(a) - dom%box_lo(a)
            if (dom%is_periodic(a)) then
                if (.not. (hi(a) - lo(a) < length)) call grp%error(extent_key(a), &
                    'the body must be narrower than the periodic box along ' // axis_text)
                if (.not. (body_mid(a) >= dom%box_lo(a) .and. body_mid(a) < dom%box_hi(a))) &
                    then
                    ! (the numbers: a box body's centre is the middle of its lo and hi)
                    call grp%error(extent_key(a), 'the body''s centre must lie in the box ' // &
                        'along ' // axis_text // ' (at ' // real_text(body_mid(a)) // &
                        ' m; the box takes [' // real_text(dom%box_lo(a)) // ', ' // &
                        real_text(dom%box_hi(a)) // ') m, box_hi excluded: a body may ' // &
                        'cross a periodic face, its centre on the lower side)')
                end if
            else if (.not. (lo(a) > dom%box_lo(a) .and. hi(a) < dom%box_hi(a))) then
                call grp%error(extent_key(a), 'the body must lie inside the box along ' // &
                    axis_text // ' and not touch its walls (it may cross periodic faces only)')
            end if
        end do

    contains

        pure real(wp) function body_mid(ax)
            integer, intent(in) :: ax
            body_mid = 0.5_wp * (lo(ax) + hi(ax))
        end function body_mid

        function extent_key(ax) result(key)
            integer, intent(in) :: ax
            character(len=:), allocatable :: key
            if (round) then
                key = 'centre(' // itoa(ax) // '), radius'
            else
                key = 'lo(' // itoa(ax) // '), hi(' // itoa(ax) // ')'
            end if
        end function extent_key
    end subroutine read_body

    !> Mirror images (&numerics wall_model 'mirror', 'repulsive_mirror') are exact only across
    !> the box's plane walls: every body is refused with them, reported against its &body
    !> shape (below). Repulsive walls alone (free slip) cannot move fluid: a body's velocity
    !> is refused with them.
    subroutine check_body_wall_model(grps, bodies, wall_model)
        type(nml_group_t), intent(inout) :: grps(:)
        type(body_input_t), intent(in) :: bodies(:)
        character(len=*), intent(in) :: wall_model
        integer :: b
        ! repulsive walls push along the surface's normal only (free slip): a moving body's
        ! wall particles would drag no fluid
        if (trim(wall_model) == 'repulsive') then
            do b = 1, size(bodies)
                if (any(abs(bodies(b)%velocity) > 0.0_wp)) call grps(b)%error('velocity', &
                    "must be 0 with &numerics wall_model = 'repulsive': repulsive walls " // &
                    'push along their normal only (free slip) and drag no fluid; use ' // &
                    "'morris' for a moving body")
            end do
        end if
        ! Mirror images are exact across a plane only: the box's walls. Across a curved
        ! surface they are not; around a rectangle or box the images of two faces overlap near
        ! their edge (a fluid particle there is mirrored across both, and through the corner:
        ! densities 47 % high at a 2D corner, 83 % at a 3D box's edge with summation density,
        ! where the run stopped at its first step), the images through a corner reach up to
        ! three supports from their sources, and the result depended on the rank count (2
        ! ranks 6e-2 of the peak speed from 1 after two steps: fz33, fz35). So no body is
        ! accepted with mirror walls.
        if (index(wall_model, 'mirror') == 0) return
        do b = 1, size(bodies)
            call grps(b)%error('shape', "a body ('" // trim(bodies(b)%shape) // &
                "') cannot be used with &numerics wall_model = '" // trim(wall_model) // &
                "': mirror images are exact across the box's plane walls only (across a " // &
                "body's surface, edges and corners they overlap or miss); use 'morris' " // &
                "or 'repulsive'")
        end do
    end subroutine check_body_wall_model

    pure function itoa(i) result(text)
        integer, intent(in) :: i
        character(len=:), allocatable :: text
        character(len=16) :: buf
        write(buf, '(i0)') i
        text = trim(buf)
    end function itoa
end module sph_body_input
