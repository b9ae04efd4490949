!> Analytic reference solutions selected by &run analytic ('none', 'poiseuille', 'couette'),
!> made once at set-up from the configuration. The channel is found from the boundaries
!> (sph_domain_input find_analytic_channel, the same rule the input check applies): the wall
!> normal is the axis whose two faces are walls, the flow runs along the body force or the
!> moving wall's velocity. The problem is linear, so a Couette channel with a body force along
!> the flow (Couette-Poiseuille) has the sum of both series as its exact solution. No MPI
!> here: the driver sums the partial error sums over ranks.
module sph_reference
    use sph_kinds, only: wp
    use sph_config, only: config_t
    use sph_domain_input, only: channel_t, find_analytic_channel
    use sph_particles, only: particles_t, KIND_FLUID
    use sph_analytic, only: channel_series_t, couette_series, poiseuille_series, series_velocity
    use sph_logger, only: fixed_text
    implicit none
    private
    public :: reference_t, reference_from_config, velocity, relative_l2_error, steady_after
    public :: relative_l2_from_sums, reference_resolved, UNRESOLVED, error_percent_text

    !> simulation_analytic_error's value for a reference below its round-off
    real(wp), parameter :: UNRESOLVED = -2.0_wp

    integer, parameter :: name_len = 32

    type :: reference_t
        character(len=name_len) :: name = 'none'
        integer :: normal_axis = 2       !< wall-normal axis of the channel
        integer :: flow_axis = 1         !< axis the flow runs along
        real(wp) :: lo = 0.0_wp          !< the walls' positions on the normal axis
        real(wp) :: hi = 0.0_wp
        real(wp) :: width = 0.0_wp       !< hi - lo
        logical :: lower_moves = .false. !< Couette: the wall at lo moves (distance from hi)
        real(wp) :: wall_speed = 0.0_wp  !< Couette: moving wall's velocity along the flow
        real(wp) :: force = 0.0_wp       !< body force along the flow
        real(wp) :: nu = 0.0_wp          !< kinematic viscosity
    end type reference_t

    !> The exact profile at some time: the moving wall's part and the body force's
    type :: profiles_t
        type(channel_series_t) :: drag, push
        logical :: with_drag = .false., with_push = .false.
    end type profiles_t

