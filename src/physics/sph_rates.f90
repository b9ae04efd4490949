!> The SPH right-hand sides (thesis ch. 2, with Morris et al. 1997 for low Reynolds number):
!>   continuity   d rho_i/dt = sum_j m_j v_ij . grad_i W_ij
!>   momentum     d v_i/dt   = - sum_j m_j (p_i/rho_i^2 + p_j/rho_j^2) grad_i W_ij + viscous + F
!>   energy       d e_i/dt   = 1/2 sum_j m_j (p_i/rho_i^2 + p_j/rho_j^2) v_ij . grad_i W_ij
!>                             + viscous heating
!> Viscous term: Morris' laminar form
!>   sum_j m_j (mu_i + mu_j) r_ij . grad_i W_ij / (rho_i rho_j (r_ij^2 + 0.01 h^2)) v_ij
!> or the strain-rate form of thesis eqs. 2.15-2.16 (with the index typos corrected: the
!> stress divergence contracts grad W over beta, and v_ji multiplies grad W in eq. 2.16).
!> Printed eq. 2.14 carries a stray rho_i and 2.17 lacks v_ij; the forms above are the
!> standard, dimensionally consistent ones.
!> Loops run over the owned particles i with neighbours j among owned, ghost and mirror
!> particles. Every pair term is antisymmetric in i and j, so momentum is conserved to
!> round-off. No MPI here: the driver refreshes ghosts between the stages.
!> Resolution levels: with `level` given, a routine updates the owned particles of that level
!> only, with phys the physics of that level (its kernel); the neighbour list pairs particles
!> of one level only, so each level is a complete SPH system of its own (real and virtual
!> particles, walls of its spacing). Virtual particles (KIND_VIRTUAL) count as fluid.
!> Transport-velocity formulation (phys%transport_velocity; Adami, Hu & Adams 2013, eqs. 7-8
!> with V = m/rho): the momentum equation becomes
!>   dv_i/dt = 1/m_i sum_j (V_i^2 + V_j^2) [-pt_ij grad W + 1/2 (A_i + A_j) . grad W] + visc + F
!> with pt_ij = (rho_j p_i + rho_i p_j)/(rho_i + rho_j) and A = rho v (vt - v); the background
!> pressure p_b acts only on the transport velocity vt, through
!>   a_b,i = -p_b/m_i sum_j (V_i^2 + V_j^2) grad W   (dvdt_background),
!> which vanishes on a regular lattice and pushes particles from crowded towards sparse
!> places otherwise. Wall particles (with the fluid's extrapolated pressure) enter the
!> pressure and background sums, not the A term (A of a wall is zero; as PySPH does). The
!> viscous term stays Morris' (equal to Adami's for uniform density), with its walls.
!> Morris walls need the distances of the fluid and the wall particle from the wall; with the
!> solids given, a curved body's are measured as Morris et al. (1997, sec. 5) do: the fluid
!> particle's is the body's signed distance at it, the wall particle's the distance behind the
!> tangent plane at the surface point nearest the fluid particle.
module sph_rates
    use sph_kinds, only: wp
    use sph_particles, only: particles_t, KIND_FLUID, KIND_WALL, KIND_VIRTUAL, moves_with_flow
    use sph_cell_list, only: neighbour_list_t
    use sph_physics, only: physics_t, VISCOSITY_MORRIS, VISCOSITY_STRAIN_RATE, WALLS_MORRIS, &
        WALLS_REPULSIVE, WALLS_REPULSIVE_MIRROR, WALL_PRESSURE_CONTINUITY, &
        QUADRATIC_WALL_GAIN
    use sph_eos, only: eos_pressure_many, eos_density
    use sph_solids, only: solids_t, solid_distance, solid_normal, SOLID_PLANE
    implicit none
    private
    public :: update_pressure, extrapolate_wall_density, compute_summation_density
    public :: compute_strain_rate, compute_rates
    public :: local_max_speed, local_motion_maxima, morris_beta, release_rates_scratch
    public :: shepard_density

    !> strain(6) components: xx, yy, zz, xy, xz, yz
    integer, parameter :: voigt(3, 3) = reshape([1, 4, 5, 4, 2, 6, 5, 6, 3], [3, 3])

    !> compute_rates' arrays over all particles, kept from call to call and grown when short:
    !> allocated afresh at every call, their ~60 bytes per particle came as new pages from
    !> the system at 10^6 particles (page faults and zeroing in every rate evaluation). The
    !> driver releases them at each rebuild (release_rates_scratch), so they do not add to
    !> the memory peaks of migration, rebuilds and output.
    type :: rates_scratch_t
        real(wp), allocatable :: state(:, :)
        logical, allocatable :: paired(:), flows(:)
        real(wp), allocatable :: filtered(:)    !< shepard_density's new densities
        !> the rows of the list of generation half_generation (for half_owned owned
        !> particles) without the partners evaluated from the other side (halve_rows):
        !> half_index(half_start(i):half_start(i + 1) - 1)
        integer, allocatable :: half_start(:), half_index(:)
        integer :: half_generation = -1, half_owned = -1
    end type rates_scratch_t
    type(rates_scratch_t), save :: kept_scratch

    !> compute_rates finds the rows of this many particles, then evaluates dW/dr and the
    !> factors of all their pairs in one batch, then their pair terms.
    integer, parameter :: RATES_BLOCK = 32

