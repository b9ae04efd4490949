!> Analytic solutions for the channel flows started from rest (Morris et al. 1997; thesis
!> eqs. 4.4 and 4.5, the latter with its sign slips corrected):
!>   Couette    v(y,t) = V y/L + sum_{n>=1} 2V/(n pi) (-1)^n sin(n pi y/L) exp(-nu n^2 pi^2 t/L^2)
!>   Poiseuille v(y,t) = F/(2 nu) y (L - y)
!>                     - sum_{n>=0} 4 F L^2/(nu pi^3 (2n+1)^3) sin((2n+1) pi y/L)
!>                                  exp(-(2n+1)^2 pi^2 nu t/L^2)
!> y is measured from the lower wall; t > 1e30 gives the steady state.
!> A profile at one time (channel_series_t) holds each term's coefficient times its decay, so
!> that many heights (every particle of a snapshot) cost no exponential each, and the sines
!> of the multiples of pi y/L come by the recurrence sin((m+d) a) = 2 cos(d a) sin(m a)
!> - sin((m-d) a) rather than a library call each: at 10^6 particles the two were a third
!> of a snapshot's cost. The series stops after the first term whose decay is below 1e-18.
module sph_analytic
    use sph_kinds, only: wp
    implicit none
    private
    public :: channel_series_t, poiseuille_series, couette_series, series_velocity

    real(wp), parameter :: pi = acos(-1.0_wp)
    integer, parameter :: max_terms = 100000
    real(wp), parameter :: steady_time = 1.0e30_wp  !< beyond this, the steady profile
    real(wp), parameter :: last_decay = 1.0e-18_wp  !< the series ends with the first term below

    !> A channel profile at one time (poiseuille_series, couette_series).
    type :: channel_series_t
        logical :: poiseuille = .true.  !< odd multiples (Poiseuille) or all (Couette)
        logical :: at_rest = .false.    !< t <= 0: the fluid at rest
        real(wp) :: width = 1.0_wp      !< L
        real(wp) :: scale = 0.0_wp      !< F / (2 nu) (Poiseuille) or V / L (Couette)
        !> term by term: the coefficient times its decay (Poiseuille's with the minus sign)
        real(wp), allocatable :: coefficient(:)
    end type channel_series_t

contains

    !> Poiseuille flow started from rest (module header) at time t, driven by the body force
    !> `force` (m/s^2) between walls `width` apart.
    pure function poiseuille_series(t, force, width, nu) result(series)
        real(wp), intent(in) :: t, force, width, nu
        type(channel_series_t) :: series
        series = channel_series(.true., t, force, width, nu)
    end function poiseuille_series

    !> Couette flow started from rest (module header) at time t between a wall at rest and
    !> one moving at wall_speed (m/s), `width` apart.
    pure function couette_series(t, wall_speed, width, nu) result(series)
        real(wp), intent(in) :: t, wall_speed, width, nu
        type(channel_series_t) :: series
        series = channel_series(.false., t, wall_speed, width, nu)
    end function couette_series

    !> Either profile: the term of multiple m (odd for Poiseuille, from 1) decays as
    !> exp(-(m pi / L)^2 nu t) and has the coefficient -4 F L^2 / (nu pi^3 m^3) (Poiseuille,
    !> amplitude F) or 2 V (-1)^m / (m pi) (Couette, amplitude V).
    pure function channel_series(poiseuille, t, amplitude, width, nu) result(series)
        logical, intent(in) :: poiseuille
        real(wp), intent(in) :: t, amplitude, width, nu
        type(channel_series_t) :: series
        integer :: n, n_last
        series%poiseuille = poiseuille
        series%width = width
        if (poiseuille) then
            series%scale = amplitude / (2.0_wp * nu)
        else
            series%scale = amplitude / width
        end if
        series%at_rest = t <= 0.0_wp
        n_last = 0
        if (t <= steady_time .and. .not. series%at_rest) then
            do n = 1, max_terms
                n_last = n
                if (decay(multiple(n)) < last_decay) exit
            end do
        end if
        allocate(series%coefficient(n_last))
        do n = 1, n_last
            if (poiseuille) then
                series%coefficient(n) = -4.0_wp * amplitude * width**2 / &
                    (nu * pi**3 * real(multiple(n), wp)**3) * decay(multiple(n))
            else
                series%coefficient(n) = 2.0_wp * amplitude / (n * pi) * (-1.0_wp)**n * &
                    decay(n)
            end if
        end do
    contains
        !> the multiple of pi y / L in the n-th term
        pure integer function multiple(n)
            integer, intent(in) :: n
            multiple = n
            if (poiseuille) multiple = 2 * n - 1
        end function multiple
        pure real(wp) function decay(m)
            integer, intent(in) :: m
            decay = exp(-(m * pi / width)**2 * nu * t)
        end function decay
    end function channel_series

    !> The profile's velocity at height y (from the resting or lower wall).
    pure real(wp) function series_velocity(series, y) result(v)
        type(channel_series_t), intent(in) :: series
        real(wp), intent(in) :: y
        real(wp) :: a, twice_cos, s, s_before, s_next
        integer :: n
        if (series%at_rest) then
            ! the series converges to 0 in the interior at t = 0 (fluid at rest)
            v = 0.0_wp
            return
        end if
        a = pi * y / series%width
        if (series%poiseuille) then
            v = series%scale * y * (series%width - y)
            ! sin(k a) for k = 1, 3, 5, ...: step 2, from sin(-a) and sin(a)
            twice_cos = 2.0_wp * cos(2.0_wp * a)
            s_before = -sin(a)
        else
            v = series%scale * y
            ! sin(n a) for n = 1, 2, 3, ...: step 1, from sin(0) and sin(a)
            twice_cos = 2.0_wp * cos(a)
            s_before = 0.0_wp
        end if
        s = sin(a)
        do n = 1, size(series%coefficient)
            v = v + series%coefficient(n) * s
            s_next = twice_cos * s - s_before
            s_before = s
            s = s_next
        end do
    end function series_velocity
end module sph_analytic
