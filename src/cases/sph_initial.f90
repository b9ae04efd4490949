!> Initial particles: fluid at rest on a lattice of spacing dx filling the box minus the
!> solids, and the wall particles of the chosen wall model (Morris: the lattice sites inside a
!> solid to one kernel support of depth, behind the box faces and inside bodies alike; thesis
!> type-1: one layer on each wall plane and on each body's surface). Each rank makes only the
!> particles its subdomain owns; global ids come from lattice indices, so they do not depend
!> on the rank count.
module sph_initial
    use sph_kinds, only: wp, i8
    use sph_config, only: config_t
    use sph_particles, only: particles_t, particles_reserve, KIND_FLUID, KIND_WALL
    use sph_physics, only: physics_t, WALLS_MORRIS, WALLS_REPULSIVE, WALLS_REPULSIVE_MIRROR, &
        DENSITY_SUMMATION
    use sph_kernel, only: kernel_lattice_sum
    use sph_walls, only: wall_layers, wall_lattice_ranges, wall_site, body_surface_sites, &
        fluid_position
    use sph_solids, only: solids_t, solid_velocity, solid_distance, SOLID_PLANE
    use sph_domain, only: domain_t, domain_owner
    use sph_eos, only: eos_pressure
    implicit none
    private
    public :: create_lattice_particles, lattice_sites_estimate, lattice_mass_factor

    !> Which lattice sites a caller wants (create_lattice_particles' optional filter): the
    !> others are never made, so a lattice over the whole box costs memory only for what is
    !> kept (a fine level of a multi-resolution run needs its region and zone only).
    type, abstract, public :: site_filter_t
    contains
        procedure(keep_site_i), deferred :: keep
    end type site_filter_t

    abstract interface
        !> Whether the site at x that would get a particle of this kind is made.
        logical function keep_site_i(self, x, kind)
            import :: site_filter_t, wp
            class(site_filter_t), intent(in) :: self
            real(wp), intent(in) :: x(3)
            integer, intent(in) :: kind
        end function keep_site_i
    end interface

    !> Summation-density runs: a lattice kernel sum within this of 1 leaves the masses at
    !> rho0 dx^dim. The 2D cubic spline's 0.99995 is: corrected, the lid-driven cavities at
    !> L/50 scored worse against Ghia (transport velocity: RMS 0.59 -> 0.91 % of U;
    !> without it 3.46 -> 3.68 %): a closed box's pressure level is set by its mass, and
    !> they are validated at the uncorrected one.
    real(wp), parameter :: LATTICE_SUM_TOLERANCE = 1.0e-3_wp

contains

    !> The factor on rho0 dx^dim that gives the lattice's particles their mass (an initial
    !> particle file's without masses too): 1, except in a run whose density is the kernel
    !> sum of the masses, where it is 1 / (the lattice's kernel sum times dx^dim) when that
    !> sum is off 1 by more than LATTICE_SUM_TOLERANCE, so that the run starts at rho0
    !> (Wendland C2 at 1.5 dx in 2D: 1.0051; the run started half a percent dense against
    !> walls at rho0, its Couette flow 0.43 % off against 0.0035 % with continuity density,
    !> now 0.029 %; the cubic spline in 3D: 0.9973, 3D Poiseuille 0.75 -> 0.22 %).
    real(wp) function lattice_mass_factor(cfg, phys) result(factor)
        type(config_t), intent(in) :: cfg
        type(physics_t), intent(in) :: phys
        factor = 1.0_wp
        if (phys%density_method /= DENSITY_SUMMATION) return
        factor = kernel_lattice_sum(phys%kernel, cfg%domain%dx, cfg%domain%dimension) * &
            cfg%domain%dx**cfg%domain%dimension
        if (abs(factor - 1.0_wp) <= LATTICE_SUM_TOLERANCE) then
            factor = 1.0_wp
        else
            factor = 1.0_wp / factor
        end if
    end function lattice_mass_factor

    !> About how many fluid particles the lattice of &domain dx lays in the box (its sites;
    !> walls and bodies not counted): in real arithmetic, so that a dx far too small for the
    !> box gives a figure to check instead of an integer overflow.
    pure real(wp) function lattice_sites_estimate(cfg) result(sites)
        type(config_t), intent(in) :: cfg
        integer :: axis
        sites = 1.0_wp
        do axis = 1, cfg%domain%dimension
            sites = sites * max(1.0_wp, anint((cfg%domain%box_hi(axis) - &
                cfg%domain%box_lo(axis)) / cfg%domain%dx))
        end do
    end function lattice_sites_estimate

    !> The initial particles: this rank's share of the fluid lattice (bodies and walls left
    !> out) and the wall particles of every solid, with masses rho0 dx^dim and ids by site.
    subroutine create_lattice_particles(cfg, phys, solids, domain, p, walls_only, filter, &
            fluid_mass_total)
        type(config_t), intent(in) :: cfg
        type(physics_t), intent(in) :: phys
        type(solids_t), intent(in) :: solids
        type(domain_t), intent(in) :: domain
        type(particles_t), intent(inout) :: p
        !> only the wall particles (a remesh's new walls; ids as in the full lattice)
        logical, intent(in), optional :: walls_only
        !> only the sites it keeps (ids as in the full lattice)
        class(site_filter_t), intent(in), optional :: filter
        !> the mass of the whole lattice's fluid, every rank's (rho0 times the fluid volume
        !> with bodies, rho0 dx^dim per site without)
        real(wp), intent(out), optional :: fluid_mass_total
        integer :: n_inside(3), first(3), last(3), idx(3), i, j, k, solid, layers, axis
        integer(i8) :: n_fluid_total, n_ext(3), linear
        real(wp) :: xi(3), xf(3), normal(3), distance, mass, fluid_mass, lattice_factor
        logical :: site, make_fluid

        n_inside = 1
        do axis = 1, cfg%domain%dimension
            n_inside(axis) = nint((cfg%domain%box_hi(axis) - cfg%domain%box_lo(axis)) / &
                cfg%domain%dx)
        end do
        n_fluid_total = product(int(n_inside, i8))
        lattice_factor = lattice_mass_factor(cfg, phys)
        mass = cfg%fluid%rho0 * cfg%domain%dx**cfg%domain%dimension * lattice_factor
        fluid_mass = mass
        p%n_owned = 0
        make_fluid = .true.
        if (present(walls_only)) make_fluid = .not. walls_only
        if (make_fluid .and. has_bodies()) fluid_mass = cfg%fluid%rho0 * fluid_volume() / &
            real(max(1_i8, count_fluid_sites()), wp) * lattice_factor
        if (present(fluid_mass_total)) fluid_mass_total = fluid_mass * &
            real(count_fluid_sites(), wp)
        ! fluid
        do k = 1, merge(n_inside(3), 0, make_fluid)
            do j = 1, n_inside(2)
                do i = 1, n_inside(1)
                    idx = [i, j, k]
                    xi = lattice_position(idx)
                    if (domain_owner(domain, xi) /= domain%rank) cycle
                    ! the lattice minus the solids (bodies inside the box, their surfaces
                    ! included): the same rule that makes the wall sites
                    if (.not. fluid_site(xi, xf)) cycle
                    if (.not. wanted(xf, KIND_FLUID)) cycle
                    linear = 1 + (i - 1) + int(n_inside(1), i8) * ((j - 1) + int(n_inside(2), &
                        i8) * (k - 1))
                    call add_particle(xf, linear, KIND_FLUID, [0.0_wp, 0.0_wp, 0.0_wp], 0.0_wp, &
                        [0.0_wp, 0.0_wp, 0.0_wp], 0)
                    p%m(p%n_owned) = fluid_mass
                    ! odd lattice index along an axis: its bit set (sph_transition: the sites
                    ! with even indices on every axis continue the lattice of twice the spacing)
                    do axis = 1, cfg%domain%dimension
                        if (mod(idx(axis), 2) == 1) p%parity(p%n_owned) = &
                            ibset(p%parity(p%n_owned), axis - 1)
                    end do
                end do
            end do
        end do
        ! Morris wall particles: every extended-lattice site inside a solid
        if (phys%walls == WALLS_MORRIS) then
            layers = wall_layers(phys)
            call wall_lattice_ranges(cfg, layers, first, last)
            n_ext = int(last - first + 1, i8)
            do k = first(3), last(3)
                do j = first(2), last(2)
                    do i = first(1), last(1)
                        idx = [i, j, k]
                        xi = lattice_position(idx)
                        call wall_site(solids, xi, cfg%domain%dx, site, solid, normal, distance)
                        if (.not. site) cycle
                        if (distance > layers * cfg%domain%dx) cycle   ! deeper than the support
                        if (domain_owner(domain, xi) /= domain%rank) cycle
                        if (.not. wanted(xi, KIND_WALL)) cycle
                        linear = n_fluid_total + 1 + (i - first(1)) &
                            + n_ext(1) * ((j - first(2)) + n_ext(2) * (k - first(3)))
                        call add_particle(xi, linear, KIND_WALL, normal, distance, &
                            solid_velocity(solids%list(solid), xi), solid)
                    end do
                end do
            end do
        end if
        ! thesis type-1 particles: one layer on each wall plane, spacing dx
        if (phys%walls == WALLS_REPULSIVE .or. phys%walls == WALLS_REPULSIVE_MIRROR) then
            call add_type1_layers(n_fluid_total)
        end if
        p%n_total = p%n_owned
        p%n_ghost = 0

    contains

        !> The caller's filter (every site without one).
        logical function wanted(x, kind)
            real(wp), intent(in) :: x(3)
            integer, intent(in) :: kind
            wanted = .true.
            if (present(filter)) wanted = filter%keep(x, kind)
        end function wanted

        !> A site that gets a fluid particle: outside every solid, its surface included; the
        !> particle goes to y, at least FLUID_CLEARANCE dx from every solid (fluid_position).
        logical function fluid_site(x, y)
            real(wp), intent(in) :: x(3)
            real(wp), intent(out) :: y(3)
            logical :: inside, clear
            integer :: s_index
            real(wp) :: s_normal(3), s_distance
            call wall_site(solids, x, cfg%domain%dx, inside, s_index, s_normal, s_distance)
            y = x
            clear = .false.
            if (.not. inside) call fluid_position(solids, x, cfg%domain%dx, y, clear)
            fluid_site = clear
        end function fluid_site

        logical function has_bodies()
            integer :: b
            has_bodies = .false.
            if (.not. allocated(solids%list)) return
            do b = 1, size(solids%list)
                if (solids%list(b)%shape /= SOLID_PLANE) has_bodies = .true.
            end do
        end function has_bodies

        !> Fluid sites of the whole lattice (every rank counts all of them: no MPI here).
        integer(i8) function count_fluid_sites() result(n)
            integer :: a, b, c
            real(wp) :: y(3)
            n = 0
            do c = 1, n_inside(3)
                do b = 1, n_inside(2)
                    do a = 1, n_inside(1)
                        if (fluid_site(lattice_position([a, b, c]), y)) n = n + 1
                    end do
                end do
            end do
        end function count_fluid_sites

        !> The volume (area in 2D) of the box outside the bodies: each lattice cell that a
        !> body surface may cross is sampled at 8^d (2D) or 4^d (3D) points. With bodies,
        !> the fluid particles share rho0 times this volume, so the fluid's mass (and the
        !> body force on it, which the drag balances at steady state) is the geometry's,
        !> not that of the lattice sites left after cutting the bodies out.
        real(wp) function fluid_volume() result(volume)
            integer :: a, b, c, sa, sb, sc, n_sub(3), inside_count
            real(wp) :: x0(3), y(3), reach, d_min
            n_sub = 1
            n_sub(1:cfg%domain%dimension) = merge(8, 4, cfg%domain%dimension == 2)
            reach = 0.5_wp * sqrt(real(cfg%domain%dimension, wp)) * cfg%domain%dx
            volume = 0.0_wp
            do c = 1, n_inside(3)
                do b = 1, n_inside(2)
                    do a = 1, n_inside(1)
                        x0 = lattice_position([a, b, c])
                        d_min = body_distance(x0)
                        if (d_min >= reach) then
                            volume = volume + 1.0_wp
                            cycle
                        end if
                        if (d_min <= -reach) cycle
                        inside_count = 0
                        do sc = 1, n_sub(3)
                            do sb = 1, n_sub(2)
                                do sa = 1, n_sub(1)
                                    y = x0 + cfg%domain%dx * ((real([sa, sb, sc], wp) - &
                                        0.5_wp) / real(n_sub, wp) - 0.5_wp)
                                    y(cfg%domain%dimension + 1:) = x0(cfg%domain%dimension + 1:)
                                    if (body_distance(y) < 0.0_wp) inside_count = inside_count + 1
                                end do
                            end do
                        end do
                        volume = volume + 1.0_wp &
                            - real(inside_count, wp) / real(product(n_sub), wp)
                    end do
                end do
            end do
            volume = volume * cfg%domain%dx**cfg%domain%dimension
        end function fluid_volume

        !> Signed distance to the nearest body (not the box faces).
        real(wp) function body_distance(x) result(d)
            real(wp), intent(in) :: x(3)
            integer :: k
            d = huge(1.0_wp)
            do k = 1, size(solids%list)
                if (solids%list(k)%shape /= SOLID_PLANE) &
                    d = min(d, solid_distance(solids%list(k), x))
            end do
        end function body_distance

        function lattice_position(ix) result(x)
            integer, intent(in) :: ix(3)
            real(wp) :: x(3)
            x = 0.0_wp
            x(1:cfg%domain%dimension) = cfg%domain%box_lo(1:cfg%domain%dimension) + &
                (real(ix(1:cfg%domain%dimension), wp) - 0.5_wp) * cfg%domain%dx
        end function lattice_position

        subroutine add_particle(x, id, kind, wall_normal, wall_distance, velocity, solid_index)
            real(wp), intent(in) :: x(3), wall_normal(3), wall_distance, velocity(3)
            integer(i8), intent(in) :: id
            integer, intent(in) :: kind, solid_index
            integer :: n
            n = p%n_owned + 1
            call particles_reserve(p, n)
            p%x(:, n) = x
            p%v(:, n) = velocity
            p%rho(n) = cfg%fluid%rho0
            p%p(n) = eos_pressure(phys%eos, cfg%fluid%rho0, phys%rho0, phys%c, phys%gamma) + &
                phys%background_pressure
            p%m(n) = mass
            p%h(n) = phys%kernel%h
            p%e(n) = 0.0_wp
            p%dvdt(:, n) = 0.0_wp; p%drhodt(n) = 0.0_wp; p%dedt(n) = 0.0_wp
            p%x_old(:, n) = x; p%v_old(:, n) = velocity
            p%rho_old(n) = cfg%fluid%rho0; p%e_old(n) = 0.0_wp
            if (p%with_strain) p%strain(:, n) = 0.0_wp
            p%wall_normal(:, n) = wall_normal
            p%wall_distance(n) = wall_distance
            p%id(n) = id
            p%kind(n) = kind
            p%level(n) = 0
            p%parity(n) = 0
            p%solid(n) = solid_index
            p%n_owned = n
            p%n_total = n
        end subroutine add_particle

        !> Sites on each wall plane at the tangential lattice positions (corners skipped), then
        !> on each body's surface (body_surface_sites).
        subroutine add_type1_layers(id_base)
            integer(i8), intent(in) :: id_base
            integer :: s, ax, t1, t2, a, b, na, nb
            integer(i8) :: id
            real(wp) :: x(3)
            id = id_base + 1000000000_i8   ! clear of every fluid id
            do s = 1, size(solids%list)
                if (solids%list(s)%face == 0) cycle   ! a body: below
                associate (plane => solids%list(s))
                    ax = (plane%face + 1) / 2
                    t1 = merge(2, 1, ax == 1)
                    t2 = 6 - ax - t1
                    na = n_inside(t1)
                    nb = 1
                    if (cfg%domain%dimension == 3) nb = n_inside(t2)
                    do b = 1, nb
                        do a = 1, na
                            id = id + 1
                            x = 0.0_wp
                            x(ax) = plane%point(ax)
                            x(t1) = cfg%domain%box_lo(t1) + (real(a, wp) - 0.5_wp) * &
                                cfg%domain%dx
                            if (cfg%domain%dimension == 3) x(t2) = cfg%domain%box_lo(t2) + &
                                (real(b, wp) - 0.5_wp) * cfg%domain%dx
                            if (domain_owner(domain, x) /= domain%rank) cycle
                            if (.not. wanted(x, KIND_WALL)) cycle
                            call add_particle(x, id, KIND_WALL, plane%normal, 0.0_wp, &
                                plane%velocity, s)
                        end do
                    end do
                end associate
            end do
            do s = 1, size(solids%list)
                if (solids%list(s)%face /= 0) cycle
                call add_body_surface(s, id)
            end do
        end subroutine add_type1_layers

        subroutine add_body_surface(s, id)
            integer, intent(in) :: s
            integer(i8), intent(inout) :: id
            real(wp), allocatable :: xs(:, :), ns(:, :)
            real(wp) :: x(3), length
            integer :: q, ax
            call body_surface_sites(solids%list(s), cfg%domain%dx, cfg%domain%box_lo, &
                cfg%domain%box_hi, xs, ns)
            do q = 1, size(xs, 2)
                id = id + 1
                x = xs(:, q)
                do ax = 1, cfg%domain%dimension   ! into the box across periodic faces
                    if (.not. cfg%domain%is_periodic(ax)) cycle
                    length = cfg%domain%box_hi(ax) - cfg%domain%box_lo(ax)
                    x(ax) = cfg%domain%box_lo(ax) + modulo(x(ax) - cfg%domain%box_lo(ax), length)
                end do
                if (domain_owner(domain, x) /= domain%rank) cycle
                if (.not. wanted(x, KIND_WALL)) cycle
                call add_particle(x, id, KIND_WALL, ns(:, q), 0.0_wp, &
                    solid_velocity(solids%list(s), x), s)
            end do
        end subroutine add_body_surface
    end subroutine create_lattice_particles
end module sph_initial
