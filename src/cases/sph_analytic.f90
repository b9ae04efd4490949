!> Analytic solutions for the channel flows started from rest (Morris et al. 1997; thesis
!> eqs. 4.4 and 4.5, the latter with its sign slips corrected):
!>   Couette    v(y,t) = V y/L + sum_{n>=1} 2V/(n pi) (-1)^n sin(n pi y/L) exp(-nu n^2 pi^2 t/L^2)
!>   Poiseuille v(y,t) = F/(2 nu) y (L - y)
!>                     - sum_{n>=0} 4 F L^2/(nu pi^3 (2n+1)^3) sin((2n+1) pi y/L)
!>                                  exp(-(2n+1)^2 pi^2 nu t/L^2)
!> y is measured from the lower wall; t > 1e30 gives the steady state.
module sph_analytic
    use sph_kinds, only: wp
    implicit none
    private
    public :: couette_velocity, poiseuille_velocity

    real(wp), parameter :: pi = acos(-1.0_wp)
    integer, parameter :: max_terms = 100000
    real(wp), parameter :: steady_time = 1.0e30_wp  !< beyond this, the steady profile

contains

    !> Couette flow started from rest (module header): velocity at height y and time t between
    !> a wall at rest and one moving at wall_speed (m/s), `width` apart.
    pure elemental real(wp) function couette_velocity(y, t, wall_speed, width, nu)
        real(wp), intent(in) :: y, t, wall_speed, width, nu
        real(wp) :: decay, term
        integer :: n
        couette_velocity = wall_speed * y / width
        if (t > steady_time) return
        if (t <= 0.0_wp) then
            ! the series converges to 0 in the interior at t = 0 (fluid at rest)
            couette_velocity = 0.0_wp
            return
        end if
        do n = 1, max_terms
            decay = exp(-nu * (n * pi / width)**2 * t)
            term = 2.0_wp * wall_speed / (n * pi) * (-1.0_wp)**n * sin(n * pi * y / width) * decay
            couette_velocity = couette_velocity + term
            if (decay < 1.0e-18_wp) exit
        end do
    end function couette_velocity

    !> Poiseuille flow started from rest (module header): velocity at height y and time t
    !> driven by the body force `force` (m/s^2) between walls `width` apart.
    pure elemental real(wp) function poiseuille_velocity(y, t, force, width, nu)
        real(wp), intent(in) :: y, t, force, width, nu
        real(wp) :: decay, k
        integer :: n
        poiseuille_velocity = force / (2.0_wp * nu) * y * (width - y)
        if (t > steady_time) return
        if (t <= 0.0_wp) then
            poiseuille_velocity = 0.0_wp
            return
        end if
        do n = 0, max_terms
            k = real(2 * n + 1, wp)
            decay = exp(-(k * pi / width)**2 * nu * t)
            poiseuille_velocity = poiseuille_velocity - 4.0_wp * force * width**2 / &
                (nu * pi**3 * k**3) * sin(k * pi * y / width) * decay
            if (decay < 1.0e-18_wp) exit
        end do
    end function poiseuille_velocity
end module sph_analytic
