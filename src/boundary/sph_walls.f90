!> Solid walls as particles. Three kinds of boundary particle, chosen by &numerics wall_model,
!> all made from the solids (sph_solids: signed distance, normal and velocity at a point):
!>  - Morris et al. (1997) no-slip wall particles: lattice sites inside a solid, to one kernel
!>    support of depth, taking part in every SPH sum; in the viscous term their velocity is
!>    extrapolated across the wall (beta factor, see sph_rates). Corners are filled too: a
!>    site belongs to the solid it lies deepest inside.
!>  - thesis type-1 particles: one layer on the wall plane exerting only the repulsive force
!>    of eq. 2.18.
!>  - thesis type-2 particles: mirror images of the fluid particles near a solid, rebuilt at
!>    every stage with the same density and pressure and the velocity 2 u_wall - v.
!> Wall particles carry their solid's velocity but stay in place (a belt), which serves both a
!> sliding plate (Couette) and a lid.
module sph_walls
    use sph_kinds, only: wp
    use sph_config, only: config_t, n_faces, face_names
    use sph_particles, only: particles_t, particles_reserve, KIND_FLUID, KIND_MIRROR, &
        moves_with_flow
    use sph_physics, only: physics_t, WALLS_MIRROR, WALLS_REPULSIVE_MIRROR
    use sph_solids, only: solids_t, solid_t, solids_add_plane, solid_distance, solid_normal, &
        solid_velocity, solid_reflect, deepest_solid, solids_add_body, SOLID_CIRCLE, &
        SOLID_SPHERE, SOLID_CYLINDER, SOLID_RECTANGLE, SOLID_BOX
    implicit none
    private
    public :: solids_from_config, wall_layers, wall_lattice_ranges, wall_site, build_mirrors
    public :: body_surface_sites, clear_of_solids, fluid_position, FLUID_CLEARANCE
    public :: body_holds_site

    !> Least distance, in spacings, of a fluid particle of the initial lattice from a solid,
    !> that of the first row at a plane wall. The sites a curved surface cuts lie at any
    !> distance s from it; those closer are pushed out to it (fluid_position), not dropped: a
    !> site stands for the fluid from s - dx/2 to s + dx/2, so dropping the sites with s < c
    !> leaves on average a layer c dx thick without fluid over the surface, which the flow
    !> feels as slip (dropped below dx/2, the creeping flow through the sphere lattice ran
    !> 18.6 % faster than Sangani & Acrivos' at L/20; pushed, 2.5 %). Pushed only to dx/4, a
    !> fluid particle entered the L/100 cylinder at t = 2381 s.
    real(wp), parameter :: FLUID_CLEARANCE = 0.5_wp

contains

    !> The solids of a configuration: the half-space behind every box face that is a wall,
    !> in face order (xlo, xhi, ylo, yhi, zlo, zhi), then one solid per &body in file order.
    function solids_from_config(cfg) result(solids)
        type(config_t), intent(in) :: cfg
        type(solids_t) :: solids
        integer :: f, axis, dim, b, shape
        real(wp) :: point(3), normal(3), velocity(3)
        dim = cfg%domain%dimension
        solids%dim = dim
        solids%period = 0.0_wp
        do axis = 1, dim
            if (cfg%domain%is_periodic(axis)) solids%period(axis) = &
                cfg%domain%box_hi(axis) - cfg%domain%box_lo(axis)
        end do
        allocate(solids%list(0))
        do f = 1, 2 * dim
            if (.not. cfg%domain%is_wall(f)) cycle
            axis = (f + 1) / 2
            point = 0.0_wp
            normal = 0.0_wp
            if (mod(f, 2) == 1) then
                point(axis) = cfg%domain%box_lo(axis)
                normal(axis) = 1.0_wp
            else
                point(axis) = cfg%domain%box_hi(axis)
                normal(axis) = -1.0_wp
            end if
            velocity = 0.0_wp
            velocity(1:dim) = cfg%domain%wall_velocity(1:dim, f)
            call solids_add_plane(solids, 'wall ' // trim(face_names(f)), point, normal, &
                velocity, face=f)
        end do
        if (.not. allocated(cfg%bodies)) return
        do b = 1, size(cfg%bodies)
            associate (body => cfg%bodies(b))
                select case (trim(body%shape))
                case ('circle'); shape = SOLID_CIRCLE
                case ('sphere'); shape = SOLID_SPHERE
                case ('cylinder'); shape = SOLID_CYLINDER
                case ('rectangle'); shape = SOLID_RECTANGLE
                case default; shape = SOLID_BOX
                end select
                velocity = 0.0_wp
                velocity(1:dim) = body%velocity(1:dim)
                call solids_add_body(solids, body%name, shape, velocity, centre=body%centre, &
                    radius=body%radius, axis=index('xyz', body%axis), lo=body%lo, hi=body%hi)
            end associate
        end do
    end function solids_from_config

    !> Sites on a body's surface at a spacing of about dx, with the body's normal there (the
    !> thesis type-1 particles of a body): circles by angle; spheres by rings of latitude, each
    !> ring by angle; cylinders by angle on rings at the lattice positions along their axis
    !> (box_lo..box_hi); rectangles and boxes on a grid over each face, corners and edges
    !> skipped as on the box walls. Positions are not wrapped into a periodic box.
    subroutine body_surface_sites(solid, dx, box_lo, box_hi, x, normal)
        type(solid_t), intent(in) :: solid
        real(wp), intent(in) :: dx, box_lo(3), box_hi(3)
        real(wp), allocatable, intent(out) :: x(:, :), normal(:, :)
        real(wp), parameter :: pi = acos(-1.0_wp)
        integer :: n, k, i, m, n_theta, n_phi, n_along, a, t1, t2, side, n1, n2, dims
        real(wp) :: theta, phi, p(3), c(3), r
        real(wp), allocatable :: buf(:, :)
        allocate(buf(3, 0))
        c = solid%centre
        r = solid%radius
        select case (solid%shape)
        case (SOLID_CIRCLE)
            n = max(3, nint(2.0_wp * pi * r / dx))
            do k = 1, n
                theta = 2.0_wp * pi * (real(k, wp) - 0.5_wp) / real(n, wp)
                call push([c(1) + r * cos(theta), c(2) + r * sin(theta), 0.0_wp])
            end do
        case (SOLID_SPHERE)
            n_theta = max(2, nint(pi * r / dx))
            do i = 1, n_theta
                theta = pi * (real(i, wp) - 0.5_wp) / real(n_theta, wp)
                n_phi = max(1, nint(2.0_wp * pi * r * sin(theta) / dx))
                do k = 1, n_phi
                    phi = 2.0_wp * pi * (real(k, wp) - 0.5_wp) / real(n_phi, wp)
                    call push(c + r * [sin(theta) * cos(phi), sin(theta) * sin(phi), &
                        cos(theta)])
                end do
            end do
        case (SOLID_CYLINDER)
            a = solid%axis
            t1 = mod(a, 3) + 1
            t2 = mod(a + 1, 3) + 1
            n = max(3, nint(2.0_wp * pi * r / dx))
            n_along = max(1, nint((box_hi(a) - box_lo(a)) / dx))
            do m = 1, n_along
                do k = 1, n
                    theta = 2.0_wp * pi * (real(k, wp) - 0.5_wp) / real(n, wp)
                    p(a) = box_lo(a) + (real(m, wp) - 0.5_wp) * dx
                    p(t1) = c(t1) + r * cos(theta)
                    p(t2) = c(t2) + r * sin(theta)
                    call push(p)
                end do
            end do
        case (SOLID_RECTANGLE, SOLID_BOX)
            dims = merge(2, 3, solid%shape == SOLID_RECTANGLE)
            do a = 1, dims
                t1 = merge(2, 1, a == 1)
                t2 = 6 - a - t1
                n1 = max(1, nint(2.0_wp * solid%half(t1) / dx))
                n2 = 1
                if (dims == 3) n2 = max(1, nint(2.0_wp * solid%half(t2) / dx))
                do side = -1, 1, 2
                    do m = 1, n2
                        do k = 1, n1
                            p = 0.0_wp
                            p(a) = c(a) + real(side, wp) * solid%half(a)
                            p(t1) = c(t1) - solid%half(t1) + (real(k, wp) - 0.5_wp) * &
                                2.0_wp * solid%half(t1) / real(n1, wp)
                            if (dims == 3) p(t2) = c(t2) - solid%half(t2) + &
                                (real(m, wp) - 0.5_wp) * 2.0_wp * solid%half(t2) / real(n2, wp)
                            call push(p)
                        end do
                    end do
                end do
            end do
        end select
        x = buf
        allocate(normal(3, size(x, 2)))
        do k = 1, size(x, 2)
            normal(:, k) = solid_normal(solid, x(:, k))
        end do

    contains

        subroutine push(point)
            real(wp), intent(in) :: point(3)
            buf = reshape([buf, point], [3, size(buf, 2) + 1])
        end subroutine push
    end subroutine body_surface_sites

    !> Layers of Morris wall particles needed to fill the kernel support.
    integer function wall_layers(phys)
        type(physics_t), intent(in) :: phys
        wall_layers = ceiling(phys%kernel%support / phys%dx - 1.0e-9_wp)
    end function wall_layers

    !> Index ranges of the extended lattice (cells of size dx; 1..n inside the box, walls add
    !> `layers` cells on each side of a wall axis).
    subroutine wall_lattice_ranges(cfg, layers, first, last)
        type(config_t), intent(in) :: cfg
        integer, intent(in) :: layers
        integer, intent(out) :: first(3), last(3)
        integer :: axis
        first = 1; last = 1
        do axis = 1, cfg%domain%dimension
            last(axis) = nint((cfg%domain%box_hi(axis) - cfg%domain%box_lo(axis)) / cfg%domain%dx)
            if (cfg%domain%is_wall(2*axis - 1)) then
                first(axis) = 1 - layers
                last(axis) = last(axis) + layers
            end if
        end do
    end subroutine wall_lattice_ranges

    !> Is the lattice site x at least FLUID_CLEARANCE dx from every solid, so that a fluid
    !> particle there does not sit on a wall? See FLUID_CLEARANCE. Box faces keep their first
    !> row at exactly dx/2.
    pure logical function clear_of_solids(solids, x, dx) result(clear)
        type(solids_t), intent(in) :: solids
        real(wp), intent(in) :: x(3), dx
        integer :: k
        clear = .true.
        if (.not. allocated(solids%list)) return
        do k = 1, size(solids%list)
            if (solid_distance(solids%list(k), x) < FLUID_CLEARANCE * dx * (1.0_wp - 1.0e-6_wp)) &
                clear = .false.
        end do
    end function clear_of_solids

    !> Where the fluid particle of the lattice site x (outside every solid) goes: x itself
    !> when it is at least FLUID_CLEARANCE dx from every solid, else x pushed out along the
    !> nearest solid's normal to that distance, so that the fluid still fills the geometry up
    !> to the surface on average (FLUID_CLEARANCE). clear = .false. when the pushed point is
    !> still too close to a solid (two surfaces less than a spacing apart): no particle.
    pure subroutine fluid_position(solids, x, dx, y, clear)
        type(solids_t), intent(in) :: solids
        real(wp), intent(in) :: x(3), dx
        real(wp), intent(out) :: y(3)
        logical, intent(out) :: clear
        integer :: k, nearest
        real(wp) :: d, d_min
        y = x
        clear = clear_of_solids(solids, y, dx)
        if (clear) return
        nearest = 0
        d_min = huge(1.0_wp)
        do k = 1, size(solids%list)
            d = solid_distance(solids%list(k), y)
            if (d < d_min) then
                d_min = d
                nearest = k
            end if
        end do
        y = y + (FLUID_CLEARANCE * dx - d_min) * solid_normal(solids%list(nearest), y)
        clear = clear_of_solids(solids, y, dx)
    end subroutine fluid_position

    !> Is the point x (a lattice site) inside a solid, and if so which (the one it lies
    !> deepest inside; ties, as on a corner diagonal, go to the lower number), the normal into
    !> the fluid and the distance behind the surface. dx sets the tie tolerance; a site on a
    !> surface (within 1e-6 dx) belongs to the solid.
    pure subroutine wall_site(solids, x, dx, is_site, solid, normal, distance)
        type(solids_t), intent(in) :: solids
        real(wp), intent(in) :: x(3), dx
        logical, intent(out) :: is_site
        integer, intent(out) :: solid
        real(wp), intent(out) :: normal(3), distance
        integer :: k
        solid = deepest_solid(solids, x, 1.0e-6_wp * dx)
        ! a site on a surface belongs to the solid: as a fluid particle it would sit at zero
        ! distance from the wall and enter it at its first move (a 3-4-5 site on a circle)
        if (solid == 0 .and. allocated(solids%list)) then
            do k = 1, size(solids%list)
                if (solid_distance(solids%list(k), x) <= 1.0e-6_wp * dx) then
                    solid = k
                    exit
                end if
            end do
        end if
        is_site = solid > 0
        normal = 0.0_wp
        distance = 0.0_wp
        if (is_site) then
            normal = solid_normal(solids%list(solid), x)
            distance = -solid_distance(solids%list(solid), x)
        end if
    end subroutine wall_site

    !> Whether a site of the lattice of spacing dx (box_lo + (i - 1/2) dx per axis, the
    !> set-up's and a remesh's walls) lies inside or on body b of cfg (Morris walls are the
    !> sites inside a solid: a body that holds none has no wall particle, no effect on the
    !> flow and no force). Geometry only: a site that a deeper solid takes (a body inside
    !> another) still counts.
    function body_holds_site(cfg, solids, b, dx) result(holds)
        type(config_t), intent(in) :: cfg
        type(solids_t), intent(in) :: solids
        integer, intent(in) :: b
        real(wp), intent(in) :: dx
        logical :: holds
        real(wp) :: lo(3), hi(3), x(3)
        integer :: first(3), last(3), i, j, k, dim, s, a, idx(3)
        dim = cfg%domain%dimension
        ! the bodies follow the box's planes in the solids' list, in input order
        s = size(solids%list) - size(cfg%bodies) + b
        associate (body => cfg%bodies(b))
            select case (trim(body%shape))
            case ('rectangle', 'box')
                lo = body%lo
                hi = body%hi
            case default
                lo = body%centre - body%radius
                hi = body%centre + body%radius
            end select
            first = 1
            last = 1
            do a = 1, dim
                ! (a cylinder is the same all along its axis: one row of sites across it)
                if (trim(body%shape) == 'cylinder' .and. achar(iachar('w') + a) == body%axis) &
                    cycle
                first(a) = floor((lo(a) - cfg%domain%box_lo(a)) / dx + 0.5_wp)
                last(a) = ceiling((hi(a) - cfg%domain%box_lo(a)) / dx + 0.5_wp)
            end do
        end associate
        holds = .true.
        x = 0.0_wp
        do k = first(3), last(3)
            do j = first(2), last(2)
                do i = first(1), last(1)
                    idx = [i, j, k]
                    x(1:dim) = cfg%domain%box_lo(1:dim) + (real(idx(1:dim), wp) - 0.5_wp) * dx
                    if (solid_distance(solids%list(s), x) <= 1.0e-6_wp * dx) return
                end do
            end do
        end do
        holds = .false.
    end function body_holds_site

    !> Append type-2 mirror images of the fluid particles (owned and ghosts) lying within the
    !> kernel support of a solid: across each such solid, and across every combination of
    !> such solids with non-parallel surfaces (corners). Mirrors go after the ghosts and are
    !> rebuilt whenever the ghosts change.
    subroutine build_mirrors(phys, solids, p)
        type(physics_t), intent(in) :: phys
        type(solids_t), intent(in) :: solids
        type(particles_t), intent(inout) :: p
        integer, parameter :: max_near = 3
        integer :: k, s, n_near, subset, bit, other, n_sources, near(max_near), n
        real(wp) :: xm(3), vm(3), reach
        logical :: combinable

        p%n_total = p%n_owned + p%n_ghost
        if (phys%walls /= WALLS_MIRROR .and. phys%walls /= WALLS_REPULSIVE_MIRROR) return
        reach = phys%kernel%support
        n_sources = p%n_total
        do k = 1, n_sources
            if (.not. moves_with_flow(p%kind(k))) cycle
            n_near = 0
            do s = 1, size(solids%list)
                if (n_near == max_near) exit
                if (solid_distance(solids%list(s), p%x(:, k)) < reach) then
                    n_near = n_near + 1
                    near(n_near) = s
                end if
            end do
            do subset = 1, 2**n_near - 1
                ! parallel surfaces (the two walls of a narrow channel) are mirrored apart,
                ! never composed: that image would be a translated copy
                combinable = .true.
                do bit = 1, n_near
                    if (.not. btest(subset, bit - 1)) cycle
                    do other = bit + 1, n_near
                        if (.not. btest(subset, other - 1)) cycle
                        if (abs(dot_product(solids%list(near(bit))%normal, &
                            solids%list(near(other))%normal)) > 1.0_wp - 1.0e-12_wp) &
                            combinable = .false.
                    end do
                end do
                if (.not. combinable) cycle
                xm = p%x(:, k)
                vm = p%v(:, k)
                do bit = 1, n_near
                    if (.not. btest(subset, bit - 1)) cycle
                    associate (solid => solids%list(near(bit)))
                        vm = 2.0_wp * solid_velocity(solid, xm) - vm
                        xm = solid_reflect(solid, xm)
                    end associate
                end do
                n = p%n_total + 1
                call particles_reserve(p, n)
                p%x(:, n) = xm
                p%v(:, n) = vm
                p%rho(n) = p%rho(k)
                p%p(n) = p%p(k)
                p%m(n) = p%m(k)
                p%h(n) = p%h(k)
                p%e(n) = p%e(k)
                ! strain of the image flow: an approximation (sign flip), see doc/physics.md
                if (p%with_strain) p%strain(:, n) = -p%strain(:, k)
                p%wall_normal(:, n) = 0.0_wp
                p%wall_distance(n) = 0.0_wp
                p%id(n) = -p%id(k)
                p%kind(n) = KIND_MIRROR
                p%level(n) = p%level(k)
                p%solid(n) = near(1)
                p%n_total = n
            end do
        end do
    end subroutine build_mirrors
end module sph_walls
