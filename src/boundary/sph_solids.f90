!> Solids are the regions of space that are not fluid, each able to say at any point its signed
!> distance (positive in the fluid, negative inside the solid), the unit normal of its surface
!> pointing into the fluid, and its velocity. Wall particles, mirror images and Morris' wall
!> normals and distances are all made from these answers, so a new shape (a circle, a sphere,
!> particles from a file) is a new case here, not a change to the wall models.
!>
!> Shapes: the half-spaces behind the box faces that are walls (SOLID_PLANE), and bodies inside
!> the box (&body): circles (2D), spheres, cylinders along a coordinate axis (3D), axis-aligned
!> rectangles (2D) and boxes (3D). Distances are exact (Euclidean outside the corners of a
!> rectangle or box, the nearest face's inside); a body's distance takes the nearest periodic
!> image of its centre along the periodic axes (period /= 0), so a body may cross a periodic
!> face. Solids are numbered 1..n in the order given; particles carry the number of the solid
!> they belong to (0 for fluid).
module sph_solids
    use sph_kinds, only: wp
    implicit none
    private
    public :: solid_t, solids_t, solids_add_plane, solid_distance, solid_normal
    public :: solid_velocity, solid_reflect, deepest_solid, solids_add_body, facing_plane
    public :: corner_planes, MAX_CORNER_COMBOS, next_image_distance, solid_mirrors
    public :: SOLID_PLANE, SOLID_CIRCLE, SOLID_SPHERE, SOLID_CYLINDER, SOLID_RECTANGLE
    public :: SOLID_BOX

    integer, parameter :: SOLID_PLANE = 1   !< the half-space behind a plane (a wall face)
    !> corner_planes' room: the box's six faces give at most 12 pairs and 8 triples at right
    !> angles
    integer, parameter :: MAX_CORNER_COMBOS = 20
    integer, parameter :: SOLID_CIRCLE = 2  !< a disc (2D): centre, radius
    integer, parameter :: SOLID_SPHERE = 3  !< a ball (3D): centre, radius
    integer, parameter :: SOLID_CYLINDER = 4    !< (3D) centre, radius, axis; infinitely long
    integer, parameter :: SOLID_RECTANGLE = 5   !< (2D) axis-aligned: lo, hi corners
    integer, parameter :: SOLID_BOX = 6         !< (3D) axis-aligned: lo, hi corners

    type :: solid_t
        integer :: shape = SOLID_PLANE
        character(len=32) :: name = ''      !< for logs and force reports ('wall ylo')
        real(wp) :: point(3) = 0.0_wp       !< a point of the surface
        real(wp) :: normal(3) = 0.0_wp      !< plane: unit normal into the fluid
        real(wp) :: velocity(3) = 0.0_wp    !< rigid translation (a sliding wall, a lid)
        integer :: face = 0                 !< the box face it stands for, 0 for a body
        real(wp) :: centre(3) = 0.0_wp      !< bodies: centre (rectangle, box: of lo..hi)
        real(wp) :: radius = 0.0_wp         !< circle, sphere, cylinder
        real(wp) :: half(3) = 0.0_wp        !< rectangle, box: half side lengths
        integer :: axis = 3                 !< cylinder: the axis it runs along (circle: 3)
        real(wp) :: period(3) = 0.0_wp      !< box length along periodic axes, 0 otherwise
    end type solid_t

    type :: solids_t
        integer :: dim = 2
        real(wp) :: period(3) = 0.0_wp      !< box length along periodic axes, 0 otherwise
        type(solid_t), allocatable :: list(:)
    end type solids_t

contains

    !> Append the half-space behind the plane through `point` with unit normal `normal`
    !> pointing into the fluid.
    subroutine solids_add_plane(solids, name, point, normal, velocity, face)
        type(solids_t), intent(inout) :: solids
        character(len=*), intent(in) :: name
        real(wp), intent(in) :: point(3), normal(3), velocity(3)
        integer, intent(in), optional :: face
        type(solid_t) :: s
        if (.not. allocated(solids%list)) allocate(solids%list(0))
        s%shape = SOLID_PLANE
        s%name = name
        s%point = point
        s%normal = normal
        s%velocity = velocity
        if (present(face)) s%face = face
        solids%list = [solids%list, s]
    end subroutine solids_add_plane

    !> Append a body. shape: SOLID_CIRCLE, SOLID_SPHERE, SOLID_CYLINDER (centre, radius,
    !> axis), SOLID_RECTANGLE, SOLID_BOX (lo, hi); it moves with `velocity` (rigid
    !> translation) and sees the periodic lengths of `solids%period`.
    subroutine solids_add_body(solids, name, shape, velocity, centre, radius, axis, lo, hi)
        type(solids_t), intent(inout) :: solids
        character(len=*), intent(in) :: name
        integer, intent(in) :: shape
        real(wp), intent(in) :: velocity(3)
        real(wp), intent(in), optional :: centre(3), radius, lo(3), hi(3)
        integer, intent(in), optional :: axis
        type(solid_t) :: s
        if (.not. allocated(solids%list)) allocate(solids%list(0))
        s%shape = shape
        s%name = name
        s%velocity = velocity
        s%period = solids%period
        select case (shape)
        case (SOLID_RECTANGLE, SOLID_BOX)
            s%centre = 0.5_wp * (lo + hi)
            s%half = 0.5_wp * (hi - lo)
            if (shape == SOLID_RECTANGLE) then
                s%centre(3) = 0.0_wp
                s%half(3) = huge(1.0_wp)    ! a rectangle is a box without a z extent
            end if
        case default
            s%centre = centre
            s%radius = radius
            s%axis = 3
            if (shape == SOLID_CYLINDER) s%axis = axis
        end select
        s%point = s%centre
        solids%list = [solids%list, s]
    end subroutine solids_add_body

    !> x - centre of the body's nearest periodic image (each periodic axis on its own: the
    !> distance of every shape here grows with |offset| along each axis separately).
    pure function body_offset(solid, x) result(r)
        type(solid_t), intent(in) :: solid
        real(wp), intent(in) :: x(3)
        real(wp) :: r(3)
        integer :: a
        r = x - solid%centre
        do a = 1, 3
            if (solid%period(a) > 0.0_wp) r(a) = r(a) - solid%period(a) * anint(r(a) / &
                solid%period(a))
        end do
        select case (solid%shape)
        case (SOLID_CIRCLE, SOLID_RECTANGLE)
            r(3) = 0.0_wp
        case (SOLID_CYLINDER)
            r(solid%axis) = 0.0_wp
        end select
    end function body_offset

    !> Signed distance of x from the surface: > 0 in the fluid, < 0 inside the solid.
    pure real(wp) function solid_distance(solid, x)
        type(solid_t), intent(in) :: solid
        real(wp), intent(in) :: x(3)
        select case (solid%shape)
        case (SOLID_PLANE)
            solid_distance = dot_product(solid%normal, x - solid%point)
        case default
            solid_distance = offset_distance(solid, body_offset(solid, x))
        end select
    end function solid_distance

    !> A body's signed distance from a point at offset r from its centre (body_offset).
    pure real(wp) function offset_distance(solid, r) result(d)
        type(solid_t), intent(in) :: solid
        real(wp), intent(in) :: r(3)
        real(wp) :: q(3)
        select case (solid%shape)
        case (SOLID_RECTANGLE, SOLID_BOX)
            q = abs(r) - solid%half
            if (any(q > 0.0_wp)) then
                d = norm2(max(q, 0.0_wp))
            else
                d = maxval(q)
            end if
        case default   ! circle, sphere, cylinder
            d = norm2(r) - solid%radius
        end select
    end function offset_distance

    !> Distance of x from the body's next periodic images: along each periodic axis the
    !> image beyond x, on the other side from the nearest one (huge for a plane or a body
    !> with no periodic axis).
    !> Between a body and its own image the half-way point is where the two are equally far,
    !> as between two bodies (the refinement's band map, sph_refine).
    pure real(wp) function next_image_distance(solid, x) result(d)
        type(solid_t), intent(in) :: solid
        real(wp), intent(in) :: x(3)
        real(wp) :: r(3), ri(3)
        integer :: a
        d = huge(1.0_wp)
        if (solid%shape == SOLID_PLANE) return
        r = body_offset(solid, x)
        do a = 1, 3
            if (.not. solid%period(a) > 0.0_wp) cycle
            ! (along a cylinder's axis, or the third of a 2D body, it has no next image)
            select case (solid%shape)
            case (SOLID_CIRCLE, SOLID_RECTANGLE)
                if (a == 3) cycle
            case (SOLID_CYLINDER)
                if (a == solid%axis) cycle
            end select
            ri = r
            ri(a) = r(a) - sign(solid%period(a), r(a))
            d = min(d, offset_distance(solid, ri))
        end do
    end function next_image_distance

    !> Unit normal into the fluid at the surface point nearest x (curved shapes use x). At a
    !> body's centre, where every direction is nearest, the first axis it spans is taken.
    pure function solid_normal(solid, x) result(normal)
        type(solid_t), intent(in) :: solid
        real(wp), intent(in) :: x(3)
        real(wp) :: normal(3)
        real(wp) :: r(3), q(3), length
        integer :: a
        select case (solid%shape)
        case (SOLID_CIRCLE, SOLID_SPHERE, SOLID_CYLINDER)
            r = body_offset(solid, x)
            length = norm2(r)
            if (length > 0.0_wp) then
                normal = r / length
            else
                normal = 0.0_wp
                normal(merge(2, 1, solid%axis == 1 .and. solid%shape == SOLID_CYLINDER)) = &
                    1.0_wp
            end if
        case (SOLID_RECTANGLE, SOLID_BOX)
            r = body_offset(solid, x)
            q = abs(r) - solid%half
            normal = 0.0_wp
            if (any(q > 0.0_wp)) then
                ! outside: from the nearest point of the surface (a face, edge or corner)
                normal = sign(1.0_wp, r) * max(q, 0.0_wp)
                normal = normal / norm2(normal)
            else
                ! inside: the nearest face's
                a = maxloc(q, dim=1)
                normal(a) = sign(1.0_wp, r(a))
            end if
        case default
            normal = solid%normal
        end select
    end function solid_normal

    !> Velocity of the solid at x (a rotating body will use x).
    pure function solid_velocity(solid, x) result(velocity)
        type(solid_t), intent(in) :: solid
        real(wp), intent(in) :: x(3)
        real(wp) :: velocity(3)
        velocity = solid%velocity
    end function solid_velocity

    !> Mirror image of x across the surface (x - 2 d n). For a plane normal to an axis the
    !> image coordinate is 2 p - x along it, exactly.
    pure function solid_reflect(solid, x) result(image)
        type(solid_t), intent(in) :: solid
        real(wp), intent(in) :: x(3)
        real(wp) :: image(3)
        integer :: axis
        image = x
        axis = findloc(abs(solid%normal), 1.0_wp, dim=1)
        if (axis > 0 .and. count(solid%normal /= 0.0_wp) == 1) then
            image(axis) = 2.0_wp * solid%point(axis) - x(axis)
        else
            image = x - 2.0_wp * solid_distance(solid, x) * solid_normal(solid, x)
        end if
    end function solid_reflect

    !> Whether the point x of the fluid has its mirror image (solid_reflect) across the solid,
    !> so that the images of the fluid next to a body fill the body's inside once. A rectangle's
    !> or box's image across a face is kept only where it lies nearer that face than any other
    !> (a tie goes to the lower axis), and a point beside an edge or corner (its nearest
    !> surface point on no face) has none; a round body's only up to its centre (d <= radius).
    !> Without this the images of the three regions round a convex edge all land in the
    !> edge's quarter of the solid (up to seven over a box's vertex): the refinement of a 3D
    !> channel with a box lost its first row over the box's faces (0-7 particles within one
    !> new spacing where the run made fine has 24-36) and its relaxation pushed the row off
    !> them. level (optional, a length): a point within it of the plane of another face counts
    !> as level with that face, and its image, within level of that face, is kept (the
    !> refinement's construction: the images of the particles level with a body's face make
    !> that face's surface row where no fluid lies beyond it, as in the slot of half a spacing
    !> between a rectangle and a wall, which refined with 0 of its 10 particles without them).
    !> others, self (optional): all the solids and this one's number; a face that another
    !> covers (a body touching this one) claims no part of the inside.
    pure logical function solid_mirrors(solid, x, level, others, self)
        type(solid_t), intent(in) :: solid
        real(wp), intent(in) :: x(3)
        real(wp), intent(in), optional :: level
        type(solids_t), intent(in), optional :: others
        integer, intent(in), optional :: self
        real(wp) :: r(3), q(3), tie, lv
        integer :: a, b
        logical :: nearer
        select case (solid%shape)
        case (SOLID_RECTANGLE, SOLID_BOX)
            r = body_offset(solid, x)
            q = abs(r) - solid%half
            a = maxloc(q, dim=1)
            ! (round-off: a lattice site level with a face lies a few ulps either side of it)
            tie = 1.0e-9_wp * solid%half(a)
            lv = tie
            if (present(level)) lv = max(level, tie)
            solid_mirrors = q(a) > 0.0_wp .and. count(q > lv) <= 1
            if (.not. solid_mirrors) return
            ! the image's depth is q(a) below face a, -q(b) below the faces of axis b, and
            ! 2 half(a) - q(a) below the opposite face (a tie there goes to the lower side)
            do b = 1, 3
                if (b == a .or. abs(q(b)) <= lv) cycle
                if (b < a) then
                    nearer = q(a) < -q(b) - tie
                else
                    nearer = q(a) <= -q(b) + tie
                end if
                if (.not. nearer) nearer = face_hidden(b)
                solid_mirrors = solid_mirrors .and. nearer
            end do
            if (r(a) < 0.0_wp) then
                solid_mirrors = solid_mirrors .and. q(a) <= solid%half(a) + tie
            else
                solid_mirrors = solid_mirrors .and. q(a) < solid%half(a) - tie
            end if
        case (SOLID_CIRCLE, SOLID_SPHERE, SOLID_CYLINDER)
            solid_mirrors = solid_distance(solid, x) <= solid%radius
        case default
            solid_mirrors = .true.
        end select

    contains

        !> Whether the face of axis b that the image faces is covered, where the image lies
        !> off it, by another of `others` (a body touching this one): no fluid is mirrored
        !> across a covered face, so it claims no part of the inside (without this the corner
        !> where a rectangle touches another's face kept particles of 0.44 the median mass)
        pure logical function face_hidden(b)
            integer, intent(in) :: b
            real(wp) :: p(3)
            integer :: t
            face_hidden = .false.
            if (.not. (present(others) .and. present(self))) return
            if (.not. allocated(others%list)) return
            ! the image's foot on that face, a little outside it (absolute coordinates)
            p = x
            p(a) = x(a) - r(a) + sign(solid%half(a) - q(a), r(a))
            p(b) = x(b) - r(b) + sign(solid%half(b) * (1.0_wp + 1.0e-6_wp), r(b))
            do t = 1, size(others%list)
                if (t == self) cycle
                if (solid_distance(others%list(t), p) < 0.0_wp) face_hidden = .true.
            end do
        end function face_hidden
    end function solid_mirrors

    !> The solid that x lies deepest inside (most negative distance), 0 when x is in the
    !> fluid. Depths within `tie` of each other count as equal and the lower number wins, so
    !> a lattice site on a corner diagonal goes to the same solid whatever the round-off.
    pure integer function deepest_solid(solids, x, tie) result(best)
        type(solids_t), intent(in) :: solids
        real(wp), intent(in) :: x(3), tie
        real(wp) :: d, deepest
        integer :: k
        best = 0
        deepest = 0.0_wp
        if (.not. allocated(solids%list)) return
        do k = 1, size(solids%list)
            d = solid_distance(solids%list(k), x)
            if (d < deepest - tie .or. (best == 0 .and. d < 0.0_wp)) then
                best = k
                deepest = d
            end if
        end do
    end function deepest_solid
    !> The plane facing plane s across the fluid (the other plane with the opposite normal: the
    !> two walls of a channel), 0 when s is not a plane or no plane faces it.
    pure integer function facing_plane(solids, s) result(t_face)
        type(solids_t), intent(in) :: solids
        integer, intent(in) :: s
        integer :: t
        t_face = 0
        if (.not. allocated(solids%list)) return
        if (solids%list(s)%shape /= SOLID_PLANE) return
        do t = 1, size(solids%list)
            if (t == s .or. solids%list(t)%shape /= SOLID_PLANE) cycle
            if (dot_product(solids%list(s)%normal, solids%list(t)%normal) < -0.999_wp) t_face = t
        end do
    end function facing_plane
    !> The corners of planes at right angles (a box's) that point x lies next to: every pair
    !> of planes within [0, dist) of x whose normals are perpendicular, and after each pair
    !> every third such plane perpendicular to both (3D), as combos(:, 1:n_combos) (plane
    !> numbers in increasing order, 0 third for a pair; at most six planes taken, the faces of
    !> a box). among (optional): only those planes.
    !> Mirroring across each plane of a combo in turn gives the image across that corner.
    pure subroutine corner_planes(solids, x, dist, combos, n_combos, among)
        type(solids_t), intent(in) :: solids
        real(wp), intent(in) :: x(3), dist
        integer, intent(out) :: combos(3, MAX_CORNER_COMBOS)
        integer, intent(out) :: n_combos
        logical, intent(in), optional :: among(:)
        integer :: near(6), t, a, b, c, nn
        real(wp) :: d
        n_combos = 0
        if (.not. allocated(solids%list)) return
        nn = 0
        do t = 1, size(solids%list)
            if (solids%list(t)%shape /= SOLID_PLANE) cycle
            if (present(among)) then
                if (.not. among(t)) cycle
            end if
            d = solid_distance(solids%list(t), x)
            if (d < 0.0_wp .or. d >= dist .or. nn == size(near)) cycle
            nn = nn + 1
            near(nn) = t
        end do
        do a = 1, nn - 1
            do b = a + 1, nn
                if (.not. square(near(a), near(b))) cycle
                n_combos = n_combos + 1
                combos(:, n_combos) = [near(a), near(b), 0]
                do c = b + 1, nn
                    if (.not. square(near(a), near(c)) .or. .not. square(near(b), near(c))) &
                        cycle
                    n_combos = n_combos + 1
                    combos(:, n_combos) = [near(a), near(b), near(c)]
                end do
            end do
        end do
    contains
        pure logical function square(p, q)
            integer, intent(in) :: p, q
            square = abs(dot_product(solids%list(p)%normal, solids%list(q)%normal)) < 1.0e-6_wp
        end function square
    end subroutine corner_planes
end module sph_solids