contains

    !> The reference for a configuration; stat /= 0 (with errmsg) when &run analytic names a
    !> solution the case is not the channel of (the input check refuses such input first).
    subroutine reference_from_config(cfg, ref, stat, errmsg)
        type(config_t), intent(in) :: cfg
        type(reference_t), intent(out) :: ref
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: errmsg
        type(channel_t) :: channel
        stat = 0
        errmsg = ''
        ref%name = cfg%run%analytic
        if (trim(ref%name) == 'none') return
        call find_analytic_channel(trim(ref%name), cfg%domain, cfg%fluid%body_force, channel, &
            errmsg)
        if (len(errmsg) > 0) then
            stat = 1
            errmsg = '&run analytic: ' // errmsg
            ref%name = 'none'
            return
        end if
        ref%normal_axis = channel%normal_axis
        ref%flow_axis = channel%flow_axis
        ref%lo = cfg%domain%box_lo(ref%normal_axis)
        ref%hi = cfg%domain%box_hi(ref%normal_axis)
        ref%width = cfg%domain%box_hi(ref%normal_axis) - cfg%domain%box_lo(ref%normal_axis)
        ref%lower_moves = channel%moving_face == 2*ref%normal_axis - 1
        if (channel%moving_face /= 0) &
            ref%wall_speed = cfg%domain%wall_velocity(ref%flow_axis, channel%moving_face)
        ref%force = cfg%fluid%body_force(ref%flow_axis)
        ref%nu = cfg%fluid%nu
    end subroutine reference_from_config

    !> The exact velocity at point x and time t (t = huge(1.0_wp): the steady profile);
    !> zero for 'none'.
    pure function velocity(ref, x, t) result(exact)
        type(reference_t), intent(in) :: ref
        real(wp), intent(in) :: x(:), t
        real(wp) :: exact(3)
        exact = velocity_on(ref, profile_at(ref, t), x)
    end function velocity

    !> The channel's profile at time t (sph_analytic): the moving wall's series and the body
    !> force's, each where it drives the flow (a Couette reference with a body force along
    !> the flow was the wall's part alone, 37 % off a Couette-Poiseuille flow that the run
    !> got right); nothing for 'none'.
    pure function profile_at(ref, t) result(profile)
        type(reference_t), intent(in) :: ref
        real(wp), intent(in) :: t
        type(profiles_t) :: profile
        if (trim(ref%name) == 'none') return
        profile%with_drag = ref%wall_speed /= 0.0_wp
        profile%with_push = ref%force /= 0.0_wp
        if (profile%with_drag) profile%drag = couette_series(t, ref%wall_speed, ref%width, ref%nu)
        if (profile%with_push) profile%push = poiseuille_series(t, ref%force, ref%width, ref%nu)
    end function profile_at

    !> The exact velocity at point x on the profile of some time (profile_at).
    pure function velocity_on(ref, profile, x) result(exact)
        type(reference_t), intent(in) :: ref
        type(profiles_t), intent(in) :: profile
        real(wp), intent(in) :: x(:)
        real(wp) :: exact(3)
        real(wp) :: y
        exact = 0.0_wp
        if (profile%with_drag) then
            ! distance from the resting wall
            if (ref%lower_moves) then
                y = ref%hi - x(ref%normal_axis)
            else
                y = x(ref%normal_axis) - ref%lo
            end if
            exact(ref%flow_axis) = series_velocity(profile%drag, y)
        end if
        if (profile%with_push) exact(ref%flow_axis) = exact(ref%flow_axis) + &
            series_velocity(profile%push, x(ref%normal_axis) - ref%lo)
    end function velocity_on

    !> This rank's partial sums of the relative L2 velocity error over its owned fluid
    !> particles at time (steady: against the steady profile): [sum |v - exact|^2,
    !> sum |exact|^2]. Sum them over ranks, then relative_l2_from_sums.
    pure function relative_l2_error(ref, p, time, steady) result(sums)
        type(reference_t), intent(in) :: ref
        type(particles_t), intent(in) :: p
        real(wp), intent(in) :: time
        logical, intent(in) :: steady
        real(wp) :: sums(2)
        real(wp) :: exact(3), t
        type(profiles_t) :: profile
        integer :: i
        t = time
        if (steady) t = huge(1.0_wp)
        sums = 0.0_wp
        ! the profile's terms once, for every particle
        profile = profile_at(ref, t)
        do i = 1, p%n_owned
            if (p%kind(i) /= KIND_FLUID) cycle
            exact = velocity_on(ref, profile, p%x(:, i))
            sums(1) = sums(1) + sum((p%v(:, i) - exact)**2)
            sums(2) = sums(2) + sum(exact**2)
        end do
    end function relative_l2_error

    !> sqrt(sums(1) / sums(2)) for the global sums; the absolute norm when the exact field is 0.
    pure real(wp) function relative_l2_from_sums(sums) result(error)
        real(wp), intent(in) :: sums(2)
        if (sums(2) > 0.0_wp) then
            error = sqrt(sums(1) / sums(2))
        else
            error = sqrt(sums(1))
        end if
    end function relative_l2_from_sums

    !> Whether exact velocities of root mean square rms_exact (over the fluid particles) lie
    !> above the series' round-off: each series is a steady profile of the channel's peak
    !> speed less its decaying terms, which cancel it down to the flow of the first moments
    !> with a round-off of 1e-16 of that peak per term. Below 1e-8 of the peak there was no
    !> error figure to give (Couette at nu t / L^2 = 1e-6: 1.3e14 %; Poiseuille at 1e-16:
    !> 26 % for velocities exactly F t, fz32).
    pure logical function reference_resolved(ref, rms_exact) result(resolved)
        type(reference_t), intent(in) :: ref
        real(wp), intent(in) :: rms_exact
        real(wp) :: peak
        peak = abs(ref%wall_speed)
        if (ref%nu > 0.0_wp) peak = max(peak, abs(ref%force) * ref%width**2 / (8.0_wp * ref%nu))
        resolved = rms_exact >= 1.0e-8_wp * peak
    end function reference_resolved

    !> A relative error as a percentage in fixed_text's width and decimals, or what
    !> UNRESOLVED means.
    function error_percent_text(error, width, decimals) result(text)
        real(wp), intent(in) :: error
        integer, intent(in) :: width, decimals
        character(len=:), allocatable :: text
        if (error == UNRESOLVED) then
            text = "n/a (the analytic velocity is still below its series' round-off)"
        else
            text = fixed_text(100.0_wp * error, width, decimals) // ' %'
        end if
    end function error_percent_text

    !> The time after which the steady profile is a meaningful reference: a few viscous
    !> times, 5 L^2/(pi^2 nu). huge for 'none'.
    pure real(wp) function steady_after(ref)
        type(reference_t), intent(in) :: ref
        steady_after = huge(1.0_wp)
        if (trim(ref%name) == 'none') return
        steady_after = 5.0_wp * ref%width**2 / (acos(-1.0_wp)**2 * ref%nu)
    end function steady_after
end module sph_reference
