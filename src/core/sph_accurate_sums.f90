!> Compensated summation (Neumaier): sums of many values exact to about one rounding whatever
!> their count, for totals that are logged as conserved or that set a correction (a remesh's
!> totals, the multi-resolution levels' real mass). Summed one by one, 10^6 equal masses came
!> out 1.7e-11 (3D) and 3.8e-12 (2D) off their total, and a remesh that conserves to 1e-15
!> was logged as changing the mass by that.
module sph_accurate_sums
    use sph_kinds, only: wp
    implicit none
    private
    public :: accurate_add, accurate_sum

contains

    !> sum + x with the rounding error of the addition kept in lost (the result is sum +
    !> lost).
    pure subroutine accurate_add(sum, lost, x)
        real(wp), intent(inout) :: sum, lost
        real(wp), intent(in) :: x
        real(wp) :: t
        t = sum + x
        if (abs(sum) >= abs(x)) then
            lost = lost + ((sum - t) + x)
        else
            lost = lost + ((x - t) + sum)
        end if
        sum = t
    end subroutine accurate_add

    !> The sum of values, compensated (accurate_add).
    pure real(wp) function accurate_sum(values) result(total)
        real(wp), intent(in) :: values(:)
        real(wp) :: lost
        integer :: i
        total = 0.0_wp
        lost = 0.0_wp
        do i = 1, size(values)
            call accurate_add(total, lost, values(i))
        end do
        total = total + lost
    end function accurate_sum
end module sph_accurate_sums
