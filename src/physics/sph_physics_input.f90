!> The physics as read from input: &fluid (material, equation of state and the scales of
!> Morris' sound-speed criterion) and &numerics (kernel, discretisation choices, wall model,
!> time-step safety factors). Read by sph_config; turned into physics_t by sph_physics.
module sph_physics_input
    use sph_kinds, only: wp
    use sph_namelist, only: nml_group_t, real_text
    use sph_domain_input, only: domain_input_t
    implicit none
    !> the largest viscous_safety found stable on the channel flows (Poiseuille at L/20, linear
    !> wall extrapolation, doc/physics.md): above it the input gets a note
    real(wp), parameter :: PC_VISCOUS_STABLE = 0.25_wp, VERLET_VISCOUS_STABLE = 0.125_wp
    private
    public :: fluid_input_t, numerics_input_t, read_fluid_input, read_numerics_input
    public :: check_moving_corners, check_transport_background

    integer, parameter :: name_len = 32

    type :: fluid_input_t
        real(wp) :: rho0, nu, body_force(3)
        character(len=name_len) :: eos
        real(wp) :: sound_speed           !< 0 = Morris' criterion
        real(wp) :: background_pressure   !< added to the equation of state's pressure
        real(wp) :: tait_gamma, density_variation
        real(wp) :: velocity_scale        !< 0 = estimated from walls and body force
        real(wp) :: length_scale          !< 0 = smallest wall-to-wall distance or box size
        logical :: energy_equation        !< integrate the internal energy (a diagnostic)
    end type fluid_input_t

    type :: numerics_input_t
        character(len=name_len) :: kernel
        real(wp) :: h_factor              !< h = h_factor * dx; 0 = kernel's default
        character(len=name_len) :: density_method, viscosity_model, viscosity_normalisation
        character(len=name_len) :: wall_model
        !> Morris wall velocity: 'linear' (Morris et al. 1997) or 'quadratic' (with curvature)
        character(len=name_len) :: wall_extrapolation
        !> 'none' or 'shepard': the integrated density renormalised every density_filter_interval
        character(len=name_len) :: density_filter
        integer :: density_filter_interval
        real(wp) :: cfl, viscous_safety, force_safety, beta_max
        real(wp) :: fixed_dt              !< s; 0 = the stable limit
        real(wp) :: repulsive_strength    !< D of eq. 2.18; 0 = velocity_scale**2
        real(wp) :: repulsive_r0          !< r0 of eq. 2.18; 0 = dx/2
        integer :: repulsive_n1, repulsive_n2
        character(len=name_len) :: shifting
        real(wp) :: shifting_coefficient  !< A of Lind's D = A h |v|max dt
        real(wp) :: shifting_limit        !< largest shift per step, in units of dx
        character(len=name_len) :: wall_pressure  !< 'continuity' or 'extrapolated'
        !> transport-velocity formulation (Adami, Hu & Adams 2013)
        logical :: transport_velocity
        real(wp) :: transport_pressure    !< Pa, p_b of the transport velocity; 0 = rho0 c^2
        !> 'predictor_corrector' (two rate evaluations per step) or 'verlet' (one)
        character(len=name_len) :: integrator
    end type numerics_input_t

