!> Stable sort of indices by integer keys compared lexicographically (signed), shared by
!> the remeshing rules whose results must not depend on the storage order (sph_refine,
!> sph_coarsen), the parallel sort of the global ids (sph_global_ids) and the id order of a
!> particle set (id_order). An unsigned 64-bit key u is given as ieor(u, ibset(0_i8, 63)).
module sph_key_sort
    use sph_kinds, only: i8
    implicit none
    private
    public :: sort_by_keys, id_order

    !> Flipped in every key for the radix passes: unsigned digits then sort in signed order.
    integer(i8), parameter :: SIGN_BIT = ishft(1_i8, 63)

contains

    !> Reorder o so that k(:, o) is ascending (first row first); ties keep their order.
    !> A least-significant-digit radix sort (stable): the rows from the last to the first,
    !> each in digits of DIGIT_BITS bits from the lowest, the sign bit flipped so that the
    !> unsigned digits give the signed order. A digit that is the same for every key (the
    !> high digits of ids, a flag row) costs one histogram and no pass. The keys travel with
    !> the indices (two buffers used in turn), so each pass reads them in sequence. A merge
    !> sort took 17 % of a refinement's positions (19 passes of branchy comparisons over
    !> 4 x 10^5 keys); this is a few passes. Keys already in order (a remeshed set that comes
    !> in id order) cost one comparison pass.
    subroutine sort_by_keys(k, o)
        integer(i8), intent(in) :: k(:, :)
        integer, intent(inout) :: o(:)
        integer, parameter :: DIGIT_BITS = 11, BUCKETS = 2**DIGIT_BITS
        integer, parameter :: DIGITS = 6   ! 64 bits in DIGIT_BITS-bit digits, the last of 9
        integer(i8), allocatable :: keys_a(:, :), keys_b(:, :)
        integer, allocatable :: order_a(:), order_b(:), tally(:, :)
        integer :: n, rows, c, r, d, width
        logical :: result_in_a
        n = size(o)
        if (n < 2) return
        do c = 2, n
            if (less(k(:, o(c)), k(:, o(c - 1)))) exit
        end do
        if (c > n) return
        rows = size(k, 1)
        allocate(keys_a(rows, n), keys_b(rows, n), order_a(n), order_b(n))
        allocate(tally(0:BUCKETS, DIGITS))
        do c = 1, n
            keys_a(:, c) = ieor(k(:, o(c)), SIGN_BIT)
        end do
        order_a = o
        result_in_a = .true.
        do r = rows, 1, -1
            ! every digit's histogram of this row in one pass
            tally = 0
            if (result_in_a) then
                call histograms(keys_a)
            else
                call histograms(keys_b)
            end if
            do d = 1, DIGITS
                width = min(DIGIT_BITS, 64 - (d - 1) * DIGIT_BITS)
                if (maxval(tally(1:BUCKETS, d)) == n) cycle
                if (result_in_a) then
                    call scatter(keys_a, order_a, keys_b, order_b)
                else
                    call scatter(keys_b, order_b, keys_a, order_a)
                end if
                result_in_a = .not. result_in_a
            end do
        end do
        if (result_in_a) then
            o = order_a
        else
            o = order_b
        end if
    contains
        !> tally(1 + v, d): keys of row r whose digit d is v.
        subroutine histograms(ks)
            integer(i8), intent(in) :: ks(:, :)
            integer :: i, dd, v
            do i = 1, n
                do dd = 1, DIGITS
                    v = int(ibits(ks(r, i), (dd - 1) * DIGIT_BITS, &
                        min(DIGIT_BITS, 64 - (dd - 1) * DIGIT_BITS)))
                    tally(1 + v, dd) = tally(1 + v, dd) + 1
                end do
            end do
        end subroutine histograms

        !> One stable pass by digit d of row r: (ks, os) into (kd, od).
        subroutine scatter(ks, os, kd, od)
            integer(i8), intent(in) :: ks(:, :)
            integer, intent(in) :: os(:)
            integer(i8), intent(inout) :: kd(:, :)
            integer, intent(inout) :: od(:)
            integer :: start(0:BUCKETS - 1), i, v, pos, shift, q
            start(0) = 1
            do v = 1, BUCKETS - 1
                start(v) = start(v - 1) + tally(v, d)
            end do
            shift = (d - 1) * DIGIT_BITS
            do i = 1, n
                v = int(ibits(ks(r, i), shift, width))
                pos = start(v)
                start(v) = pos + 1
                ! element by element: an array assignment of this short column was a call
                ! to memcpy per key
                do q = 1, rows
                    kd(q, pos) = ks(q, i)
                end do
                od(pos) = os(i)
            end do
        end subroutine scatter
    end subroutine sort_by_keys

    !> order(1:n) such that ids(order(1:n)) increases (stable): the storage order that the
    !> remeshing and the set-up make independent of the rank count.
    subroutine id_order(ids, n, order)
        integer(i8), intent(in) :: ids(:)
        integer, intent(in) :: n
        integer, intent(out) :: order(:)
        integer :: i
        order(1:n) = [(i, i = 1, n)]
        call sort_by_keys(reshape(ids(1:n), [1, n]), order(1:n))
    end subroutine id_order

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
