!> Fine-to-coarse particle selection (thesis sec. 3.2.2, with the tagging fixed as the errata
!> ask). Serial, no MPI, selection only: the fields of the deleted particles are handed on to
!> the kept ones by sph_remesh_interp.
!>
!> Tagging (thesis steps 1-5). Particles are visited in the order of (h(id), id), h the
!> splitmix64 finaliser of the global id (unsigned compare), so the order depends neither on
!> the storage order nor on how particles are spread over ranks. Each particle gets the lowest
!> natural number absent among the tags of its already-tagged tagging neighbours; class
!> KEPT_CLASS = 1 is kept. Class 1 is a maximal set in which no two particles are tagging
!> neighbours (each particle either has tag 1 or a tag-1 neighbour), so the kept set has no
!> clumps (no two kept closer than r_near) and no holes wider than r_far.
!>
!> Tagging neighbours. Pairs closer than r_near are always neighbours; pairs with
!> r_near <= d < r_far are neighbours when a symmetric hash of the two ids, read as a fraction
!> of 2^64, is below p_far (so the relation is symmetric and order independent).
!>
!> Why not one radius and one class. With a hashed order class 1 is a random maximal set, not
!> the lattice one (the lattice 4-colouring, class 1 = every other site per axis, comes out of
!> a lexicographic order only), and on a lattice of spacing dx its size is quantised by the
!> radius. Measured (square / cubic periodic lattices, 64^2, 16^3, 20^3, perfect and 5 %
!> jitter):
!>   2D, dx < r < 1.41 dx (4 axis neighbours):          0.35 N = 1.40 N/4, nn 1.44 dx;
!>   2D, 1.41 dx < r < 2 dx (8 neighbours, the lattice
!>       4-colouring's radius): jams at 0.19 N = 0.75 N/4 (random sequential adsorption);
!>   3D, 1.41 dx < r < 1.73 dx (axis and face diagonals): 0.91-0.93 N/8 (8^3 periodic: 1.06);
!>   3D, 1.73 dx < r < 2 dx (26 neighbours):             0.65 N/8.
!> No class other than 1 does better (classes 2, 3 hold about as many but are not maximal).
!> So a fraction p_far of the diagonal pairs is made neighbours, which interpolates between the
!> two densities; p_far was set on the large samples above, not on the test lattices:
!>   2D: r_near = 1.2 dx, r_far = 1.7 dx, p_far = 0.45: 1.031 N/4 (16^2), 1.023 (32^2),
!>       1.001 (64^2, jittered);
!>   3D: r_near = 1.2 dx, r_far = 1.6 dx, p_far = 0.90: 1.047 N/8 (8^3), 1.037 (12^3),
!>       1.010 (16^3, jittered), 1.003 (20^3).
!> The price: kept pairs at a face diagonal remain, so the minimum kept distance is
!> sqrt(2) dx on a lattice (r_near = 1.2 dx is the guaranteed bound), not 0.8 x 2 dx, and the
!> mean nearest-neighbour distance is about 1.6 dx, not 2 dx (CV 0.18 in 2D, 0.09 in 3D).
!> No holes: every particle lies within r_far of a kept one (maximality of class 1).
!> With +-5 % jitter per axis, axis pairs stay below 1.1 dx, face diagonals within
!> [1.27, 1.56] dx and 2 dx pairs above 1.9 dx, so r_near and r_far sit in the gaps (3D body
!> diagonals, >= 1.56 dx, may fall below r_far = 1.6 dx and are then far pairs).
!> Only dim = 2 and 3 are tuned; dim = 1 is refused.
!>
!> Periodic: with box (lengths of the axes, domain [0, box)) neighbours are found through
!> periodic images (minimum image); the box must exceed 2 r_far per axis. Ids must be >= 0 and
!> unique (ties in the order are broken by id; a repeated id is refused).
module sph_coarsen
    use sph_kinds, only: wp, i8
    use sph_cell_list, only: neighbour_list_t, build_neighbour_list
    use sph_remesh_images, only: with_periodic_images
    implicit none
    private
    public :: coarsen_select, coarsen_radii, id_hash, KEPT_CLASS

    integer, parameter :: KEPT_CLASS = 1

contains

    !> Tagging radii (in units of dx) and the fraction of r_near..r_far pairs that are
    !> neighbours, per dimension (see the module header).
    pure subroutine coarsen_radii(dim, r_near, r_far, p_far)
        integer, intent(in) :: dim
        real(wp), intent(out) :: r_near, r_far, p_far
        r_near = 1.2_wp
        if (dim == 3) then
            r_far = 1.6_wp; p_far = 0.90_wp
        else
            r_far = 1.7_wp; p_far = 0.45_wp
        end if
    end subroutine coarsen_radii

    !> Select the particles kept when coarsening a set of spacing dx by 2 per axis.
    !> kept(1:n_kept): indices (ascending) of the kept particles; tag(1:n): the tag classes.
    subroutine coarsen_select(dim, n, x, ids, dx, n_kept, kept, tag, stat, errmsg, box)
        integer, intent(in) :: dim, n
        real(wp), intent(in) :: x(:, :), dx
        integer(i8), intent(in) :: ids(:)
        integer, intent(out) :: n_kept
        integer, allocatable, intent(out) :: kept(:)
        integer, allocatable, intent(out) :: tag(:)
        integer, intent(out), optional :: stat
        character(len=*), intent(out), optional :: errmsg
        real(wp), intent(in), optional :: box(3)
        real(wp) :: r_near, r_far, p_far, bx(3), rn2
        logical :: periodic
        integer, allocatable :: astart(:), adj(:), order(:)
        integer(i8), allocatable :: h(:)
        logical, allocatable :: seen(:)
        integer :: i, k, p, j, t

        if (present(stat)) stat = 0
        n_kept = 0
        allocate(kept(0), tag(max(n, 0)))
        periodic = present(box)
        bx = 0.0_wp
        if (periodic) bx = box
        call coarsen_radii(dim, r_near, r_far, p_far)
        r_near = r_near * dx
        r_far = r_far * dx
        rn2 = r_near * r_near
        if (dim < 2 .or. dim > 3 .or. n < 0 .or. dx <= 0.0_wp) then
            call fail('coarsen_select: need dim 2 or 3, n >= 0, dx > 0')
            return
        end if
        if (periodic) then
            if (any(bx(1:dim) <= 2.0_wp * r_far)) then
                call fail('coarsen_select: periodic box shorter than 2 tagging radii')
                return
            end if
        end if
        if (n == 0) return
        if (any(ids(1:n) < 0_i8)) then
            call fail('coarsen_select: ids must be >= 0')
            return
        end if
        allocate(h(n), order(n))
        do i = 1, n
            h(i) = id_hash(ids(i))
            order(i) = i
        end do
        call sort_order(order)
        do k = 2, n
            if (ids(order(k)) == ids(order(k - 1))) then
                call fail('coarsen_select: repeated id')
                return
            end if
        end do
        call adjacency()

        tag = 0
        allocate(seen(0:64))
        do k = 1, n
            i = order(k)
            seen = .false.
            do p = astart(i), astart(i + 1) - 1
                j = adj(p)
                if (tag(j) > 0 .and. tag(j) <= 64) seen(tag(j)) = .true.
            end do
            t = 1
            do while (t <= 64)
                if (.not. seen(t)) exit
                t = t + 1
            end do
            tag(i) = t
        end do
        n_kept = count(tag(1:n) == KEPT_CLASS)
        deallocate(kept)
        allocate(kept(n_kept))
        kept = pack([(i, i = 1, n)], tag(1:n) == KEPT_CLASS)

    contains

        !> Tagging neighbours (through periodic images if periodic), deduplicated.
        subroutine adjacency()
            real(wp), allocatable :: xa(:, :)
            integer, allocatable :: orig(:)
            type(neighbour_list_t) :: nl
            integer :: a, m, s, ntot, b
            real(wp) :: d(3)
            call with_periodic_images(dim, n, x, periodic, bx, r_far, xa, orig, ntot)
            call build_neighbour_list(xa, ntot, n, dim, r_far, nl)
            allocate(astart(n + 1), adj(max(nl%n_pairs, 1)))
            m = 0
            do a = 1, n
                astart(a) = m + 1
                do s = nl%start(a), nl%start(a + 1) - 1
                    b = orig(nl%index(s))
                    if (b == a .or. any(adj(astart(a):m) == b)) cycle
                    d = xa(:, nl%index(s)) - xa(:, a)
                    if (sum(d(1:dim)**2) >= rn2) then
                        if (.not. far_pair_is_neighbour(ids(a), ids(b), p_far)) cycle
                    end if
                    m = m + 1
                    adj(m) = b
                end do
            end do
            astart(n + 1) = m + 1
        end subroutine adjacency

        !> Merge sort of indices by (h, id), h compared as unsigned.
        subroutine sort_order(o)
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
                        else if (before(o(b), o(a))) then
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
        end subroutine sort_order

        logical function before(a, b)
            integer, intent(in) :: a, b
            if (h(a) /= h(b)) then
                before = ult(h(a), h(b))
            else
                before = ids(a) < ids(b)
            end if
        end function before

        subroutine fail(msg)
            character(len=*), intent(in) :: msg
            n_kept = 0
            if (allocated(kept)) deallocate(kept)
            allocate(kept(0))
            if (present(errmsg)) errmsg = msg
            if (present(stat)) then
                stat = 1
                return
            end if
            error stop 'coarsen_select: invalid input'
        end subroutine fail
    end subroutine coarsen_select

    !> Whether a pair at r_near <= d < r_far is a tagging neighbour: the pair hash
    !> h(h(min id) xor max id), as an unsigned fraction of 2^64, is below p.
    pure logical function far_pair_is_neighbour(a, b, p)
        integer(i8), intent(in) :: a, b
        real(wp), intent(in) :: p
        integer(i8) :: hp
        if (p >= 1.0_wp) then
            far_pair_is_neighbour = .true.
            return
        end if
        hp = id_hash(ieor(id_hash(min(a, b)), max(a, b)))
        far_pair_is_neighbour = real(shiftr(hp, 11), wp) * 2.0_wp**(-53) < p
    end function far_pair_is_neighbour

    !> splitmix64 finaliser of z + 0x9E3779B97F4A7C15, all arithmetic modulo 2^64 (done on
    !> 16-bit limbs, so no signed overflow).
    pure integer(i8) function id_hash(id) result(z)
        integer(i8), intent(in) :: id
        z = add64(id, from_hex(int(z'9E37', i8), int(z'79B9', i8), int(z'7F4A', i8), &
            int(z'7C15', i8)))
        z = mul64(ieor(z, shiftr(z, 30)), from_hex(int(z'BF58', i8), int(z'476D', i8), &
            int(z'1CE4', i8), int(z'E5B9', i8)))
        z = mul64(ieor(z, shiftr(z, 27)), from_hex(int(z'94D0', i8), int(z'49BB', i8), &
            int(z'1331', i8), int(z'11EB', i8)))
        z = ieor(z, shiftr(z, 31))
    end function id_hash

    !> The 64-bit pattern w3 w2 w1 w0 (16-bit words, w3 most significant).
    pure integer(i8) function from_hex(w3, w2, w1, w0) result(v)
        integer(i8), intent(in) :: w3, w2, w1, w0
        v = ior(ior(shiftl(w3, 48), shiftl(w2, 32)), ior(shiftl(w1, 16), w0))
    end function from_hex

    pure function limbs(v) result(l)
        integer(i8), intent(in) :: v
        integer(i8) :: l(0:3)
        integer :: k
        do k = 0, 3
            l(k) = ibits(v, 16 * k, 16)
        end do
    end function limbs

    !> Sum of 16-bit limb sums s(0:3) (each < 2^40) with carries, modulo 2^64.
    pure integer(i8) function assemble(s) result(v)
        integer(i8), intent(in) :: s(0:3)
        integer(i8) :: c, w(0:3)
        integer :: k
        c = 0_i8
        do k = 0, 3
            w(k) = s(k) + c
            c = shiftr(w(k), 16)
            w(k) = iand(w(k), int(z'FFFF', i8))
        end do
        v = from_hex(w(3), w(2), w(1), w(0))
    end function assemble

    pure integer(i8) function add64(a, b)
        integer(i8), intent(in) :: a, b
        add64 = assemble(limbs(a) + limbs(b))
    end function add64

    pure integer(i8) function mul64(a, b)
        integer(i8), intent(in) :: a, b
        integer(i8) :: la(0:3), lb(0:3), s(0:3)
        integer :: i, j
        la = limbs(a)
        lb = limbs(b)
        s = 0_i8
        do i = 0, 3
            do j = 0, 3 - i
                ! each product < 2^32; the sums and the carries stay below 2^40
                s(i + j) = s(i + j) + la(i) * lb(j)
            end do
        end do
        mul64 = assemble(s)
    end function mul64

    !> Unsigned a < b for 64-bit patterns.
    pure logical function ult(a, b)
        integer(i8), intent(in) :: a, b
        ult = ieor(a, ibset(0_i8, 63)) < ieor(b, ibset(0_i8, 63))
    end function ult
end module sph_coarsen