contains

    !> Read the &fluid group (rest density, viscosity, body force, equation of state, scales).
    subroutine read_fluid_input(grp, fl)
        type(nml_group_t), intent(inout) :: grp
        type(fluid_input_t), intent(out) :: fl
        ! (bounded: squares and inverse squares of densities stay finite)
        call grp%get_real('rho0', fl%rho0, 1000.0_wp, min=1.0e-10_wp, max=1.0e10_wp, &
            unit='kg/m^3', doc='rest density')
        call grp%get_real('nu', fl%nu, 1.0e-6_wp, min=0.0_wp, unit='m^2/s', &
            doc='kinematic viscosity')
        call grp%get_real_array('body_force', fl%body_force, 0.0_wp, unit='m/s^2', &
            doc='body force per unit mass')
        call grp%get_string('eos', fl%eos, 'morris_relative', &
            choices=[character(len=16) :: 'morris', 'morris_relative', 'tait'], &
            doc='equation of state')
        call grp%get_real('sound_speed', fl%sound_speed, 0.0_wp, min=0.0_wp, unit='m/s', &
            doc="0 = Morris' criterion")
        call grp%get_real('background_pressure', fl%background_pressure, 0.0_wp, min=0.0_wp, &
            unit='Pa', doc="added to the equation of state's pressure")
        call grp%get_real('tait_gamma', fl%tait_gamma, 7.0_wp, min=1.0_wp, &
            doc='exponent of the Tait equation')
        call grp%get_real('density_variation', fl%density_variation, 0.01_wp, &
            min_exclusive=0.0_wp, max_exclusive=1.0_wp, &
            doc="delta in Morris' sound-speed criterion")
        call grp%get_real('velocity_scale', fl%velocity_scale, 0.0_wp, min=0.0_wp, &
            unit='m/s', doc='V for the criterion; 0 = estimated')
        call grp%get_real('length_scale', fl%length_scale, 0.0_wp, min=0.0_wp, unit='m', &
            doc='L for the criterion; 0 = narrowest gap or smallest box side')
        call grp%get_logical('energy_equation', fl%energy_equation, .false., &
            doc='integrate the internal energy per unit mass (pressure work and viscous ' // &
            'heating): a diagnostic, which no equation of state reads; .false. keeps ' // &
            'each particle''s energy as it started')
        ! keys given that the rest of the input makes idle: a note each, not an error
        if (trim(fl%eos) /= 'tait') call grp%note_if_given('tait_gamma', &
            "it is the exponent of eos = 'tait' (eos = '" // trim(fl%eos) // "')")
        if (fl%sound_speed > 0.0_wp) call grp%note_if_given('density_variation', &
            "it sets the sound speed by Morris' criterion, and sound_speed is given")
    end subroutine read_fluid_input

    !> Read the &numerics group (kernel, models, time-step factors, shifting, integrator, ...).
    subroutine read_numerics_input(grp, num)
        type(nml_group_t), intent(inout) :: grp
        type(numerics_input_t), intent(out) :: num
        call grp%get_string('kernel', num%kernel, 'cubic', &
            choices=[character(len=12) :: 'cubic', 'quintic', 'wendland_c2'], &
            doc='smoothing kernel')
        call grp%get_real('h_factor', num%h_factor, 0.0_wp, min=0.0_wp, &
            doc='h = h_factor dx; 0 = kernel default, otherwise 0.8 to 4')
        ! a smaller h leaves a particle without neighbours (1e-3: none, and a time step of
        ! 1e-9 s from the viscous limit: the run seemed to hang), a larger one costs
        ! (h_factor)^dim times the pairs for no accuracy
        if (num%h_factor > 0.0_wp .and. (num%h_factor < 0.8_wp .or. num%h_factor > 4.0_wp)) &
            call grp%error('h_factor', real_text(num%h_factor) // ' is out of range: ' // &
                'must be 0 (the kernel''s default) or from 0.8 to 4 (times dx)')
        call grp%get_string('density_method', num%density_method, 'continuity', &
            choices=[character(len=12) :: 'continuity', 'summation'], &
            doc='integrated continuity equation or summation')
        call grp%get_string('density_filter', num%density_filter, 'none', &
            choices=[character(len=8) :: 'none', 'shepard'], &
            doc="'shepard': every density_filter_interval steps each fluid particle's " // &
            "integrated density is replaced by sum m W / sum (m/rho) W over its " // &
            "partners, which a uniform density keeps on any arrangement")
        call grp%get_int('density_filter_interval', num%density_filter_interval, 1, min=1, &
            doc='steps between two Shepard filters of the density')
        call grp%get_string('viscosity_model', num%viscosity_model, 'morris', &
            choices=[character(len=12) :: 'morris', 'strain_rate'], doc='viscous term')
        call grp%get_string('viscosity_normalisation', num%viscosity_normalisation, &
            'lattice', choices=[character(len=8) :: 'lattice', 'none'], &
            doc="normalise Morris' viscous term by its lattice second moment")
        call grp%get_string('wall_model', num%wall_model, 'morris', &
            choices=[character(len=16) :: 'morris', 'repulsive', 'mirror', 'repulsive_mirror'], &
            doc='wall boundary model')
        call grp%get_string('wall_extrapolation', num%wall_extrapolation, 'linear', &
            choices=[character(len=12) :: 'linear', 'quadratic'], &
            doc="Morris wall particles' velocity: extrapolated linearly to the wall " // &
            "(Morris et al. 1997) or along a parabola whose curvature is the fluid " // &
            "particle's velocity Laplacian")
        call grp%get_real('cfl', num%cfl, 0.25_wp, min_exclusive=0.0_wp, max=1.0_wp, &
            doc='safety factor of the CFL time-step limit')
        call grp%get_real('viscous_safety', num%viscous_safety, 0.125_wp, &
            min_exclusive=0.0_wp, max=0.5_wp, doc='safety factor of the viscous limit')
        call grp%get_real('force_safety', num%force_safety, 0.25_wp, min_exclusive=0.0_wp, &
            max=1.0_wp, doc='safety factor of the force limit')
        call grp%get_real('fixed_dt', num%fixed_dt, 0.0_wp, min=0.0_wp, unit='s', &
            doc='a fixed time step instead of the stable limit; 0 = the limit')
        call grp%get_real('beta_max', num%beta_max, 10.0_wp, min=1.0_wp, &
            doc="cap of Morris' wall-velocity extrapolation factor")
        call grp%get_real('repulsive_strength', num%repulsive_strength, 0.0_wp, min=0.0_wp, &
            unit='m^2/s^2', doc='D of eq. 2.18; 0 = velocity_scale^2')
        call grp%get_real('repulsive_r0', num%repulsive_r0, 0.0_wp, min=0.0_wp, unit='m', &
            doc='r0 of eq. 2.18; 0 = dx/2')
        call grp%get_int('repulsive_n1', num%repulsive_n1, 12, min=2, &
            doc='exponent n1 of eq. 2.18 (> n2)')
        call grp%get_int('repulsive_n2', num%repulsive_n2, 4, min=1, &
            doc='exponent n2 of eq. 2.18 (>= 1)')
        call grp%get_string('shifting', num%shifting, 'none', &
            choices=[character(len=8) :: 'none', 'lind'], &
            doc='particle shifting after each step (Lind et al. 2012)')
        call grp%get_real('shifting_coefficient', num%shifting_coefficient, 2.0_wp, &
            min_exclusive=0.0_wp, doc='A of the shifting coefficient D = A h |v|max dt')
        call grp%get_real('shifting_limit', num%shifting_limit, 0.1_wp, min_exclusive=0.0_wp, &
            max=0.5_wp, doc='largest shift of a particle in one step, in units of dx')
        call grp%get_string('wall_pressure', num%wall_pressure, 'continuity', &
            choices=[character(len=12) :: 'continuity', 'extrapolated'], &
            doc="Morris wall particles' density: integrated like the fluid's, or " // &
            "extrapolated from the fluid's pressure each stage (Adami et al. 2012)")
        call grp%get_logical('transport_velocity', num%transport_velocity, .false., &
            doc='transport-velocity formulation (Adami, Hu & Adams 2013): the background ' // &
            'pressure moves the particles, not the momentum')
        call grp%get_real('transport_pressure', num%transport_pressure, 0.0_wp, min=0.0_wp, &
            unit='Pa', doc="background pressure p_b of the transport velocity; 0 = " // &
            "rho0 c^2 (the equation of state's p0, as Adami et al. use)")
        call grp%get_string('integrator', num%integrator, 'predictor_corrector', &
            choices=[character(len=20) :: 'predictor_corrector', 'verlet'], &
            doc='time integration: midpoint predictor-corrector (two rate evaluations ' // &
            'per step) or velocity Verlet kick-drift-kick (one, as LAMMPS fix sph)')
        if (num%transport_velocity) call check_transport_velocity(grp, num)
        if (num%transport_velocity .and. trim(num%integrator) == 'verlet') &
            call grp%error('integrator', "'verlet' works with transport_velocity = .false. " // &
                "only (the transport offsets follow the predictor-corrector's stages); use " // &
                "integrator = 'predictor_corrector'")
        ! a fixed step leaves the limits' factors idle
        if (num%fixed_dt > 0.0_wp) then
            call grp%note_if_given('cfl', 'fixed_dt sets the step')
            call grp%note_if_given('viscous_safety', 'fixed_dt sets the step')
            call grp%note_if_given('force_safety', 'fixed_dt sets the step')
        else if (num%viscous_safety > merge(VERLET_VISCOUS_STABLE, PC_VISCOUS_STABLE, &
                trim(num%integrator) == 'verlet') * (1.0_wp + 1.0e-12_wp)) then
            ! (an unstable viscous step grows a zig-zag of the first rows that the force
            ! limit throttles: the densities stay in their band and the run ends with exit
            ! status 0: 1081 % off at 1 s with 0.3 on the L/20 Poiseuille channel; fz41)
            call grp%note('viscous_safety', 'above ' // trim(real_text(merge( &
                VERLET_VISCOUS_STABLE, PC_VISCOUS_STABLE, trim(num%integrator) == 'verlet'))) // &
                ', the largest factor found stable with this integrator on the channel flows ' // &
                '(doc/physics.md): the viscous term may go unstable, which the &health ' // &
                'checks do not always see')
        end if
        if (num%repulsive_n1 <= num%repulsive_n2) &
            call grp%error('repulsive_n1, repulsive_n2', 'need n1 > n2 >= 1')
        ! (kept to reproduce the thesis' form; its weakness grows into an instability)
        if (trim(num%viscosity_model) == 'strain_rate') call grp%note('viscosity_model', &
            "'strain_rate' is not recommended: it does not see a zig-zag of rows 2 dx " // &
            'apart, which grows (Poiseuille at L/40: 25 % off at 0.225 s, 420 % at 1 s); ' // &
            "use 'morris' (doc/physics.md)")
        if (trim(num%viscosity_model) == 'strain_rate' .and. &
            (trim(num%wall_model) == 'mirror' .or. trim(num%wall_model) == 'repulsive_mirror')) &
            call grp%error('viscosity_model', "'strain_rate' works with wall_model = " // &
                "'morris' or 'repulsive', not '" // trim(num%wall_model) // &
                "' (mirror images do not carry a consistent strain rate)")
        if (trim(num%wall_extrapolation) == 'quadratic' .and. &
            trim(num%wall_model) /= 'morris') call grp%error('wall_extrapolation', &
                "'quadratic' works with wall_model = 'morris' only (the other models have " // &
                "no wall particles to give a velocity)")
        if (trim(num%wall_extrapolation) == 'quadratic' .and. &
            trim(num%viscosity_model) /= 'morris') call grp%error('wall_extrapolation', &
                "'quadratic' works with viscosity_model = 'morris' only (the curvature is " // &
                "the Laplacian of Morris' viscous term)")
        if (trim(num%density_filter) == 'shepard' .and. &
            trim(num%density_method) /= 'continuity') call grp%error('density_filter', &
                "'shepard' filters the integrated density; it works with density_method = " // &
                "'continuity' only")
        if (trim(num%shifting) /= 'none' .and. trim(num%wall_model) /= 'morris') &
            call grp%error('shifting', "'lind' works with wall_model = 'morris' only (the " // &
                "wall particles must fill the support to complete the concentration field)")
        if (trim(num%wall_pressure) /= 'continuity' .and. trim(num%wall_model) /= 'morris') &
            call grp%error('wall_pressure', "'extrapolated' works with wall_model = " // &
                "'morris' only (the other models have no wall particles in the sums)")
        call note_idle_numerics(grp, num)
    end subroutine read_numerics_input

    !> A note for each &numerics key given that the rest of the group makes idle (a
    !> repulsive wall's strength with Morris walls, ...): not errors, but a user who set
    !> one expected it to act.
    subroutine note_idle_numerics(grp, num)
        type(nml_group_t), intent(inout) :: grp
        type(numerics_input_t), intent(in) :: num
        character(len=*), parameter :: repulsive_keys(4) = [character(len=18) :: &
            'repulsive_strength', 'repulsive_r0', 'repulsive_n1', 'repulsive_n2']
        character(len=:), allocatable :: walls
        integer :: k
        walls = "(wall_model = '" // trim(num%wall_model) // "')"
        if (trim(num%wall_model) /= 'repulsive' .and. &
            trim(num%wall_model) /= 'repulsive_mirror') then
            do k = 1, size(repulsive_keys)
                call grp%note_if_given(trim(repulsive_keys(k)), 'it shapes the repulsive ' // &
                    "walls' force (eq. 2.18) " // walls)
            end do
        end if
        if (trim(num%wall_model) /= 'morris') then
            call grp%note_if_given('beta_max', "it caps Morris' wall velocity " // &
                'extrapolation ' // walls)
            call grp%note_if_given('wall_extrapolation', "it sets Morris' wall particles' " // &
                'velocities ' // walls)
            call grp%note_if_given('wall_pressure', "it sets Morris' wall particles' " // &
                'density ' // walls)
        end if
        if (trim(num%viscosity_model) /= 'morris') call grp%note_if_given( &
            'viscosity_normalisation', "it scales Morris' viscous term (viscosity_model = '" // &
            trim(num%viscosity_model) // "')")
        if (trim(num%density_filter) == 'none') call grp%note_if_given( &
            'density_filter_interval', "it spaces the Shepard filters (density_filter = 'none')")
        if (trim(num%shifting) == 'none') then
            call grp%note_if_given('shifting_coefficient', "it scales the particle shifting " // &
                "(shifting = 'none')")
            call grp%note_if_given('shifting_limit', "it caps the particle shifting " // &
                "(shifting = 'none')")
        end if
        if (.not. num%transport_velocity) call grp%note_if_given('transport_pressure', &
            'it is the transport velocity''s background pressure (transport_velocity = .false.)')
    end subroutine note_idle_numerics

    !> The transport-velocity formulation needs a density from the particles' positions (its
    !> background pressure acts on their arrangement), wall particles that fill the support
    !> and press back with the fluid's pressure (Adami et al. 2012, as in the 2013 paper),
    !> and does the work of particle shifting itself: other choices are refused, naming the key.
    subroutine check_transport_velocity(grp, num)
        type(nml_group_t), intent(inout) :: grp
        type(numerics_input_t), intent(in) :: num
        character(len=*), parameter :: tvf = 'transport_velocity = .true. needs '
        if (trim(num%density_method) /= 'summation') call grp%error('density_method', &
            "'" // trim(num%density_method) // "': " // tvf // "density_method = " // &
            "'summation' (the background pressure acts on the particles' arrangement)")
        if (trim(num%wall_model) /= 'morris') call grp%error('wall_model', "'" // &
            trim(num%wall_model) // "': " // tvf // "wall_model = 'morris' (wall " // &
            'particles that fill the support)')
        if (trim(num%wall_pressure) /= 'extrapolated') call grp%error('wall_pressure', &
            "'" // trim(num%wall_pressure) // "': " // tvf // "wall_pressure = " // &
            "'extrapolated' (the walls of Adami et al. 2012)")
        if (trim(num%shifting) /= 'none') call grp%error('shifting', "'" // &
            trim(num%shifting) // "' with transport_velocity = .true.: the transport " // &
            "velocity already keeps the particles evenly spread; use shifting = 'none'")
        if (trim(num%viscosity_model) /= 'morris') call grp%error('viscosity_model', "'" // &
            trim(num%viscosity_model) // "': " // tvf // "viscosity_model = 'morris'")
    end subroutine check_transport_velocity

    !> The transport velocity keeps the background pressure out of the momentum: it takes
    !> its own (&numerics transport_pressure), and a background in the equation of state
    !> (&fluid background_pressure) would push on the momentum as well, which the transport
    !> velocity does not balance (Poiseuille at L/20 with 10 Pa: 2.5e4 % off at 0.225 s,
    !> densities +-6 %, exit status 0; fz41).
    subroutine check_transport_background(fluid_grp, num, fl)
        type(nml_group_t), intent(inout) :: fluid_grp
        type(numerics_input_t), intent(in) :: num
        type(fluid_input_t), intent(in) :: fl
        if (.not. num%transport_velocity) return
        if (fl%background_pressure /= 0.0_wp) call fluid_grp%error('background_pressure', &
            real_text(fl%background_pressure) // ' Pa with &numerics transport_velocity = ' // &
            ".true.: the transport velocity takes its background pressure from &numerics " // &
            'transport_pressure and keeps it out of the momentum; a background in the ' // &
            'equation of state acts on the momentum, unbalanced: use background_pressure ' // &
            '= 0 (and transport_pressure for the background)')
    end subroutine check_transport_background

    !> Where walls of different velocities meet at a corner (a lid-driven cavity), the lid's
    !> velocity jump drags fluid into the downstream corner at every step. Only a density
    !> from the particles' positions (summation) stops a corner particle from being
    !> compressed without bound (an integrated density accumulates the jump), only wall
    !> particles that fill the corner (Morris) hold it there, and the fluid needs a
    !> background pressure, or the suction at the upstream corner pulls particles into the
    !> walls. Other choices are refused here, naming the key.
    subroutine check_moving_corners(num_grp, fluid_grp, dom, num, fl)
        type(nml_group_t), intent(inout) :: num_grp, fluid_grp
        type(domain_input_t), intent(in) :: dom
        type(numerics_input_t), intent(in) :: num
        type(fluid_input_t), intent(in) :: fl
        character(len=*), parameter :: where = ' where walls of different velocities ' // &
            'meet at a corner (&domain wall_velocity)'
        if (.not. (dom%corner_velocity_jump() > 0.0_wp)) return
        if (trim(num%wall_model) /= 'morris') call num_grp%error('wall_model', &
            "'" // trim(num%wall_model) // "' cannot hold the fluid" // where // &
            "; use 'morris' (wall particles that fill the corner)")
        if (trim(num%density_method) /= 'summation') call num_grp%error('density_method', &
            "'" // trim(num%density_method) // "' compresses the corner particles " // &
            'without bound' // where // "; use 'summation'")
        ! the transport velocity's background pressure keeps the particles off the walls
        if (trim(fl%eos) /= 'morris' .and. .not. (fl%background_pressure > 0.0_wp) .and. &
            .not. num%transport_velocity) &
            call fluid_grp%error('eos, background_pressure', "'" // trim(fl%eos) // &
            "' without a background pressure lets the fluid's tension pull particles " // &
            'into the walls' // where // "; use eos = 'morris' (p = c^2 rho), give " // &
            'background_pressure > 0 (a few rho0 U^2) or set &numerics ' // &
            'transport_velocity = .true.')
    end subroutine check_moving_corners
end module sph_physics_input
