!> Time-step limits (thesis eqs. 4.1-4.3 with Morris' safety factors):
!>   CFL      dt <= C_cfl h / (c + |v|max)
!>   viscous  dt <= C_nu h^2 / nu
!>   force    dt <= C_f sqrt(h / |f|max)
module sph_timestep
    use sph_kinds, only: wp
    implicit none
    private
    public :: timestep_limits_t, timestep_limits

    type :: timestep_limits_t
        real(wp) :: cfl = huge(1.0_wp)
        real(wp) :: viscous = huge(1.0_wp)
        real(wp) :: force = huge(1.0_wp)
        real(wp) :: dt = huge(1.0_wp)      !< the smallest of the three
        real(wp) :: max_speed = 0.0_wp     !< the flow's largest speed and acceleration used
        real(wp) :: max_accel = 0.0_wp
    end type timestep_limits_t

contains

    !> The stable time step and its three limits (Morris et al. 1997): CFL h/(c + vmax),
    !> viscous h^2/nu and force sqrt(h/amax), each with its safety factor.
    pure function timestep_limits(h, c, max_speed, nu, max_accel, cfl, viscous_safety, &
                                  force_safety) result(lim)
        real(wp), intent(in) :: h, c, max_speed, nu, max_accel, cfl, viscous_safety, force_safety
        type(timestep_limits_t) :: lim
        lim%cfl = cfl * h / (c + max_speed)
        if (nu > 0.0_wp) lim%viscous = viscous_safety * h * h / nu
        if (max_accel > 0.0_wp) lim%force = force_safety * sqrt(h / max_accel)
        lim%dt = min(lim%cfl, lim%viscous, lim%force)
        lim%max_speed = max_speed
        lim%max_accel = max_accel
    end function timestep_limits
end module sph_timestep
