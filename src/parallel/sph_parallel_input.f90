!> Load balancing as read from input (&parallel); used by the driver with sph_domain.
module sph_parallel_input
    use sph_kinds, only: wp
    use sph_namelist, only: nml_group_t
    implicit none
    private
    public :: parallel_input_t, read_parallel_input

    type :: parallel_input_t
        real(wp) :: rebalance_threshold
        integer :: rebalance_check_interval
    end type parallel_input_t

contains

    !> Read the &parallel group (rebalancing threshold and interval).
    subroutine read_parallel_input(grp, par)
        type(nml_group_t), intent(inout) :: grp
        type(parallel_input_t), intent(out) :: par
        call grp%get_real('rebalance_threshold', par%rebalance_threshold, 1.1_wp, &
            min=1.0_wp, doc='rebalance when max/mean particles per rank exceeds this')
        call grp%get_int('rebalance_check_interval', par%rebalance_check_interval, 50, &
            min=1, unit='steps', doc='steps between imbalance checks')
    end subroutine read_parallel_input
end module sph_parallel_input
