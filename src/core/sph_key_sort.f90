!> Stable merge sort of indices by integer keys compared lexicographically (signed), shared by
!> the remeshing rules whose results must not depend on the storage order (sph_refine,
!> sph_coarsen) and the parallel sort of the global ids (sph_global_ids). An unsigned 64-bit
!> key u is given as ieor(u, ibset(0_i8, 63)).
module sph_key_sort
    use sph_kinds, only: i8
    implicit none
    private
    public :: sort_by_keys

contains

    !> Reorder o so that k(:, o) is ascending (first row first); ties keep their order.
    !> The keys travel with the indices through the merges (two buffers used in turn), so
    !> each merge reads and writes them in sequence: comparing through o, with k(:, o(a))
    !> fetched from anywhere in k, was a cache miss per comparison for the 10^5-10^6 keys of
    !> a remesh. Keys already in order (a remeshed set that comes in id order) cost one pass.
    subroutine sort_by_keys(k, o)
        integer(i8), intent(in) :: k(:, :)
        integer, intent(inout) :: o(:)
        integer(i8), allocatable :: keys_a(:, :), keys_b(:, :)
        integer, allocatable :: order_a(:), order_b(:)
        integer :: n, width, c
        logical :: result_in_a
        n = size(o)
        if (n < 2) return
        do c = 2, n
            if (less(k(:, o(c)), k(:, o(c - 1)))) exit
        end do
        if (c > n) return
        keys_a = k(:, o)
        order_a = o
        allocate(keys_b(size(k, 1), n), order_b(n))
        width = 1
        result_in_a = .true.
        do while (width < n)
            if (result_in_a) then
                call merge_runs(keys_a, order_a, keys_b, order_b)
            else
                call merge_runs(keys_b, order_b, keys_a, order_a)
            end if
            result_in_a = .not. result_in_a
            width = 2 * width
        end do
        if (result_in_a) then
            o = order_a
        else
            o = order_b
        end if
    contains
        !> One bottom-up pass: the sorted runs of `width` in (ks, os) merged pairwise into
        !> (kd, od).
        subroutine merge_runs(ks, os, kd, od)
            integer(i8), intent(in) :: ks(:, :)
            integer, intent(in) :: os(:)
            integer(i8), intent(inout) :: kd(:, :)
            integer, intent(inout) :: od(:)
            integer :: lo, mid, hi, a, b, c
            lo = 1
            do while (lo <= n)
                mid = min(lo + width - 1, n)
                hi = min(lo + 2 * width - 1, n)
                a = lo
                b = mid + 1
                do c = lo, hi
                    if (b > hi) then
                        kd(:, c) = ks(:, a); od(c) = os(a); a = a + 1
                    else if (a > mid) then
                        kd(:, c) = ks(:, b); od(c) = os(b); b = b + 1
                    else if (less(ks(:, b), ks(:, a))) then
                        kd(:, c) = ks(:, b); od(c) = os(b); b = b + 1
                    else
                        kd(:, c) = ks(:, a); od(c) = os(a); a = a + 1
                    end if
                end do
                lo = hi + 1
            end do
        end subroutine merge_runs
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