contains

    !> Pressure from density by the equation of state (plus the background pressure), for
    !> particles first..last.
    subroutine update_pressure(phys, p, first, last)
        type(physics_t), intent(in) :: phys
        type(particles_t), intent(inout) :: p
        integer, intent(in) :: first, last
        call eos_pressure_many(phys%eos, p%rho(first:last), phys%rho0, phys%c, phys%gamma, &
            phys%background_pressure, p%p(first:last))
    end subroutine update_pressure

    !> Density of owned Morris wall particles from the fluid around them (Adami, Hu & Adams
    !> 2012, eq. 27): the wall pressure is the kernel-weighted fluid pressure plus the
    !> hydrostatic part of the body force F (walls do not accelerate),
    !>   p_w = (sum_f p_f W_wf + F . sum_f rho_f (x_w - x_f) W_wf) / sum_f W_wf,
    !> and the density is the equation of state's for that pressure. The wall then pushes
    !> back exactly as hard as the fluid next to it presses, wherever walls of different
    !> velocities meet, instead of carrying a density of its own that the fluid can squeeze
    !> into a corner. A wall particle without fluid in reach takes the rest density.
    !> The fluid pressures must be current (update_pressure) on entry.
    subroutine extrapolate_wall_density(phys, p, nl, level)
        type(physics_t), intent(in) :: phys
        type(particles_t), intent(inout) :: p
        type(neighbour_list_t), intent(in) :: nl
        integer, intent(in), optional :: level
        integer :: i, k, j
        real(wp) :: d(3), w, sum_w, sum_p, support2
        support2 = phys%kernel%support**2
        do i = 1, p%n_owned
            if (p%kind(i) /= KIND_WALL) cycle
            if (other_level(p, i, level)) cycle
            sum_w = 0.0_wp
            sum_p = 0.0_wp
            do k = nl%start(i), nl%start(i + 1) - 1
                j = nl%index(k)
                if (.not. moves_with_flow(p%kind(j))) cycle
                d = p%x(:, i) - p%x(:, j)
                if (dot_product(d, d) >= support2) cycle
                w = phys%kernel%w(norm2(d))
                sum_w = sum_w + w
                sum_p = sum_p + (p%p(j) + p%rho(j) * dot_product(phys%body_force, d)) * w
            end do
            if (sum_w > 0.0_wp) then
                p%rho(i) = eos_density(phys%eos, sum_p / sum_w - phys%background_pressure, &
                    phys%rho0, phys%c, phys%gamma)
            else
                p%rho(i) = phys%rho0
            end if
        end do
    end subroutine extrapolate_wall_density

    !> Particle i is not of `level` (when given): a per-level call leaves it alone.
    pure logical function other_level(p, i, level)
        type(particles_t), intent(in) :: p
        integer, intent(in) :: i
        integer, intent(in), optional :: level
        other_level = .false.
        if (present(level)) other_level = p%level(i) /= level
    end function other_level

    !> Type-1 boundary particles only repel; they take no part in the SPH sums.
    pure logical function repulsive_only(phys, kind_j)
        type(physics_t), intent(in) :: phys
        integer, intent(in) :: kind_j
        repulsive_only = kind_j == KIND_WALL .and. (phys%walls == WALLS_REPULSIVE .or. &
            phys%walls == WALLS_REPULSIVE_MIRROR)
    end function repulsive_only

    !> Morris' factor for the wall particle's extrapolated velocity: the relative velocity used
    !> in the viscous term is beta (v_i - v_wall), beta = min(beta_max, 1 + d_wall / d_fluid).
    pure real(wp) function morris_beta(d_fluid, d_wall, beta_max)
        real(wp), intent(in) :: d_fluid, d_wall, beta_max
        if (d_fluid > 0.0_wp) then
            morris_beta = min(beta_max, 1.0_wp + d_wall / d_fluid)
        else
            morris_beta = beta_max
        end if
    end function morris_beta

    !> Distance of point xi in front of the wall plane of wall particle j.
    pure real(wp) function distance_to_wall(p, xi, j)
        type(particles_t), intent(in) :: p
        real(wp), intent(in) :: xi(3)
        integer, intent(in) :: j
        distance_to_wall = dot_product(p%wall_normal(:, j), xi - p%x(:, j)) - p%wall_distance(j)
    end function distance_to_wall

    !> Morris' beta for fluid particle i and wall particle j (wall_depths' distances).
    pure real(wp) function wall_beta(phys, p, i, j, solids)
        type(physics_t), intent(in) :: phys
        type(particles_t), intent(in) :: p
        integer, intent(in) :: i, j
        type(solids_t), intent(in), optional :: solids
        real(wp) :: d_fluid, d_wall
        call wall_depths(p, i, j, d_fluid, d_wall, solids)
        wall_beta = morris_beta(d_fluid, d_wall, phys%beta_max)
    end function wall_beta

    !> Distances of fluid particle i in front of and wall particle j behind the wall. A plane
    !> wall (or no solids given) uses the plane through j stored with it; a body uses its
    !> exact distance at x_i (d_fluid) and the depth of x_j behind the tangent plane of the
    !> surface point nearest x_i (d_wall), which is >= 0 for the convex bodies of sph_solids.
    pure subroutine wall_depths(p, i, j, d_fluid, d_wall, solids)
        type(particles_t), intent(in) :: p
        integer, intent(in) :: i, j
        real(wp), intent(out) :: d_fluid, d_wall
        type(solids_t), intent(in), optional :: solids
        real(wp) :: n(3)
        logical :: curved
        curved = .false.
        if (present(solids)) then
            if (p%solid(j) > 0) curved = solids%list(p%solid(j))%shape /= SOLID_PLANE
        end if
        if (curved) then
            associate (body => solids%list(p%solid(j)))
                d_fluid = solid_distance(body, p%x(:, i))
                n = solid_normal(body, p%x(:, i))
                d_wall = dot_product(n, p%x(:, i) - p%x(:, j)) - d_fluid
            end associate
        else
            d_fluid = distance_to_wall(p, p%x(:, i), j)
            d_wall = p%wall_distance(j)
        end if
    end subroutine wall_depths

    !> The longest neighbour list of an owned particle (the size of the partner scratch).
    pure integer function longest_list(p, nl) result(m)
        type(particles_t), intent(in) :: p
        type(neighbour_list_t), intent(in) :: nl
        m = 0
        if (p%n_owned > 0) m = maxval(nl%start(2:p%n_owned + 1) - nl%start(1:p%n_owned))
    end function longest_list

    !> The partners of owned particle i that its density takes (all but repulsive-only
    !> walls) within the kernel's support: m of them, at distances r(1:m), indices
    !> partner(1:m), in the list's order. r and partner hold longest_list entries.
    pure subroutine support_partners(phys, p, nl, i, m, r, partner)
        type(physics_t), intent(in) :: phys
        type(particles_t), intent(in) :: p
        type(neighbour_list_t), intent(in) :: nl
        integer, intent(in) :: i
        integer, intent(out) :: m
        real(wp), intent(inout) :: r(:)
        integer, intent(inout) :: partner(:)
        integer :: k, j
        real(wp) :: d(3), r2, support2
        support2 = phys%kernel%support**2
        m = 0
        do k = nl%start(i), nl%start(i + 1) - 1
            j = nl%index(k)
            if (repulsive_only(phys, p%kind(j))) cycle
            d(1) = p%x(1, i) - p%x(1, j)
            d(2) = p%x(2, i) - p%x(2, j)
            d(3) = p%x(3, i) - p%x(3, j)
            r2 = d(1)**2 + d(2)**2 + d(3)**2
            if (r2 >= support2) cycle
            m = m + 1
            r(m) = sqrt(r2)
            partner(m) = j
        end do
    end subroutine support_partners

    !> rho_i = sum_j m_j W_ij (self included) for owned fluid particles; walls keep theirs.
    !> The partners within the support first, then W of all of them in one kernel call, as in
    !> shepard_density (one call per pair, through the kernel's select, took 0.11 s for 4e5
    !> particles in 2D, two thirds of a time step of them; a remesh makes up to 9 of these).
    subroutine compute_summation_density(phys, p, nl, level)
        type(physics_t), intent(in) :: phys
        type(particles_t), intent(inout) :: p
        type(neighbour_list_t), intent(in) :: nl
        integer, intent(in), optional :: level
        integer :: i, k, m
        real(wp) :: s, w0
        real(wp), allocatable :: r(:), w(:)
        integer, allocatable :: partner(:)
        w0 = phys%kernel%w(0.0_wp)
        m = longest_list(p, nl)
        allocate(r(m), w(m), partner(m))
        do i = 1, p%n_owned
            if (.not. moves_with_flow(p%kind(i))) cycle
            if (other_level(p, i, level)) cycle
            call support_partners(phys, p, nl, i, m, r, partner)
            call phys%kernel%w_many(r(1:m), w(1:m))
            ! (summed in the list's order, as before)
            s = p%m(i) * w0
            do k = 1, m
                s = s + p%m(partner(k)) * w(k)
            end do
            p%rho(i) = s
        end do
    end subroutine compute_summation_density

    !> Shepard filter of the density of owned real fluid particles (of one level):
    !>   rho_i = sum_j m_j W_ij / sum_j (m_j / rho_j) W_ij   (self included)
    !> over the partners the summation density takes (real, virtual and wall particles). A
    !> uniform density is kept exactly on any arrangement, where the kernel sum alone (and
    !> the continuity equation, which follows it) changes as rows of a lattice slide past
    !> each other (physics.md, "Known behaviour"). Walls and virtual particles keep theirs.
    !> also: the same change is added to it (Verlet's half-kicked densities, rho_old).
    subroutine shepard_density(phys, p, nl, level, also)
        type(physics_t), intent(in) :: phys
        type(particles_t), intent(inout) :: p
        type(neighbour_list_t), intent(in) :: nl
        integer, intent(in), optional :: level
        real(wp), intent(inout), optional :: also(:)
        integer :: i, m
        real(wp) :: w0, num, den
        real(wp), allocatable :: r(:), w(:), mass(:), volume(:)
        integer, allocatable :: partner(:)
        w0 = phys%kernel%w(0.0_wp)
        m = longest_list(p, nl)
        allocate(r(m), w(m), mass(m), volume(m), partner(m))
        ! the new densities in a kept array (no fresh pages at every step)
        if (allocated(kept_scratch%filtered)) then
            if (size(kept_scratch%filtered) < p%n_owned) deallocate(kept_scratch%filtered)
        end if
        if (.not. allocated(kept_scratch%filtered)) &
            allocate(kept_scratch%filtered(max(p%n_owned, 1)))
        associate (filtered => kept_scratch%filtered)
            do i = 1, p%n_owned
                filtered(i) = p%rho(i)
                if (p%kind(i) /= KIND_FLUID) cycle
                if (other_level(p, i, level)) cycle
                call support_partners(phys, p, nl, i, m, r, partner)
                mass(1:m) = p%m(partner(1:m))
                volume(1:m) = p%m(partner(1:m)) / p%rho(partner(1:m))
                call phys%kernel%w_many(r(1:m), w(1:m))
                num = p%m(i) * w0 + sum(mass(1:m) * w(1:m))
                den = p%m(i) / p%rho(i) * w0 + sum(volume(1:m) * w(1:m))
                filtered(i) = num / den
            end do
            if (present(also)) also(1:p%n_owned) = also(1:p%n_owned) + &
                (filtered(1:p%n_owned) - p%rho(1:p%n_owned))
            p%rho(1:p%n_owned) = filtered(1:p%n_owned)
        end associate
    end subroutine shepard_density

    !> Strain rate (thesis eq. 2.16, corrected) of owned particles:
    !> eps^ab = sum_j m_j/rho_j (v_ji^b dW/dx^a + v_ji^a dW/dx^b)
    !>          - 2/3 delta^ab sum_j m_j/rho_j v_ji . grad W
    !> (the 2/3 of a three-dimensional fluid is kept in 2D: plane flow of a real fluid).
    subroutine compute_strain_rate(phys, p, nl, solids, level)
        type(physics_t), intent(in) :: phys
        type(particles_t), intent(inout) :: p
        type(neighbour_list_t), intent(in) :: nl
        type(solids_t), intent(in), optional :: solids   !< for Morris walls of curved bodies
        integer, intent(in), optional :: level
        integer :: i, k, j, a, b
        real(wp) :: d(3), r, grad(3), vji(3), g(3, 3), div, beta
        do i = 1, p%n_owned
            if (other_level(p, i, level)) cycle
            g = 0.0_wp
            do k = nl%start(i), nl%start(i + 1) - 1
                j = nl%index(k)
                if (repulsive_only(phys, p%kind(j))) cycle
                d = p%x(:, i) - p%x(:, j)
                r = norm2(d)
                if (r <= 0.0_wp) cycle
                grad = d / r * phys%kernel%dwdr(r)
                vji = p%v(:, j) - p%v(:, i)
                if (p%kind(j) == KIND_WALL .and. moves_with_flow(p%kind(i)) .and. &
                    phys%walls == WALLS_MORRIS) then
                    beta = wall_beta(phys, p, i, j, solids)
                    vji = -beta * (p%v(:, i) - p%v(:, j))
                end if
                do b = 1, 3
                    g(:, b) = g(:, b) + p%m(j) / p%rho(j) * vji(b) * grad(:)
                end do
            end do
            ! g(a, b) = sum m/rho v^b dW/dx^a
            div = g(1, 1) + g(2, 2) + g(3, 3)
            do b = 1, 3
                do a = b, 3
                    p%strain(voigt(a, b), i) = g(a, b) + g(b, a)
                end do
                p%strain(b, i) = p%strain(b, i) - 2.0_wp / 3.0_wp * div
            end do
        end do
    end subroutine compute_strain_rate

    !> d rho/dt, d v/dt and d e/dt of every owned particle.
    !> With wall_forces (3, 2, number of solids), the force the fluid exerts on each solid is
    !> added: (:, 1, s) pressure (and repulsion), (:, 2, s) viscous; it is minus the pair
    !> terms its wall (or mirror) particles give the owned fluid particles, so the fluid's
    !> total m dv/dt plus the forces on all solids equals the body force on the fluid.
    !> Each pair of owned fluid particles is evaluated once, from its lower index, and its
    !> terms go to both (they are antisymmetric, so d v_j gets minus what d v_i gets, with
    !> the masses swapped): half the pair work of visiting every pair from both sides. Pairs
    !> with ghosts, walls and mirrors are evaluated from the owned fluid side only, as the
    !> other side is owned by another rank or follows its own rule.
    subroutine compute_rates(phys, p, nl, solids, wall_forces, level)
        type(physics_t), intent(in) :: phys
        type(particles_t), intent(inout) :: p
        type(neighbour_list_t), intent(in) :: nl
        type(solids_t), intent(in), optional :: solids   !< for Morris walls of curved bodies
        real(wp), intent(inout), optional :: wall_forces(:, :, :)
        integer, intent(in), optional :: level
        integer :: i, k, j, a, s, m, n_near, n_fluid, n_other, b, i0, i1, n_block
        real(wp) :: d(3), r2, grad(3), vij(3), vvisc(3), pterm, coeff, beta, xi(3)
        real(wp) :: drho, dv(3), de, rho_i, mu_i, q, sterm(3), eps_i(3, 3), eps_j(3, 3)
        real(wp) :: support2, m_i, m_j, vg, f(3), e_pair, visc_scale
        real(wp) :: vol2, pt, fp(3), fb(3), dvb(3), a_i(3), a_j(3), p_b
        integer, allocatable :: near(:)   !< the neighbours of i within the support
        !> a block's rows in near(:) and alike: i's are b + 1 .. b + n_near (fluid first,
        !> n_fluid of them), with b = row_base(i - i0 + 1), n_near = row_count(...)
        integer :: row_base(RATES_BLOCK), row_count(RATES_BLOCK), row_fluid(RATES_BLOCK)
        integer, allocatable :: w_near(:)  !< wall_density_rate's partners
        real(wp), allocatable :: w_d(:, :), w_r(:), w_r2(:), w_dwdr(:)
        real(wp), allocatable :: d_near(:, :), r_near(:), r2_near(:), dwdr_near(:)
        real(wp), allocatable :: grad_near(:), visc_near(:)
        real(wp), allocatable :: state(:, :)  !< v, m, p/rho^2, 1/rho of all particles
        logical, allocatable :: paired(:)     !< owned fluid of this level: pair terms shared
        logical, allocatable :: flows(:)      !< fluid, real or virtual (moves_with_flow)
        integer, allocatable :: other(:)      !< the partners of i that are not fluid
        integer, allocatable :: all_near(:)   !< wall_curvature: all partners of i
        real(wp), allocatable :: all_r(:), all_r2(:), all_dwdr(:)
        logical :: repulsive_walls, morris_walls, strain_viscosity, tvf, fast_fluid, fast_walls
        logical, allocatable :: curved(:)     !< solid s (1..) is not a plane
        real(wp), allocatable :: vol_sq(:)   !< transport velocity: (m/rho)^2 of all particles
        logical :: quadratic_walls            !< Morris walls with wall_extrapolation = quadratic
        logical :: energy                     !< the energy's rate wanted (else dedt stays 0)
        real(wp) :: curv_i(3)                 !< half of i's velocity Laplacian (wall_curvature)
        real(wp) :: d_f, d_w

        support2 = phys%kernel%support**2
        repulsive_walls = phys%walls == WALLS_REPULSIVE .or. phys%walls == WALLS_REPULSIVE_MIRROR
        morris_walls = phys%walls == WALLS_MORRIS
        quadratic_walls = morris_walls .and. phys%wall_quadratic .and. phys%nu > 0.0_wp
        strain_viscosity = phys%viscosity == VISCOSITY_STRAIN_RATE
        visc_scale = phys%nu * phys%viscous_scale
        energy = phys%energy_equation
        k = 0
        if (p%n_owned > 0) k = maxval(nl%start(2:p%n_owned + 1) - nl%start(1:p%n_owned))
        allocate(w_near(k), w_d(3, k), w_r(k), w_r2(k), w_dwdr(k), other(k))
        if (quadratic_walls) allocate(all_near(k), all_r(k), all_r2(k), all_dwdr(k))
        k = k * RATES_BLOCK
        allocate(near(k), d_near(3, k), r_near(k), r2_near(k), dwdr_near(k), grad_near(k), &
            visc_near(k))
        ! what a pair reads of j, packed: one or two cache lines per neighbour
        ! of the particles of this level only: the list pairs no others (half the work of a
        ! two-level run, evaluated level by level)
        ! (the passes over all particles below write the components out and test the kinds
        ! of moves_with_flow inline: gfortran neither knows the arrays' leading extent nor
        ! inlines across modules, and the loops cost more than their work)
        call take_scratch(p%n_total, state, paired, flows)
        if (.not. present(level)) then
            call fill_pair_state(p%n_total, p%n_owned, p%v, p%m, p%p, p%rho, p%kind, state, &
                flows, paired, p%drhodt, p%dvdt, p%dedt)
        else
            do j = 1, p%n_total
                paired(j) = .false.
                if (other_level(p, j, level)) cycle
                state(1, j) = p%v(1, j)
                state(2, j) = p%v(2, j)
                state(3, j) = p%v(3, j)
                state(4, j) = p%m(j)
                state(5, j) = p%p(j) / p%rho(j)**2
                state(6, j) = 1.0_wp / p%rho(j)
                flows(j) = p%kind(j) == KIND_FLUID .or. p%kind(j) == KIND_VIRTUAL
                ! the rates of ghosts too: morris_fluid_pairs adds j's terms straight to
                ! j's rates, with no test (a ghost's are this rank's partial sums)
                p%drhodt(j) = 0.0_wp
                p%dvdt(1, j) = 0.0_wp
                p%dvdt(2, j) = 0.0_wp
                p%dvdt(3, j) = 0.0_wp
                p%dedt(j) = 0.0_wp
            end do
            do i = 1, p%n_owned
                if (other_level(p, i, level)) cycle
                paired(i) = flows(i)
            end do
        end if
        call halve_rows(p, nl)
        tvf = phys%transport_velocity
        p_b = phys%transport_pressure
        ! the terms morris_fluid_pairs evaluates: Morris' viscosity, no transport velocity
        fast_fluid = phys%viscosity == VISCOSITY_MORRIS .and. .not. tvf
        ! and the terms morris_wall_pairs evaluates: Morris' walls besides
        fast_walls = fast_fluid .and. morris_walls
        allocate(curved(0:0), source=.false.)
        if (present(solids)) then
            if (allocated(solids%list)) then
                deallocate(curved)
                allocate(curved(0:size(solids%list)), source=.false.)
                curved(1:) = solids%list(:)%shape /= SOLID_PLANE
            end if
        end if
        if (tvf) then
            allocate(vol_sq(p%n_total))
            vol_sq(:) = (p%m(1:p%n_total) / p%rho(1:p%n_total))**2
            do i = 1, p%n_owned
                if (.not. other_level(p, i, level)) p%dvdt_background(:, i) = 0.0_wp
            end do
        end if

        associate (half_start => kept_scratch%half_start, half_index => kept_scratch%half_index)
        do i0 = 1, p%n_owned, RATES_BLOCK
            i1 = min(i0 + RATES_BLOCK - 1, p%n_owned)
            ! the rows of the block's fluid particles: the pairs within the support not yet
            ! evaluated from the other side, every row after the one before. With Morris'
            ! viscosity and without the transport velocity a row's fluid partners come first
            ! (n_fluid of them) and go through morris_fluid_pairs; the others (walls, mirrors)
            ! follow in list order through the general loop.
            n_block = 0
            do i = i0, i1
                b = i - i0 + 1
                row_base(b) = n_block
                row_count(b) = 0
                row_fluid(b) = 0
                if (other_level(p, i, level)) cycle
                if (.not. (p%kind(i) == KIND_FLUID .or. p%kind(i) == KIND_VIRTUAL)) cycle
                xi = p%x(:, i)
                n_near = n_block
                call find_row(xi, half_index(half_start(i):half_start(i + 1) - 1), &
                    half_start(i + 1) - half_start(i), p%x, flows, fast_fluid, support2, near, &
                    d_near, r2_near, n_near, other, n_other)
                row_fluid(b) = merge(n_near - n_block, 0, fast_fluid)
                do m = 1, n_other
                    j = other(m)
                    n_near = n_near + 1
                    near(n_near) = j
                    d_near(:, n_near) = xi - p%x(:, j)
                    r2_near(n_near) = sum(d_near(:, n_near)**2)
                end do
                row_count(b) = n_near - n_block
                n_block = n_near
            end do
            ! dW/dr of the whole block in one kernel call, and grad W = d * grad_near, Morris'
            ! viscous factor r dW/dr / (r^2 + eta^2): loops long enough to vectorise well (one
            ! particle's row is about ten pairs, the vector tails cost as much as the vectors)
            r_near(1:n_block) = sqrt(r2_near(1:n_block))
            call phys%kernel%dwdr_many(r_near(1:n_block), dwdr_near(1:n_block))
            do m = 1, n_block
                grad_near(m) = dwdr_near(m) / r_near(m)
                visc_near(m) = r_near(m) * dwdr_near(m) / (r2_near(m) + phys%eta2)
            end do
            do i = i0, i1
                if (other_level(p, i, level)) cycle
                select case (p%kind(i))
                case (KIND_WALL)
                    if (phys%walls == WALLS_MORRIS .and. &
                        phys%wall_pressure == WALL_PRESSURE_CONTINUITY) call wall_density_rate(i)
                    cycle
                case (KIND_FLUID, KIND_VIRTUAL)
                case default
                    cycle
                end select
                rho_i = p%rho(i)
                m_i = state(4, i)
                mu_i = rho_i * phys%nu
                if (strain_viscosity) eps_i = tensor(p%strain(:, i))
                drho = 0.0_wp
                dv = 0.0_wp
                de = 0.0_wp
                dvb = 0.0_wp
                xi = p%x(:, i)
                b = row_base(i - i0 + 1)
                n_near = row_count(i - i0 + 1)
                n_fluid = row_fluid(i - i0 + 1)
                ! A_i = rho_i v_i (vt_i - v_i): (A_i . grad W)_a = a_i(a) (dv_transport_i . grad W)
                if (tvf) a_i = rho_i * p%v(:, i)
                curv_i = 0.0_wp
                if (quadratic_walls) then
                    if (any(p%kind(near(b + n_fluid + 1:b + n_near)) == KIND_WALL)) &
                        call wall_curvature()
                end if
                if (n_fluid > 0) call morris_fluid_pairs(n_fluid, near(b + 1:), &
                    d_near(:, b + 1:), grad_near(b + 1:), visc_near(b + 1:), i, visc_scale, &
                    state, energy, drho, dv, de, p%drhodt, p%dvdt, p%dedt)
                ! Morris' walls: every other partner is a wall particle (morris_wall_pairs)
                if (fast_walls) call morris_wall_pairs(b + n_fluid + 1, b + n_near)
                do m = b + merge(n_near + 1, n_fluid + 1, fast_walls), b + n_near
                    j = near(m)
                    d = d_near(:, m)
                    r2 = r2_near(m)
                    if (repulsive_walls .and. p%kind(j) == KIND_WALL) then
                        if (r_near(m) < phys%repulsive_r0) then
                            q = phys%repulsive_r0 / r_near(m)
                            f = phys%repulsive_d * (q**phys%repulsive_n1 - q**phys%repulsive_n2) &
                                * d / r2
                            dv = dv + f
                            s = force_slot(j)
                            if (s > 0) wall_forces(:, 1, s) = wall_forces(:, 1, s) - m_i * f
                        end if
                        cycle
                    end if
                    m_j = state(4, j)
                    grad = d * grad_near(m)
                    vij = p%v(:, i) - state(1:3, j)
                    vg = dot_product(vij, grad)
                    pterm = state(5, i) + state(5, j)
                    ! per unit mass of the partner: f is the force on i, e_pair its heating
                    if (tvf) then
                        ! per unit mass of both: (V_i^2 + V_j^2) / (m_i m_j)
                        vol2 = (vol_sq(i) + vol_sq(j)) / (m_i * m_j)
                        pt = (p%rho(j) * p%p(i) + rho_i * p%p(j)) / (rho_i + p%rho(j))
                        fp = -(vol2 * pt) * grad
                        fb = -(vol2 * p_b) * grad
                        f = fp
                        if (p%kind(j) /= KIND_WALL) then
                            a_j = p%rho(j) * state(1:3, j)
                            f = f + (0.5_wp * vol2) * (a_i * dot_product(p%dv_transport(:, i), &
                                grad) + a_j * dot_product(p%dv_transport(:, j), grad))
                        end if
                        e_pair = 0.5_wp * vol2 * pt * vg
                        dvb = dvb + m_j * fb
                        if (paired(j)) p%dvdt_background(:, j) = p%dvdt_background(:, j) - m_i * fb
                    else
                        f = -pterm * grad
                        e_pair = 0.5_wp * pterm * vg
                    end if
                    if (strain_viscosity) then
                        eps_j = tensor(p%strain(:, j))
                        do a = 1, 3
                            sterm(a) = dot_product(mu_i * eps_i(a, :) / rho_i**2 + &
                                phys%nu * eps_j(a, :) * state(6, j), grad)
                        end do
                        f = f + sterm
                    else
                        ! Morris: (mu_i + mu_j) / (rho_i rho_j) = nu (1/rho_i + 1/rho_j)
                        coeff = visc_scale * (state(6, i) + state(6, j)) * visc_near(m)
                        vvisc = vij
                        if (morris_walls .and. p%kind(j) == KIND_WALL) then
                            call wall_depths(p, i, j, d_f, d_w, solids)
                            beta = morris_beta(d_f, d_w, phys%beta_max)
                            ! the wall particle's velocity on the parabola (wall_curvature)
                            vvisc = beta * vij - curv_i * (d_w * (d_f + d_w))
                        end if
                        f = f + coeff * vvisc
                        e_pair = e_pair - 0.5_wp * coeff * dot_product(vvisc, vvisc)
                    end if
                    drho = drho + m_j * vg
                    dv = dv + m_j * f
                    de = de + m_j * e_pair
                    if (paired(j)) then
                        p%drhodt(j) = p%drhodt(j) + m_i * vg
                        p%dvdt(:, j) = p%dvdt(:, j) - m_i * f
                        if (energy) p%dedt(j) = p%dedt(j) + m_i * e_pair
                    else
                        s = force_slot(j)
                        if (s > 0 .and. tvf) then
                            wall_forces(:, 1, s) = wall_forces(:, 1, s) - m_i * m_j * fp
                            wall_forces(:, 2, s) = wall_forces(:, 2, s) - m_i * m_j * (f - fp)
                        else if (s > 0) then
                            wall_forces(:, 1, s) = wall_forces(:, 1, s) + m_i * m_j * pterm * grad
                            wall_forces(:, 2, s) = wall_forces(:, 2, s) - m_i * m_j * &
                                (f + pterm * grad)
                        end if
                    end if
                end do
                if (strain_viscosity) de = de + mu_i / (2.0_wp * rho_i) * sum(eps_i * eps_i)
                if (tvf) p%dvdt_background(:, i) = p%dvdt_background(:, i) + dvb
                ! i's rates already hold what the rows before handed on (pairs of owned
                ! fluid particles are evaluated from the lower index only): i is complete
                p%drhodt(i) = p%drhodt(i) + drho
                if (energy) p%dedt(i) = p%dedt(i) + de
                if (paired(i)) then
                    p%dvdt(1, i) = p%dvdt(1, i) + dv(1) + phys%body_force(1)
                    p%dvdt(2, i) = p%dvdt(2, i) + dv(2) + phys%body_force(2)
                    p%dvdt(3, i) = p%dvdt(3, i) + dv(3) + phys%body_force(3)
                else
                    p%dvdt(1, i) = p%dvdt(1, i) + dv(1)
                    p%dvdt(2, i) = p%dvdt(2, i) + dv(2)
                    p%dvdt(3, i) = p%dvdt(3, i) + dv(3)
                end if
            end do
        end do
        end associate
        call move_alloc(state, kept_scratch%state)
        call move_alloc(paired, kept_scratch%paired)
        call move_alloc(flows, kept_scratch%flows)

    contains

        !> Half the velocity Laplacian of owned fluid particle i next to Morris walls, the
        !> curvature c of the parabola u(n) = v_w + a n + c n^2 through the wall (n the
        !> distance from it) on which its wall partners' velocities lie:
        !>   v_i - v_j = beta (v_i - v_w) - c d_w (d_f + d_w)
        !> (Morris' linear extrapolation is c = 0). At a no-slip wall the tangential
        !> derivatives vanish, so c = (1/2) d2u/dn2 = lap(u) / 2: Morris' viscous sum over all
        !> of i's partners, A = nu lap(u), with the wall terms taken on the same parabola, is
        !> A = S - c K (S the sum with c = 0, K = sum m_j f_ij d_w (d_f + d_w) <= 0), solved for
        !> c = A / (2 nu) in closed form: A = S 2 nu / (2 nu + K), i's viscous term raised by
        !> the gain 2 nu / (2 nu + K), about 1.4 for the first row of a lattice at a plane
        !> wall, more for particles closer to it or between walls a few spacings apart. The
        !> gain is held at QUADRATIC_WALL_GAIN, which the viscous time step assumes.
        subroutine wall_curvature()
            integer :: kk, jj, nn, mm
            real(wp) :: dd(3), rr2, cc, s_sum(3), k_sum, dfl, dwl
            nn = 0
            do kk = nl%start(i), nl%start(i + 1) - 1
                jj = nl%index(kk)
                if (.not. (flows(jj) .or. p%kind(jj) == KIND_WALL)) cycle
                dd = xi - p%x(:, jj)
                rr2 = dd(1)**2 + dd(2)**2 + dd(3)**2
                if (rr2 <= 0.0_wp .or. rr2 >= support2) cycle
                nn = nn + 1
                all_near(nn) = jj
                all_r2(nn) = rr2
            end do
            all_r(1:nn) = sqrt(all_r2(1:nn))
            call phys%kernel%dwdr_many(all_r(1:nn), all_dwdr(1:nn))
            s_sum = 0.0_wp
            k_sum = 0.0_wp
            do mm = 1, nn
                jj = all_near(mm)
                cc = state(4, jj) * visc_scale * (state(6, i) + state(6, jj)) * all_r(mm) * &
                    all_dwdr(mm) / (all_r2(mm) + phys%eta2)
                if (p%kind(jj) == KIND_WALL) then
                    call wall_depths(p, i, jj, dfl, dwl, solids)
                    s_sum = s_sum + (cc * morris_beta(dfl, dwl, phys%beta_max)) * &
                        (state(1:3, i) - state(1:3, jj))
                    k_sum = k_sum + cc * dwl * (dfl + dwl)
                else
                    s_sum = s_sum + cc * (state(1:3, i) - state(1:3, jj))
                end if
            end do
            curv_i = s_sum / max(2.0_wp * phys%nu + k_sum, &
                2.0_wp * phys%nu / QUADRATIC_WALL_GAIN)
        end subroutine wall_curvature

        !> The solid whose force a pair with j counts towards, 0 when forces are not asked
        !> for or j belongs to no solid (fluid).
        integer function force_slot(jj)
            integer, intent(in) :: jj
            force_slot = 0
            if (.not. present(wall_forces)) return
            ! a virtual particle stands in for fluid that the other level's real particles
            ! carry, and they push on the solid already
            if (p%kind(i) /= KIND_FLUID) return
            force_slot = p%solid(jj)
        end function force_slot

        !> The pairs near(first:last) of owned particle i with Morris wall particles, under
        !> Morris' viscosity without the transport velocity (fast_walls): the general loop's
        !> terms for such a pair, in its order of operations, without its tests per pair:
        !>   f = -(p_i/rho_i^2 + p_j/rho_j^2) grad W + nu s (1/rho_i + 1/rho_j) visc_f beta v_ij,
        !> beta Morris' factor (a plane wall's inline, a body's through wall_beta).
        subroutine morris_wall_pairs(first, last)
            integer, intent(in) :: first, last
            integer :: mm, jj, ss
            real(wp) :: gw(3), vw(3), vgw, pw, cw, bw, vv(3), fw(3), ew, mw, df, dw
            logical :: bw_curved
            do mm = first, last
                jj = near(mm)
                mw = state(4, jj)
                gw = d_near(:, mm) * grad_near(mm)
                vw = state(1:3, i) - state(1:3, jj)
                vgw = vw(1) * gw(1) + vw(2) * gw(2) + vw(3) * gw(3)
                pw = state(5, i) + state(5, jj)
                fw = -pw * gw
                ew = 0.5_wp * pw * vgw
                cw = visc_scale * (state(6, i) + state(6, jj)) * visc_near(mm)
                ! (a wall particle of a solid not passed in, as in wall_beta: its plane)
                if (p%solid(jj) <= ubound(curved, 1)) then
                    bw_curved = curved(p%solid(jj))
                else
                    bw_curved = .false.
                end if
                if (bw_curved) then
                    call wall_depths(p, i, jj, df, dw, solids)
                else
                    ! distance_to_wall written out: calling it here (inlined) made the rates
                    ! 5 % slower on the channel, four runs side by side
                    df = p%wall_normal(1, jj) * (xi(1) - p%x(1, jj)) + p%wall_normal(2, jj) * &
                        (xi(2) - p%x(2, jj)) + p%wall_normal(3, jj) * (xi(3) - p%x(3, jj)) - &
                        p%wall_distance(jj)
                    dw = p%wall_distance(jj)
                end if
                bw = morris_beta(df, dw, phys%beta_max)
                vv = bw * vw - curv_i * (dw * (df + dw))
                fw = fw + cw * vv
                ew = ew - 0.5_wp * cw * (vv(1) * vv(1) + vv(2) * vv(2) + vv(3) * vv(3))
                drho = drho + mw * vgw
                dv = dv + mw * fw
                de = de + mw * ew
                ss = force_slot(jj)
                if (ss > 0) then
                    wall_forces(:, 1, ss) = wall_forces(:, 1, ss) + m_i * mw * pw * gw
                    wall_forces(:, 2, ss) = wall_forces(:, 2, ss) - m_i * mw * (fw + pw * gw)
                end if
            end do
        end subroutine morris_wall_pairs

        !> Morris wall particles follow the continuity equation with their own velocity.
        !> (As the fluid's rates: the partners within the support first, then dW/dr of all of
        !> them in one kernel call; partners beyond the support would add dW/dr = 0.)
        subroutine wall_density_rate(iw)
            integer, intent(in) :: iw
            integer :: kk, jj, mm, nw
            real(wp) :: dd(3), rr2, gw
            nw = 0
            ! walls are rigid: a belt (lid) sliding past a resting wall does not compress
            ! either of them, so only the fluid changes a wall particle's density: the halved
            ! row holds the partners that are not walls
            do kk = kept_scratch%half_start(iw), kept_scratch%half_start(iw + 1) - 1
                jj = kept_scratch%half_index(kk)
                dd(1) = p%x(1, iw) - p%x(1, jj)
                dd(2) = p%x(2, iw) - p%x(2, jj)
                dd(3) = p%x(3, iw) - p%x(3, jj)
                rr2 = dd(1)**2 + dd(2)**2 + dd(3)**2
                if (rr2 <= 0.0_wp .or. rr2 >= support2) cycle
                nw = nw + 1
                w_near(nw) = jj
                w_d(:, nw) = dd
                w_r2(nw) = rr2
            end do
            w_r(1:nw) = sqrt(w_r2(1:nw))
            call phys%kernel%dwdr_many(w_r(1:nw), w_dwdr(1:nw))
            drho = 0.0_wp
            do mm = 1, nw
                jj = w_near(mm)
                gw = w_dwdr(mm) / w_r(mm)
                drho = drho + state(4, jj) * ((state(1, iw) - state(1, jj)) * (w_d(1, mm) &
                    * gw) + (state(2, iw) - state(2, jj)) * (w_d(2, mm) * gw) + &
                    (state(3, iw) - state(3, jj)) * (w_d(3, mm) * gw))
            end do
            p%drhodt(iw) = drho
        end subroutine wall_density_rate
    end subroutine compute_rates

    !> The rows of list nl that compute_rates evaluates (kept_scratch's half rows, made
    !> once per list): a pair of two owned fluid particles (real or virtual) is evaluated
    !> from its lower index only, so the other's row drops it; a wall's row keeps the
    !> partners that are not walls (the fluid and mirrors its density rate sums over). A
    !> particle does not change between fluid and wall while a list lasts (only fluid and
    !> virtual turn into each other), so the rows hold until the next build. Scanning the
    !> whole rows and skipping the shared pairs one by one cost a tenth of the rates.
    subroutine halve_rows(p, nl)
        type(particles_t), intent(in) :: p
        type(neighbour_list_t), intent(in) :: nl
        integer :: i, k, j, n_half
        associate (sc => kept_scratch)
            ! (a list made by hand, not by sph_cell_list, has generation 0: halved each time)
            if (nl%generation > 0 .and. sc%half_generation == nl%generation .and. &
                sc%half_owned == p%n_owned) return
            if (allocated(sc%half_start)) then
                if (size(sc%half_start) < p%n_owned + 1 .or. &
                    size(sc%half_index) < nl%start(p%n_owned + 1) - 1) &
                    deallocate(sc%half_start, sc%half_index)
            end if
            if (.not. allocated(sc%half_start)) allocate(sc%half_start(p%n_owned + 1), &
                sc%half_index(max(nl%start(p%n_owned + 1) - 1, 1)))
            n_half = 0
            do i = 1, p%n_owned
                sc%half_start(i) = n_half + 1
                if (p%kind(i) == KIND_WALL) then
                    ! a wall's density follows the fluid around it only (wall_density_rate)
                    do k = nl%start(i), nl%start(i + 1) - 1
                        j = nl%index(k)
                        if (p%kind(j) == KIND_WALL) cycle
                        n_half = n_half + 1
                        sc%half_index(n_half) = j
                    end do
                end if
                if (.not. moves_with_flow(p%kind(i))) cycle
                do k = nl%start(i), nl%start(i + 1) - 1
                    j = nl%index(k)
                    if (j < i) then
                        if (moves_with_flow(p%kind(j))) cycle
                    end if
                    n_half = n_half + 1
                    sc%half_index(n_half) = j
                end do
            end do
            sc%half_start(p%n_owned + 1) = n_half + 1
            sc%half_generation = nl%generation
            sc%half_owned = p%n_owned
        end associate
    end subroutine halve_rows

    !> Free compute_rates' kept arrays (the next evaluation allocates them again).
    subroutine release_rates_scratch()
        if (allocated(kept_scratch%state)) deallocate(kept_scratch%state)
        if (allocated(kept_scratch%paired)) deallocate(kept_scratch%paired)
        if (allocated(kept_scratch%flows)) deallocate(kept_scratch%flows)
        if (allocated(kept_scratch%filtered)) deallocate(kept_scratch%filtered)
        if (allocated(kept_scratch%half_start)) deallocate(kept_scratch%half_start, &
            kept_scratch%half_index)
        kept_scratch%half_generation = -1
    end subroutine release_rates_scratch

    !> compute_rates' kept arrays (kept_scratch), at least n particles long; the caller hands
    !> them back with move_alloc.
    subroutine take_scratch(n, state, paired, flows)
        integer, intent(in) :: n
        real(wp), allocatable, intent(out) :: state(:, :)
        logical, allocatable, intent(out) :: paired(:), flows(:)
        call move_alloc(kept_scratch%state, state)
        call move_alloc(kept_scratch%paired, paired)
        call move_alloc(kept_scratch%flows, flows)
        if (allocated(paired)) then
            if (size(paired) >= n) return
            deallocate(state, paired, flows)
        end if
        allocate(state(6, max(1, n)), paired(max(1, n)), flows(max(1, n)))
    end subroutine take_scratch

    !> The pairs of owned particle i with its first n fluid partners (real or virtual, within
    !> the support, dW/dr / r in grad_w and Morris' r dW/dr / (r^2 + eta^2) in visc_f) under
    !> Morris' viscosity without the transport velocity: the bulk of a step's pair work, in a
    !> loop of its own over plain arrays without a test, so the compiler keeps i's sums in
    !> registers and knows every stride. The terms are those of compute_rates' general loop
    !> for such a pair:
    !>   f = -(p_i/rho_i^2 + p_j/rho_j^2) grad W + nu s (1/rho_i + 1/rho_j) visc_f v_ij,
    !>   e = 1/2 (p_i/rho_i^2 + p_j/rho_j^2) v_ij . grad W - 1/2 nu s (...) visc_f |v_ij|^2,
    !> per unit mass of the partner; state holds v, m, p/rho^2, 1/rho of every particle.
    !> The energy's terms only with `energy` (the loop unswitched: without them it is a
    !> tenth of a channel step cheaper). (A variant computing two components in 2D ran no
    !> faster.)
    subroutine morris_fluid_pairs(n, near, d, grad_w, visc_f, i, visc_scale, state, energy, &
            drho, dv, de, drhodt, dvdt, dedt)
        integer, intent(in) :: n, near(n), i
        real(wp), intent(in) :: d(3, *), grad_w(n), visc_f(n), visc_scale
        real(wp), intent(in) :: state(6, *)
        logical, intent(in) :: energy
        real(wp), intent(inout) :: drho, dv(3), de
        !> the particles' rates (all of them, ghosts included): j's terms are added to j's.
        !> (Written straight to them rather than to a packed scratch array read back later:
        !> two passes over all particles less, 40 bytes per particle less, rates 1-3 %
        !> faster.)
        real(wp), intent(inout) :: drhodt(*), dvdt(3, *), dedt(*)
        integer :: m, j
        real(wp) :: vi(3), m_i, pi_term, inv_rho_i, grad(3), vij(3), vg, pterm, coeff
        real(wp) :: f(3), e_pair, m_j, sum_rho, sum_v(3), sum_e
        vi = state(1:3, i)
        m_i = state(4, i)
        pi_term = state(5, i)
        inv_rho_i = state(6, i)
        sum_rho = 0.0_wp
        sum_v = 0.0_wp
        sum_e = 0.0_wp
        do m = 1, n
            j = near(m)
            grad = d(:, m) * grad_w(m)
            vij = vi - state(1:3, j)
            vg = vij(1) * grad(1) + vij(2) * grad(2) + vij(3) * grad(3)
            pterm = pi_term + state(5, j)
            coeff = visc_scale * (inv_rho_i + state(6, j)) * visc_f(m)
            f = coeff * vij - pterm * grad
            m_j = state(4, j)
            sum_rho = sum_rho + m_j * vg
            sum_v = sum_v + m_j * f
            drhodt(j) = drhodt(j) + m_i * vg
            dvdt(:, j) = dvdt(:, j) - m_i * f
            if (energy) then
                e_pair = 0.5_wp * pterm * vg - 0.5_wp * coeff * (vij(1)**2 + vij(2)**2 + &
                    vij(3)**2)
                sum_e = sum_e + m_j * e_pair
                dedt(j) = dedt(j) + m_i * e_pair
            end if
        end do
        drho = drho + sum_rho
        dv = dv + sum_v
        de = de + sum_e
    end subroutine morris_fluid_pairs

    !> compute_rates' search of one row: of the n listed partners idx of the particle at xi,
    !> those within the support (x the positions of all particles) appended to near, d_near
    !> (xi - x_j) and r2_near after n_near; with `fast`, partners that do not move with the
    !> flow (flows) go to other(1:n_other) instead, in list order. Explicit shapes: the
    !> positions' stride known to the compiler.
    subroutine find_row(xi, idx, n, x, flows, fast, support2, near, d_near, r2_near, n_near, &
            other, n_other)
        integer, intent(in) :: n, idx(n)
        real(wp), intent(in) :: xi(3), x(3, *), support2
        logical, intent(in) :: flows(*), fast
        integer, intent(inout) :: near(*), n_near
        real(wp), intent(inout) :: d_near(3, *), r2_near(*)
        integer, intent(out) :: other(*), n_other
        integer :: k, j
        real(wp) :: d(3), r2
        n_other = 0
        do k = 1, n
            j = idx(k)
            d(1) = xi(1) - x(1, j)
            d(2) = xi(2) - x(2, j)
            d(3) = xi(3) - x(3, j)
            r2 = d(1)**2 + d(2)**2 + d(3)**2
            if (r2 <= 0.0_wp .or. r2 >= support2) cycle
            if (fast .and. .not. flows(j)) then
                n_other = n_other + 1
                other(n_other) = j
                cycle
            end if
            n_near = n_near + 1
            near(n_near) = j
            d_near(1, n_near) = d(1)
            d_near(2, n_near) = d(2)
            d_near(3, n_near) = d(3)
            r2_near(n_near) = r2
        end do
    end subroutine find_row

    !> compute_rates' set-up of a one-level run: what a pair reads of each particle, packed
    !> (state: v, m, p/rho^2, 1/rho), whether it moves with the flow (flows) and shares its
    !> pair terms (paired: owned and flowing), and the rates zeroed, ghosts' too
    !> (morris_fluid_pairs adds j's terms straight to j's rates, with no test; a ghost's are
    !> this rank's partial sums and mean nothing). Explicit shapes and the kinds in a loop of
    !> their own: the general loop's level test and strided reads cost 4.6 % of a 10^5
    !> channel step. (Split further so that every loop vectorised, or in blocks, it moved
    !> more memory and was slower at 10^6.)
    subroutine fill_pair_state(n, n_owned, v, m, pres, rho, kind, state, flows, paired, &
            drhodt, dvdt, dedt)
        integer, intent(in) :: n, n_owned, kind(n)
        real(wp), intent(in) :: v(3, n), m(n), pres(n), rho(n)
        real(wp), intent(out) :: state(6, n), drhodt(n), dvdt(3, n), dedt(n)
        logical, intent(out) :: flows(n), paired(n)
        integer :: j
        do j = 1, n
            state(1, j) = v(1, j)
            state(2, j) = v(2, j)
            state(3, j) = v(3, j)
            state(4, j) = m(j)
            state(5, j) = pres(j) / rho(j)**2
            state(6, j) = 1.0_wp / rho(j)
            drhodt(j) = 0.0_wp
            dvdt(1, j) = 0.0_wp
            dvdt(2, j) = 0.0_wp
            dvdt(3, j) = 0.0_wp
            dedt(j) = 0.0_wp
        end do
        do j = 1, n
            flows(j) = kind(j) == KIND_FLUID .or. kind(j) == KIND_VIRTUAL
        end do
        paired(1:n_owned) = flows(1:n_owned)
        paired(n_owned + 1:n) = .false.
    end subroutine fill_pair_state

    pure function tensor(s) result(t)
        real(wp), intent(in) :: s(6)
        real(wp) :: t(3, 3)
        integer :: a, b
        do b = 1, 3
            do a = 1, 3
                t(a, b) = s(voigt(a, b))
            end do
        end do
    end function tensor

    !> Largest speed among owned fluid particles, real or virtual (for the CFL limit and the
    !> log).
    pure real(wp) function local_max_speed(p, transport)
        type(particles_t), intent(in) :: p
        logical, intent(in) :: transport   !< as local_motion_maxima
        real(wp) :: maxima(2)
        maxima = local_motion_maxima(p, transport)
        local_max_speed = maxima(1)
    end function local_max_speed

    !> The largest speed (CFL limit) and acceleration magnitude (force limit, eq. 4.3) among
    !> owned fluid particles, real or virtual, in one pass. The speed is that of the
    !> transport velocity, which moves the particles (v when it is off).
    pure function local_motion_maxima(p, transport) result(maxima)
        type(particles_t), intent(in) :: p
        !> the transport-velocity formulation is in use (phys%transport_velocity)
        logical, intent(in) :: transport
        real(wp) :: maxima(2)
        real(wp) :: speed2, accel2
        integer :: i
        speed2 = 0.0_wp
        accel2 = 0.0_wp
        ! components written out (a loop over the unknown leading extent per particle cost
        ! more than the arithmetic; moves_with_flow written out, as gfortran does not inline
        ! across modules); the transport offsets are read only when they are in use
        if (transport) then
            do i = 1, p%n_owned
                if (.not. (p%kind(i) == KIND_FLUID .or. p%kind(i) == KIND_VIRTUAL)) cycle
                speed2 = max(speed2, (p%v(1, i) + p%dv_transport(1, i))**2 + &
                    (p%v(2, i) + p%dv_transport(2, i))**2 + (p%v(3, i) + p%dv_transport(3, i))**2)
                accel2 = max(accel2, p%dvdt(1, i)**2 + p%dvdt(2, i)**2 + p%dvdt(3, i)**2)
            end do
        else
            do i = 1, p%n_owned
                if (.not. (p%kind(i) == KIND_FLUID .or. p%kind(i) == KIND_VIRTUAL)) cycle
                speed2 = max(speed2, p%v(1, i)**2 + p%v(2, i)**2 + p%v(3, i)**2)
                accel2 = max(accel2, p%dvdt(1, i)**2 + p%dvdt(2, i)**2 + p%dvdt(3, i)**2)
            end do
        end if
        maxima = sqrt([speed2, accel2])
    end function local_motion_maxima
end module sph_rates
