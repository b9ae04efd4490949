!> The geometry of spatially varying resolution (thesis sec. 3.3): which level of refinement a
!> point belongs to, how far it is from the points of another level, and whether it lies in
!> that level's transition zone. Pure geometry: no particles, no MPI.
!>
!> R_L is the union of the regions of level >= L (R_0 = everywhere); level_at(x) = k means x
!> lies in R_k \ R_{k+1}. For a point x of level k and a level L /= k, distance_to_level is
!>   k < L: the distance from x to R_L (the minimum over its regions: exact);
!>   k > L: the depth of x inside R_{L+1} (the maximum over its regions of the depth inside
!>          each: a lower bound of the true depth, on the safe side: zones only get wider).
!> A transition zone of level L is the set of points of another level within `width` of the
!> points of level L: there the virtual particles of level L live.
!>
!> Box regions: axis-aligned; along a periodic axis the nearest periodic image of the box
!> (each axis on its own, as sph_solids does for bodies); a box spanning a whole period has no
!> face on that axis, and a face at or beyond a wall bounds nothing inside the domain. Body
!> regions: sd = the signed distance from the body's surface (sph_solids, periodic images
!> included); the region is sd <= distance, its exterior distance sd - distance (exact), its
!> depth distance - sd (a lower bound: the signed distance is 1-Lipschitz).
module sph_zones
    use sph_kinds, only: wp
    use sph_config, only: config_t
    use sph_solids, only: solid_t, solids_t, solid_distance
    implicit none
    private
    public :: zones_create

    integer, parameter, public :: MAX_LEVEL = 3
    integer, parameter :: ZONE_BOX = 1, ZONE_BODY = 2
    !> stands for an unbounded side of a box (finite, so sums and differences stay finite)
    real(wp), parameter :: far = huge(1.0_wp) / 8.0_wp

    !> One region, ready for the point queries.
    type :: zone_region_t
        integer :: shape = ZONE_BOX
        integer :: level = 1
        real(wp) :: lo(3) = -far, hi(3) = far   !< box: plain sides (non-periodic axes)
        logical :: wrap(3) = .false.            !< box: periodic axis, by nearest image
        real(wp) :: centre(3) = 0.0_wp, half(3) = 0.0_wp   !< box: along wrapped axes
        real(wp) :: period(3) = 0.0_wp          !< box: the period of each wrapped axis
        real(wp) :: distance = 0.0_wp           !< body: band width around the surface
        type(solid_t) :: solid                  !< body: a copy of the body's solid
    end type zone_region_t

    type, public :: zones_t
        integer :: dim = 2
        integer :: n_levels = 1      !< 1 + highest region level; 1 = uniform resolution
        real(wp) :: width = 0.0_wp   !< resolved transition zone width (m)
        !> virtual particles by the split rule (&refinement virtual_rule = 'split') or by
        !> the remeshing rules ('remesh'); see sph_transition
        logical :: split_virtuals = .true.
        real(wp) :: period(3) = 0.0_wp   !< box length along periodic axes, 0 otherwise
        type(zone_region_t), allocatable :: regions(:)
    contains
        procedure :: level_at
        procedure :: distance_to_level
        procedure :: in_transition
    end type zones_t

