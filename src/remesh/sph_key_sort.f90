!> Stable merge sort of indices by integer keys compared lexicographically (signed), shared by
!> the remeshing rules whose results must not depend on the storage order (sph_refine,
!> sph_coarsen). An unsigned 64-bit key u is given as ieor(u, ibset(0_i8, 63)).
module sph_key_sort
    use sph_kinds, only: i8
    implicit none
    private
    public :: sort_by_keys

contains

    !> Reorder o so that k(:, o) is ascending (first row first); ties keep their order.
    subroutine sort_by_keys(k, o)
        integer(i8), intent(in) :: k(:, :)
        integer, intent(inout) :: o(:)
        integer :: tmp(size(o)), width, lo, mid, hi, a, b, c
        width = 1
        do while (width < size(o))
            lo = 1
            do while (lo <= size(o))
                mid = min(lo + width - 1, size(o))
                hi = min(lo + 2 * width - 1, size(o))
                a = lo; b = mid + 1; c = lo
                do while (c <= hi)
                    if (b > hi) then
                        tmp(c) = o(a); a = a + 1
                    else if (a > mid) then
                        tmp(c) = o(b); b = b + 1
                    else if (less(k(:, o(b)), k(:, o(a)))) then
                        tmp(c) = o(b); b = b + 1
                    else
                        tmp(c) = o(a); a = a + 1
                    end if
                    c = c + 1
                end do
                lo = hi + 1
            end do
            o = tmp
            width = 2 * width
        end do
    end subroutine sort_by_keys

    pure logical function less(p, q)
        integer(i8), intent(in) :: p(:), q(:)
        integer :: r
        less = .false.
        do r = 1, size(p)
            if (p(r) /= q(r)) then
                less = p(r) < q(r)
                return
            end if
        end do
    end function less
end module sph_key_sort
