!> Run-time health checks as read from input (&health); used by sph_health.
module sph_health_input
    use sph_kinds, only: wp
    use sph_namelist, only: nml_group_t
    implicit none
    private
    public :: health_input_t, read_health_input

    type :: health_input_t
        real(wp) :: density_band         !< fluid density must stay within rho0 (1 +- band)
        real(wp) :: timestep_floor       !< dt must stay above this fraction of the first dt
    end type health_input_t

contains

    !> Read the &health group (the density band and the time-step floor that stop a run).
    subroutine read_health_input(grp, health)
        type(nml_group_t), intent(inout) :: grp
        type(health_input_t), intent(out) :: health
        call grp%get_real('density_band', health%density_band, 0.5_wp, &
            min_exclusive=0.0_wp, doc='stop when a fluid density leaves rho0 (1 +- band)')
        call grp%get_real('timestep_floor', health%timestep_floor, 1.0e-3_wp, &
            min=0.0_wp, max_exclusive=1.0_wp, &
            doc='stop when the time step falls below this fraction of the first one; 0 = off')
    end subroutine read_health_input
end module sph_health_input
