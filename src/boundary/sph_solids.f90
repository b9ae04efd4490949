!> Solids: the regions of space that are not fluid, each able to say at any point its signed
!> distance (positive in the fluid, negative inside the solid), the unit normal of its surface
!> pointing into the fluid, and its velocity. Wall particles, mirror images and Morris' wall
!> normals and distances are all made from these answers, so a new shape (a circle, a sphere,
!> particles from a file) is a new case here, not a change to the wall models.
!>
!> Today: the half-spaces behind the box faces that are walls (SOLID_PLANE). Solids are
!> numbered 1..n in the order given; particles carry the number of the solid they belong to
!> (0 for fluid).
module sph_solids
    use sph_kinds, only: wp
    implicit none
    private
    public :: solid_t, solids_t, solids_add_plane, solid_distance, solid_normal
    public :: solid_velocity, solid_reflect, deepest_solid
    public :: SOLID_PLANE

    integer, parameter :: SOLID_PLANE = 1   !< the half-space behind a plane (a wall face)

    type :: solid_t
        integer :: shape = SOLID_PLANE
        character(len=32) :: name = ''      !< for logs and force reports ('wall ylo')
        real(wp) :: point(3) = 0.0_wp       !< a point of the surface
        real(wp) :: normal(3) = 0.0_wp      !< plane: unit normal into the fluid
        real(wp) :: velocity(3) = 0.0_wp    !< rigid translation (a sliding wall, a lid)
        integer :: face = 0                 !< the box face it stands for, 0 for a body
    end type solid_t

    type :: solids_t
        integer :: dim = 2
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

    !> Signed distance of x from the surface: > 0 in the fluid, < 0 inside the solid.
    pure real(wp) function solid_distance(solid, x)
        type(solid_t), intent(in) :: solid
        real(wp), intent(in) :: x(3)
        select case (solid%shape)
        case default   ! SOLID_PLANE
            solid_distance = dot_product(solid%normal, x - solid%point)
        end select
    end function solid_distance

    !> Unit normal into the fluid at the surface point nearest x (curved shapes use x).
    pure function solid_normal(solid, x) result(normal)
        type(solid_t), intent(in) :: solid
        real(wp), intent(in) :: x(3)
        real(wp) :: normal(3)
        select case (solid%shape)
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
end module sph_solids
