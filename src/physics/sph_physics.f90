!> The physical and numerical parameters the particle loops need, resolved from the input
!> (automatic sound speed and smoothing length filled in), in one plain value type.
module sph_physics
    use sph_kinds, only: wp
    use sph_config, only: config_t, n_faces
    use sph_kernel, only: kernel_t, kernel_create, kernel_id_from_name, kernel_default_h_factor
    use sph_eos, only: eos_id_from_name, morris_sound_speed
    implicit none
    private
    public :: physics_t, physics_from_config
    public :: DENSITY_CONTINUITY, DENSITY_SUMMATION, VISCOSITY_MORRIS, VISCOSITY_STRAIN_RATE
    public :: WALLS_MORRIS, WALLS_REPULSIVE, WALLS_MIRROR, WALLS_REPULSIVE_MIRROR
    public :: SHIFTING_NONE, SHIFTING_LIND
    public :: WALL_PRESSURE_CONTINUITY, WALL_PRESSURE_EXTRAPOLATED
    public :: QUADRATIC_WALL_GAIN, stiffest_viscosity

    integer, parameter :: DENSITY_CONTINUITY = 1, DENSITY_SUMMATION = 2
    integer, parameter :: VISCOSITY_MORRIS = 1, VISCOSITY_STRAIN_RATE = 2
    integer, parameter :: WALLS_MORRIS = 1, WALLS_REPULSIVE = 2, WALLS_MIRROR = 3
    integer, parameter :: WALLS_REPULSIVE_MIRROR = 4
    integer, parameter :: SHIFTING_NONE = 0, SHIFTING_LIND = 1
    !> Largest factor by which quadratic wall extrapolation raises a fluid particle's viscous
    !> term (sph_rates' wall_curvature keeps it there): on the lattice of a plane wall the
    !> first row's is about 1.4, and the stable step shrank by about as much
    real(wp), parameter :: QUADRATIC_WALL_GAIN = 1.5_wp
    integer, parameter :: WALL_PRESSURE_CONTINUITY = 1, WALL_PRESSURE_EXTRAPOLATED = 2

    type :: physics_t
        integer :: dim = 2
        type(kernel_t) :: kernel
        real(wp) :: dx = 1.0_wp
        real(wp) :: rho0 = 1000.0_wp
        real(wp) :: nu = 1.0e-6_wp
        real(wp) :: body_force(3) = 0.0_wp
        integer :: eos = 1
        real(wp) :: c = 1.0_wp             !< sound speed used
        real(wp) :: gamma = 7.0_wp
        real(wp) :: background_pressure = 0.0_wp   !< added to the equation of state's
        integer :: density_method = DENSITY_CONTINUITY
        integer :: viscosity = VISCOSITY_MORRIS
        integer :: walls = WALLS_MORRIS
        real(wp) :: beta_max = 10.0_wp     !< cap of Morris' wall velocity extrapolation
        !> Morris wall velocities on a parabola through the wall (curvature from the fluid);
        !> it raises the viscous term next to a wall by at most QUADRATIC_WALL_GAIN
        logical :: wall_quadratic = .false.
        !> Shepard filter of the integrated density every density_filter_interval steps (0:
        !> none)
        integer :: density_filter_interval = 0
        real(wp) :: eta2 = 0.0_wp          !< 0.01 h^2: keeps Morris' viscous term finite
        real(wp) :: viscous_scale = 1.0_wp !< 1 / lattice second moment of Morris' operator
        real(wp) :: repulsive_d = 0.0_wp, repulsive_r0 = 0.0_wp
        integer :: repulsive_n1 = 12, repulsive_n2 = 4
        real(wp) :: velocity_scale = 0.0_wp, length_scale = 0.0_wp
        integer :: shifting = SHIFTING_NONE
        real(wp) :: shifting_coefficient = 2.0_wp  !< A of D = A h |v|max dt (sph_shifting)
        real(wp) :: shifting_limit = 0.1_wp        !< largest shift per step / dx
        !> Morris wall particles' density: continuity, or from the fluid's pressure
        integer :: wall_pressure = WALL_PRESSURE_CONTINUITY
        !> transport-velocity formulation (Adami, Hu & Adams 2013): the particles move with
        !> v + dt a_b, a_b the acceleration of the background pressure transport_pressure
        logical :: transport_velocity = .false.
        real(wp) :: transport_pressure = 0.0_wp    !< Pa, p_b
        !> the internal energy's rate: pressure work and viscous heating. Off, dedt stays 0
        !> (no equation of state reads the energy; its terms were a tenth of a step)
        logical :: energy_equation = .false.
    end type physics_t

contains

    !> The viscosity the viscous time-step limit must assume: nu, raised by the quadratic
    !> wall extrapolation's gain where it is on (measured on Poiseuille at L/20: Verlet stable
    !> at viscous_safety 0.125 with Morris' linear walls, at 0.1 and not 0.125 with quadratic).
    pure real(wp) function stiffest_viscosity(phys)
        type(physics_t), intent(in) :: phys
        stiffest_viscosity = phys%nu
        if (phys%wall_quadratic .and. phys%walls == WALLS_MORRIS) &
            stiffest_viscosity = phys%nu * QUADRATIC_WALL_GAIN
    end function stiffest_viscosity

    !> Resolve the parameters; stat /= 0 with a message naming the keys when impossible.
    subroutine physics_from_config(cfg, phys, stat, errmsg)
        type(config_t), intent(in) :: cfg
        type(physics_t), intent(out) :: phys
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: errmsg
        real(wp) :: h, length, velocity, force, jump
        integer :: axis, f

        stat = 0
        errmsg = ''
        phys%dim = cfg%domain%dimension
        phys%dx = cfg%domain%dx
        h = cfg%numerics%h_factor
        if (h <= 0.0_wp) h = kernel_default_h_factor(kernel_id_from_name(cfg%numerics%kernel))
        phys%kernel = kernel_create(kernel_id_from_name(cfg%numerics%kernel), &
            cfg%domain%dimension, h * cfg%domain%dx)
        phys%rho0 = cfg%fluid%rho0
        phys%nu = cfg%fluid%nu
        phys%body_force = 0.0_wp
        phys%body_force(1:cfg%domain%dimension) = cfg%fluid%body_force(1:cfg%domain%dimension)
        phys%eos = eos_id_from_name(cfg%fluid%eos)
        phys%gamma = cfg%fluid%tait_gamma
        phys%background_pressure = cfg%fluid%background_pressure
        select case (trim(cfg%numerics%density_method))
        case ('summation'); phys%density_method = DENSITY_SUMMATION
        case default; phys%density_method = DENSITY_CONTINUITY
        end select
        select case (trim(cfg%numerics%viscosity_model))
        case ('strain_rate'); phys%viscosity = VISCOSITY_STRAIN_RATE
        case default; phys%viscosity = VISCOSITY_MORRIS
        end select
        select case (trim(cfg%numerics%wall_model))
        case ('repulsive'); phys%walls = WALLS_REPULSIVE
        case ('mirror'); phys%walls = WALLS_MIRROR
        case ('repulsive_mirror'); phys%walls = WALLS_REPULSIVE_MIRROR
        case default; phys%walls = WALLS_MORRIS
        end select
        phys%beta_max = cfg%numerics%beta_max
        phys%wall_quadratic = trim(cfg%numerics%wall_extrapolation) == 'quadratic'
        phys%density_filter_interval = 0
        if (trim(cfg%numerics%density_filter) == 'shepard') &
            phys%density_filter_interval = cfg%numerics%density_filter_interval
        phys%eta2 = 0.01_wp * phys%kernel%h**2
        phys%viscous_scale = 1.0_wp
        if (trim(cfg%numerics%viscosity_normalisation) == 'lattice') phys%viscous_scale = &
            1.0_wp / lattice_laplacian_moment(phys%kernel, cfg%domain%dx, phys%eta2)

        ! length scale: the narrowest wall-to-wall gap, else the smallest box side
        length = cfg%fluid%length_scale
        if (length <= 0.0_wp) then
            length = huge(1.0_wp)
            do axis = 1, cfg%domain%dimension
                if (cfg%domain%is_wall(2*axis - 1)) length = min(length, &
                    cfg%domain%box_hi(axis) - cfg%domain%box_lo(axis))
            end do
            if (length == huge(1.0_wp)) length = &
                minval(cfg%domain%box_hi(1:cfg%domain%dimension) - &
                cfg%domain%box_lo(1:cfg%domain%dimension))
        end if
        force = norm2(phys%body_force)
        velocity = cfg%fluid%velocity_scale
        if (velocity <= 0.0_wp) then
            ! fastest wall or body, or the peak of the Poiseuille profile the body force
            ! drives (a moving body was left out: a cylinder drawn through resting fluid was
            ! refused as having no velocity scale, and one at 1 cm/s in a 2.5e-5 m/s channel
            ! outran the sound speed at its fourth step)
            velocity = 0.0_wp
            do f = 1, n_faces
                if (cfg%domain%is_wall(f)) &
                    velocity = max(velocity, norm2(cfg%domain%wall_velocity(:, f)))
            end do
            if (allocated(cfg%bodies)) then
                do f = 1, size(cfg%bodies)
                    velocity = max(velocity, norm2(cfg%bodies(f)%velocity))
                end do
            end if
            if (cfg%fluid%nu > 0.0_wp) &
                velocity = max(velocity, force * length**2 / (8.0_wp * cfg%fluid%nu))
        end if
        phys%velocity_scale = velocity
        phys%length_scale = length
        if (cfg%fluid%sound_speed > 0.0_wp) then
            phys%c = cfg%fluid%sound_speed
        else
            phys%c = morris_sound_speed(velocity, cfg%fluid%nu, length, force, &
                cfg%fluid%density_variation)
            ! where walls of different velocities meet at a corner (a lid), the velocity
            ! jumps by the difference within one smoothing length: the viscous stress there
            ! scales with nu dV / h, not nu V / L, and the pressure must hold it
            jump = cfg%domain%corner_velocity_jump()
            if (jump > 0.0_wp) phys%c = max(phys%c, morris_sound_speed(jump, cfg%fluid%nu, &
                phys%kernel%h, 0.0_wp, cfg%fluid%density_variation))
            if (.not. (phys%c > 0.0_wp)) then
                stat = 1
                errmsg = '&fluid sound_speed = 0 asks for the automatic (Morris) sound ' // &
                    'speed, but this flow has no velocity scale (resting walls and bodies, ' // &
                    'no body force): give ' // &
                    '&fluid sound_speed > 0 or &fluid velocity_scale > 0'
                return
            end if
        end if
        phys%repulsive_d = cfg%numerics%repulsive_strength
        if (phys%repulsive_d <= 0.0_wp) phys%repulsive_d = velocity**2
        phys%repulsive_r0 = cfg%numerics%repulsive_r0
        ! the first fluid row starts dx/2 from the wall plane: no repulsion in the initial state
        if (phys%repulsive_r0 <= 0.0_wp) phys%repulsive_r0 = 0.5_wp * cfg%domain%dx
        phys%repulsive_n1 = cfg%numerics%repulsive_n1
        phys%repulsive_n2 = cfg%numerics%repulsive_n2
        phys%shifting = SHIFTING_NONE
        if (trim(cfg%numerics%shifting) == 'lind') phys%shifting = SHIFTING_LIND
        phys%shifting_coefficient = cfg%numerics%shifting_coefficient
        phys%shifting_limit = cfg%numerics%shifting_limit
        phys%wall_pressure = WALL_PRESSURE_CONTINUITY
        if (trim(cfg%numerics%wall_pressure) == 'extrapolated') &
            phys%wall_pressure = WALL_PRESSURE_EXTRAPOLATED
        phys%transport_velocity = cfg%numerics%transport_velocity
        phys%energy_equation = cfg%fluid%energy_equation
        ! Adami et al. (2013) take p_b = p0 = rho0 c^2, the equation of state's stiffness
        phys%transport_pressure = cfg%numerics%transport_pressure
        if (phys%transport_pressure <= 0.0_wp) phys%transport_pressure = phys%rho0 * phys%c**2
    end subroutine physics_from_config

    !> Morris' viscous term is exact for a quadratic velocity field only if the discrete second
    !> moment  M = sum_j V_j (-r_ij dW/dr) y_ij^2 / (r_ij^2 + eta^2)  equals 1 (the continuous
    !> integral does). On a lattice of spacing dx it does not quite: cubic spline, h = 1.3 dx
    !> gives 0.9998 in 2D but 0.985 in 3D, i.e. a viscosity 1.5 % low. Dividing the term by M
    !> of the initial lattice makes the operator consistent for every kernel and dimension.
    real(wp) function lattice_laplacian_moment(kernel, dx, eta2) result(moment)
        type(kernel_t), intent(in) :: kernel
        real(wp), intent(in) :: dx, eta2
        integer :: n, i, j, k, kmax
        real(wp) :: d(3), r
        n = ceiling(kernel%support / dx) + 1
        kmax = merge(n, 0, kernel%dim == 3)
        moment = 0.0_wp
        do k = -kmax, kmax
            do j = -n, n
                do i = -n, n
                    if (i == 0 .and. j == 0 .and. k == 0) cycle
                    d = [i, j, k] * dx
                    r = norm2(d)
                    if (r >= kernel%support) cycle
                    moment = moment + dx**kernel%dim * (-r * kernel%dwdr(r)) * d(2)**2 &
                        / (r * r + eta2)
                end do
            end do
        end do
    end function lattice_laplacian_moment
end module sph_physics
