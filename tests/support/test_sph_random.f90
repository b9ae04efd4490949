!> Deterministic pseudo-random numbers for tests (xorshift64*): the same sequence on every
!> rank, compiler and rank count, so each rank can build the same global particle set.
module test_sph_random
    use sph_kinds, only: wp, i8
    implicit none
    private
    public :: random_points, random_uniform

contains

    !> Uniform number in [0, 1) from a state that is advanced.
    real(wp) function random_uniform(state)
        integer(i8), intent(inout) :: state
        integer(i8) :: mixed
        state = ieor(state, shiftl(state, 13))
        state = ieor(state, shiftr(state, 7))
        state = ieor(state, shiftl(state, 17))
        mixed = shiftr(state, 11)
        random_uniform = real(mixed, wp) * 2.0_wp**(-53)
    end function random_uniform

    !> n points uniform in the box [lo, hi] (first dim coordinates; the rest 0).
    subroutine random_points(n, dim, lo, hi, seed, x)
        integer, intent(in) :: n, dim
        real(wp), intent(in) :: lo(3), hi(3)
        integer(i8), intent(in) :: seed
        real(wp), allocatable, intent(out) :: x(:, :)
        integer(i8) :: state
        integer :: i, a
        allocate(x(3, n))
        x = 0.0_wp
        state = seed
        do i = 1, n
            do a = 1, dim
                x(a, i) = lo(a) + (hi(a) - lo(a)) * random_uniform(state)
            end do
        end do
    end subroutine random_points
end module test_sph_random