contains

    !> The zones of a validated configuration; `solids` are sph_walls' solids_from_config(cfg)
    !> (a body region copies its body's solid, found by name).
    function zones_create(cfg, solids) result(z)
        type(config_t), intent(in) :: cfg
        type(solids_t), intent(in) :: solids
        type(zones_t) :: z
        integer :: r, a, s, n
        real(wp) :: length
        n = 0
        if (allocated(cfg%regions)) n = size(cfg%regions)
        z%dim = cfg%domain%dimension
        z%width = cfg%refinement%width
        z%split_virtuals = trim(cfg%refinement%virtual_rule) /= 'remesh'
        z%period = 0.0_wp
        do a = 1, z%dim
            if (cfg%domain%is_periodic(a)) z%period(a) = cfg%domain%box_hi(a) - &
                cfg%domain%box_lo(a)
        end do
        allocate(z%regions(n))
        z%n_levels = 1
        do r = 1, n
            associate (inp => cfg%regions(r), reg => z%regions(r))
                reg%level = inp%level
                z%n_levels = max(z%n_levels, inp%level + 1)
                select case (trim(inp%shape))
                case ('body')
                    reg%shape = ZONE_BODY
                    reg%distance = inp%distance
                    s = find_body(trim(inp%body))
                    if (s == 0) error stop 'zones_create: a &region names an unknown body'
                    reg%solid = solids%list(s)
                case default
                    reg%shape = ZONE_BOX
                    do a = 1, z%dim
                        length = z%period(a)
                        if (length > 0.0_wp) then
                            ! spanning the whole period: no face on this axis
                            if (inp%hi(a) - inp%lo(a) >= length) cycle
                            reg%wrap(a) = .true.
                            reg%period(a) = length
                            reg%centre(a) = 0.5_wp * (inp%lo(a) + inp%hi(a))
                            reg%half(a) = 0.5_wp * (inp%hi(a) - inp%lo(a))
                        else
                            ! a face at or beyond a wall bounds nothing inside the domain
                            if (inp%lo(a) > cfg%domain%box_lo(a)) reg%lo(a) = inp%lo(a)
                            if (inp%hi(a) < cfg%domain%box_hi(a)) reg%hi(a) = inp%hi(a)
                        end if
                    end do
                end select
            end associate
        end do

    contains

        integer function find_body(name)
            character(len=*), intent(in) :: name
            integer :: k
            find_body = 0
            if (.not. allocated(solids%list)) return
            do k = 1, size(solids%list)
                if (solids%list(k)%face == 0 .and. trim(solids%list(k)%name) == name) then
                    find_body = k
                    return
                end if
            end do
        end function find_body
    end function zones_create

    !> The highest level of the regions containing x; 0 outside every region.
    pure integer function level_at(self, x) result(level)
        class(zones_t), intent(in) :: self
        real(wp), intent(in) :: x(3)
        real(wp) :: outside, depth
        integer :: r
        level = 0
        do r = 1, size(self%regions)
            if (self%regions(r)%level <= level) cycle
            call region_measure(self%regions(r), x, outside, depth)
            if (depth >= 0.0_wp) level = self%regions(r)%level
        end do
    end function level_at

    !> 0 where level_at(x) == level; elsewhere a lower bound of the distance from x to the
    !> points of that level (see the module header); huge when no point has that level.
    pure real(wp) function distance_to_level(self, x, level) result(d)
        class(zones_t), intent(in) :: self
        real(wp), intent(in) :: x(3)
        integer, intent(in) :: level
        d = level_distance(self, x, level, self%level_at(x))
    end function distance_to_level

    !> distance_to_level for a point x of level k.
    pure real(wp) function level_distance(self, x, level, k) result(d)
        class(zones_t), intent(in) :: self
        real(wp), intent(in) :: x(3)
        integer, intent(in) :: level, k
        real(wp) :: outside, depth
        integer :: r
        if (k == level) then
            d = 0.0_wp
        else if (k < level) then
            ! outside R_level: the distance to it
            d = huge(1.0_wp)
            do r = 1, size(self%regions)
                if (self%regions(r)%level < level) cycle
                call region_measure(self%regions(r), x, outside, depth)
                d = min(d, outside)
            end do
        else
            ! inside R_(level+1): the depth inside it
            d = 0.0_wp
            do r = 1, size(self%regions)
                if (self%regions(r)%level <= level) cycle
                call region_measure(self%regions(r), x, outside, depth)
                d = max(d, depth)
            end do
        end if
    end function level_distance

    !> x is not of this level but within the transition width of its points: where the
    !> virtual particles of this level live.
    pure logical function in_transition(self, x, level)
        class(zones_t), intent(in) :: self
        real(wp), intent(in) :: x(3)
        integer, intent(in) :: level
        integer :: k
        in_transition = .false.
        k = self%level_at(x)
        if (k == level) return
        in_transition = level_distance(self, x, level, k) < self%width
    end function in_transition

    !> Distance from x to the region (0 inside) and depth of x inside it (< 0 outside: minus
    !> a lower bound of the distance; only its sign and positive values are used).
    pure subroutine region_measure(reg, x, outside, depth)
        type(zone_region_t), intent(in) :: reg
        real(wp), intent(in) :: x(3)
        real(wp), intent(out) :: outside, depth
        real(wp) :: r, ex(3), sd
        integer :: a
        if (reg%shape == ZONE_BODY) then
            sd = solid_distance(reg%solid, x)
            outside = max(sd - reg%distance, 0.0_wp)
            depth = reg%distance - sd
            return
        end if
        depth = far
        do a = 1, 3
            if (reg%wrap(a)) then
                r = x(a) - reg%centre(a)
                r = abs(r - reg%period(a) * anint(r / reg%period(a)))
                ex(a) = max(r - reg%half(a), 0.0_wp)
                depth = min(depth, reg%half(a) - r)
            else
                ex(a) = max(reg%lo(a) - x(a), x(a) - reg%hi(a), 0.0_wp)
                depth = min(depth, x(a) - reg%lo(a), reg%hi(a) - x(a))
            end if
        end do
        outside = norm2(ex)
    end subroutine region_measure
end module sph_zones
