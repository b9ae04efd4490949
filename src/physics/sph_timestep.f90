!> Time-step limits (thesis eqs. 4.1-4.3 with Morris' safety factors):
!>   CFL      dt <= C_cfl h / (c + |v|max)
!>   viscous  dt <= C_nu h^2 / nu
!>   force    dt <= C_f sqrt(h / |f|max)
module sph_timestep
    use sph_kinds, only: wp
    implicit none
    private
    public :: timestep_limits_t, timestep_limits, level_substeps

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

    !> Sub-cycling: the steps of the finest level each level's step spans, for levels
    !> 0 (coarsest) .. n - 1 (finest, 1): the largest power of two, at most max_subcycles, whose
    !> multiple of dt (the finest level's step) stays within the level's own limit, and never
    !> fewer than the next finer level's (so every level's step ends where finer ones do).
    pure function level_substeps(dt, level_limit, max_subcycles) result(k)
        real(wp), intent(in) :: dt
        real(wp), intent(in) :: level_limit(0:)   !< each level's stable step (s)
        integer, intent(in) :: max_subcycles
        integer :: k(0:size(level_limit) - 1)
        integer :: lv, finest
        finest = size(level_limit) - 1
        k(finest) = 1
        do lv = finest - 1, 0, -1
            k(lv) = k(lv + 1)
            do while (2 * k(lv) <= max_subcycles .and. real(2 * k(lv), wp) * dt <= &
                level_limit(lv))
                k(lv) = 2 * k(lv)
            end do
        end do
    end function level_substeps
end module sph_timestep
