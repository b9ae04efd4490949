!> Equations of state for a weakly compressible fluid, and Morris' choice of sound speed.
module sph_eos
    use sph_kinds, only: wp
    implicit none
    private
    public :: EOS_MORRIS, EOS_MORRIS_RELATIVE, EOS_TAIT, eos_id_from_name, eos_pressure
    public :: eos_density, eos_pressure_many
    public :: morris_sound_speed

    integer, parameter :: EOS_MORRIS = 1           !< p = c^2 rho (Morris et al. 1997)
    integer, parameter :: EOS_MORRIS_RELATIVE = 2  !< p = c^2 (rho - rho0)
    integer, parameter :: EOS_TAIT = 3             !< p = c^2 rho0 / gamma ((rho/rho0)^gamma - 1)

contains

    !> The EOS_* id of an &fluid eos name (0 when unknown).
    integer function eos_id_from_name(name)
        character(len=*), intent(in) :: name
        select case (trim(name))
        case ('morris'); eos_id_from_name = EOS_MORRIS
        case ('morris_relative'); eos_id_from_name = EOS_MORRIS_RELATIVE
        case ('tait'); eos_id_from_name = EOS_TAIT
        case default; eos_id_from_name = 0
        end select
    end function eos_id_from_name

    !> Pressure (Pa) of density rho (kg/m^3) by the equation of state `id`, with the rest
    !> density rho0, sound speed c (m/s) and Tait exponent gamma.
    pure elemental real(wp) function eos_pressure(id, rho, rho0, c, gamma)
        integer, intent(in) :: id
        real(wp), intent(in) :: rho, rho0, c, gamma
        select case (id)
        case (EOS_MORRIS_RELATIVE)
            eos_pressure = c * c * (rho - rho0)
        case (EOS_TAIT)
            eos_pressure = c * c * rho0 / gamma * ((rho / rho0)**gamma - 1.0_wp)
        case default
            eos_pressure = c * c * rho
        end select
    end function eos_pressure

    !> p(k) = eos_pressure(id, rho(k), rho0, c, gamma) + offset for every k, the form chosen
    !> once so that the loop vectorises (every particle at every rate evaluation).
    pure subroutine eos_pressure_many(id, rho, rho0, c, gamma, offset, p)
        integer, intent(in) :: id
        real(wp), intent(in) :: rho(:), rho0, c, gamma, offset
        real(wp), intent(out) :: p(:)
        real(wp) :: c2
        c2 = c * c
        select case (id)
        case (EOS_MORRIS_RELATIVE)
            p = c2 * (rho - rho0) + offset
        case (EOS_TAIT)
            p = c2 * rho0 / gamma * ((rho / rho0)**gamma - 1.0_wp) + offset
        case default
            p = c2 * rho + offset
        end select
    end subroutine eos_pressure_many

    !> The density of a pressure: the inverse of eos_pressure. Tait densities are kept
    !> positive (a tension beyond -c^2 rho0 / gamma has no Tait density).
    pure elemental real(wp) function eos_density(id, p, rho0, c, gamma)
        integer, intent(in) :: id
        real(wp), intent(in) :: p, rho0, c, gamma
        select case (id)
        case (EOS_MORRIS_RELATIVE)
            eos_density = rho0 + p / (c * c)
        case (EOS_TAIT)
            eos_density = rho0 * max(1.0e-3_wp, 1.0_wp + gamma * p / (c * c * rho0)) &
                **(1.0_wp / gamma)
        case default
            eos_density = p / (c * c)
        end select
    end function eos_density

    !> Morris et al. (1997): keep density variations near delta by
    !> c^2 >= max(V^2, nu V / L, F L) / delta.
    pure real(wp) function morris_sound_speed(velocity, nu, length, force, delta)
        real(wp), intent(in) :: velocity, nu, length, force, delta
        morris_sound_speed = sqrt(max(velocity**2, nu * velocity / length, force * length) / delta)
    end function morris_sound_speed
end module sph_eos
