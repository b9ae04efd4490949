!> Solid walls of the box. Three kinds of boundary particle, chosen by &numerics wall_model:
!>  - Morris et al. (1997) no-slip wall particles: layers outside each wall face filling the
!>    kernel support, taking part in every SPH sum; in the viscous term their velocity is
!>    extrapolated across the wall (beta factor, see sph_rates). Corners are filled too.
!>  - thesis type-1 particles: one layer on the wall plane exerting only the repulsive force
!>    of eq. 2.18.
!>  - thesis type-2 particles: mirror images of the fluid particles near a wall, rebuilt at
!>    every stage with the same density and pressure and the velocity 2 u_wall - v.
!> Wall particles carry their wall's velocity but stay in place (a belt), which serves both a
!> sliding plate (Couette) and a lid.
module sph_walls
    use sph_kinds, only: wp
    use sph_config, only: config_t, n_faces
    use sph_particles, only: particles_t, particles_reserve, KIND_FLUID, KIND_MIRROR
    use sph_physics, only: physics_t, WALLS_MIRROR, WALLS_REPULSIVE_MIRROR
    implicit none
    private
    public :: wall_geometry_t, wall_geometry_from_config, wall_layers, wall_lattice_ranges
    public :: wall_site, build_mirrors

    type :: wall_geometry_t
        integer :: dim = 2
        logical :: is_wall(n_faces) = .false.
        real(wp) :: plane(n_faces) = 0.0_wp          !< coordinate of the face along its axis
        real(wp) :: velocity(3, n_faces) = 0.0_wp
        real(wp) :: lo(3) = 0.0_wp, hi(3) = 0.0_wp
    end type wall_geometry_t

contains

    function wall_geometry_from_config(cfg) result(geo)
        type(config_t), intent(in) :: cfg
        type(wall_geometry_t) :: geo
        integer :: f, axis
        geo%dim = cfg%domain%dimension
        geo%lo = cfg%domain%box_lo
        geo%hi = cfg%domain%box_hi
        do f = 1, 2 * cfg%domain%dimension
            axis = (f + 1) / 2
            geo%is_wall(f) = cfg%domain%is_wall(f)
            if (mod(f, 2) == 1) then
                geo%plane(f) = cfg%domain%box_lo(axis)
            else
                geo%plane(f) = cfg%domain%box_hi(axis)
            end if
            geo%velocity(:, f) = 0.0_wp
            geo%velocity(1:cfg%domain%dimension, f) = &
                cfg%domain%wall_velocity(1:cfg%domain%dimension, f)
        end do
    end function wall_geometry_from_config

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

    !> For lattice cell idx of the extended lattice: is it a wall site, and its face, normal
    !> (into the fluid) and distance behind the wall plane. The face is the one the site lies
    !> deepest behind (ties: the lower axis), so each corner site belongs to exactly one face.
    pure subroutine wall_site(geo, n_inside, idx, dx, is_site, face, normal, distance)
        type(wall_geometry_t), intent(in) :: geo
        integer, intent(in) :: n_inside(3), idx(3)
        real(wp), intent(in) :: dx
        logical, intent(out) :: is_site
        integer, intent(out) :: face
        real(wp), intent(out) :: normal(3), distance
        integer :: axis, depth, best
        best = 0
        face = 0
        do axis = 1, geo%dim
            depth = 0
            if (idx(axis) < 1) then
                depth = 1 - idx(axis)
                if (depth > best) then
                    best = depth; face = 2*axis - 1
                end if
            else if (idx(axis) > n_inside(axis)) then
                depth = idx(axis) - n_inside(axis)
                if (depth > best) then
                    best = depth; face = 2*axis
                end if
            end if
        end do
        is_site = best > 0
        normal = 0.0_wp
        distance = 0.0_wp
        if (is_site) then
            axis = (face + 1) / 2
            normal(axis) = merge(1.0_wp, -1.0_wp, mod(face, 2) == 1)
            distance = (real(best, wp) - 0.5_wp) * dx
        end if
    end subroutine wall_site

    !> Append type-2 mirror images of the fluid particles (owned and ghosts) lying within the
    !> kernel support of a wall, across each such wall and across pairs/triples of walls at
    !> corners. Mirrors go after the ghosts and are rebuilt whenever the ghosts change.
    subroutine build_mirrors(phys, geo, p)
        type(physics_t), intent(in) :: phys
        type(wall_geometry_t), intent(in) :: geo
        type(particles_t), intent(inout) :: p
        integer :: k, axis, n_near, subset, bit, f, n_sources, faces(3), n
        real(wp) :: xm(3), vm(3), reach

        p%n_total = p%n_owned + p%n_ghost
        if (phys%walls /= WALLS_MIRROR .and. phys%walls /= WALLS_REPULSIVE_MIRROR) return
        reach = phys%kernel%support
        n_sources = p%n_total
        do k = 1, n_sources
            if (p%kind(k) /= KIND_FLUID) cycle
            n_near = 0
            do axis = 1, geo%dim
                f = 0
                if (geo%is_wall(2*axis - 1) .and. p%x(axis, k) - geo%plane(2*axis - 1) < reach) then
                    f = 2*axis - 1
                else if (geo%is_wall(2*axis) .and. geo%plane(2*axis) - p%x(axis, k) < reach) then
                    f = 2*axis
                end if
                if (f > 0) then
                    n_near = n_near + 1
                    faces(n_near) = f
                end if
            end do
            do subset = 1, 2**n_near - 1
                xm = p%x(:, k)
                vm = p%v(:, k)
                do bit = 1, n_near
                    if (.not. btest(subset, bit - 1)) cycle
                    f = faces(bit)
                    axis = (f + 1) / 2
                    xm(axis) = 2.0_wp * geo%plane(f) - xm(axis)
                    vm = 2.0_wp * geo%velocity(:, f) - vm
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
                p%strain(:, n) = -p%strain(:, k)
                p%wall_normal(:, n) = 0.0_wp
                p%wall_distance(n) = 0.0_wp
                p%id(n) = -p%id(k)
                p%kind(n) = KIND_MIRROR
                p%level(n) = p%level(k)
                p%n_total = n
            end do
        end do
    end subroutine build_mirrors
end module sph_walls
