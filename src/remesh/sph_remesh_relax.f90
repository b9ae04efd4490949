!> Relaxation of a new particle set before the transfer (same-level remeshing of a disordered
!> flow). Serial, no MPI: the caller hands in the new positions followed by their periodic
!> images and their mirrors across solids (the repulsors that keep the first row off a wall).
!>
!> Why. A selected set (sph_coarsen's class 1 and fill on a refined disordered flow) has the
!> right count but uneven volumes: its Voronoi areas vary by 25-30 % (coefficient of
!> variation) against 8-13 % for the flow it came from, because a maximal set at a fixed
!> radius packs randomly. The transfer hands each new particle the mass of its volume, so the
!> masses vary alike (0.5-1.4 m0 between the 5th and 95th percentiles on the L/50 cylinder
!> flow) and every remesh puts that noise into the flow.
!>
!> Rule. Each pass moves every particle down the gradient of the particle concentration
!> C(x) = sum_b V W(x - x_b) (Lind et al. 2012's shifting, used here as a static smoother):
!> dx_a = -RELAX_COEFFICIENT h^2 sum_b V grad_a W_ab, V = dx^dim, cubic B-spline with h =
!> 1.3 dx, each move capped at RELAX_MAX_STEP dx. A uniform arrangement has no gradient; a
!> clump pushes its members apart into the gaps around it. RELAX_PASSES passes bring the
!> masses that the transfer hands the coarsened cylinder flow's sets (their volumes) from
!> 23-26 % apart (CoV) to 5-8 % while the particles move by a fraction of a spacing, so the
!> disorder stays that of the flow, not a lattice.
module sph_remesh_relax
    use sph_kinds, only: wp
    use sph_cell_list, only: neighbour_list_t, build_neighbour_list
    use sph_kernel, only: kernel_t, kernel_create, KERNEL_CUBIC
    implicit none
    private
    public :: relax_displacements, relax_list_t, RELAX_PASSES, RELAX_H_FACTOR, RELAX_TOLERANCE
    public :: move_allowed_i

    abstract interface
        !> Whether a point may move to z (the caller's constraint: keep off solids).
        logical function move_allowed_i(z)
            import :: wp
            real(wp), intent(in) :: z(3)
        end function move_allowed_i
    end interface

    !> Five passes of coefficient 0.6 leave the coarsened cylinder flows' sets as ten of 0.3
    !> did (nearest-distance mean and CoV within 0.02 and 0.004, mass CoV 5-8 %: offline
    !> coarsening of the L/25 and L/50 snapshots at 1500 and 6000 s) at half the cost.
    integer, parameter :: RELAX_PASSES = 5
    real(wp), parameter :: RELAX_H_FACTOR = 1.3_wp
    real(wp), parameter :: RELAX_COEFFICIENT = 0.6_wp
    real(wp), parameter :: RELAX_MAX_STEP = 0.2_wp
    !> A pass whose largest move is below this (in dx) ends the relaxation: the set is even
    !> (a lattice's sublattice moves by round-off). The coarsened developed flows' sets still
    !> move by 0.04-0.19 dx in their fifth pass (the cylinder and Poiseuille coarsenings of
    !> doc/validation.md), so they get all RELAX_PASSES; the long channel's same-level
    !> remeshes (a sheared near-lattice) stop after 1 or 2 passes in 5 of 10.
    real(wp), parameter :: RELAX_TOLERANCE = 0.01_wp
    !> The list of a pass serves the next ones (relax_list_t) while no point has moved more
    !> than half this skin (in dx) since it was built.
    real(wp), parameter :: RELAX_SKIN = 0.4_wp

    !> A neighbour list kept from pass to pass (Verlet-list reuse): built at y_ref with the
    !> pair radius plus a skin, it holds every pair within the radius while each point (image
    !> and mirror included) stays within half the skin of where it was. Its first use builds it.
    type :: relax_list_t
        type(neighbour_list_t) :: nl
        !> the pairs (a, b) of nl with b > a, each once: row a's in index(start(a):start(a+1)-1)
        integer, allocatable :: start(:), index(:)
        real(wp), allocatable :: y_ref(:, :)
        integer :: ny = -1
    end type relax_list_t

contains

    !> One pass: displacements d(:, 1:n) of the points y(:, 1:n) of spacing dx, the points
    !> y(:, n + 1:ny) (images and mirrors) pushing but not moved. kept: the list of earlier
    !> passes over the same points (in the same order), reused while it holds every pair.
    !> floor (in dx): a point whose move would leave it closer than floor dx to another, and
    !> closer than before, stays (and so does that other one); the pushes of a clump's
    !> neighbours can otherwise squeeze two points together (0.28 new spacings on a coarsened
    !> cylinder flow whose selection kept 0.4).
    !> allowed: a move it refuses is not made, before the floor is checked (a refusal after
    !> it let a pair's partner close in: 0.27 new spacings next to the cylinder).
    !> pair_gap (in dx): two points that are each other's nearest, closer than pair_gap dx,
    !> move together (both by their mean move), so that a clumped flow's pairs stay pairs
    !> while the relaxation evens the volumes around them (refinement, sph_remesh_driver).
    !> moves_with(k) (optional): the point 1..n that point k > n is a periodic image of (it
    !> moves as that point does), 0 for one that does not move (a mirror): the floor holds
    !> across a periodic face too (without it, two points on both sides of the face came
    !> 0.37 new spacings apart: the refined L/50 cylinder flow at 6000 s).
    subroutine relax_displacements(dim, n, ny, y, dx, d, kept, floor, allowed, pair_gap, &
            moves_with)
        integer, intent(in) :: dim, n, ny
        real(wp), intent(in) :: y(:, :), dx
        real(wp), intent(out) :: d(:, :)
        type(relax_list_t), intent(inout), optional :: kept
        real(wp), intent(in), optional :: floor, pair_gap
        procedure(move_allowed_i), optional :: allowed
        integer, intent(in), optional :: moves_with(:)
        type(relax_list_t) :: own
        type(kernel_t) :: kernel
        real(wp) :: h, vol
        h = RELAX_H_FACTOR * dx
        vol = dx**dim
        d(:, 1:n) = 0.0_wp
        if (n == 0) return
        kernel = kernel_create(KERNEL_CUBIC, dim, h)
        if (present(kept)) then
            call pass(kept)
        else
            call pass(own)
        end if

    contains

        !> The displacements with `list`, built first unless it still holds every pair. Each
        !> pair once (the half list: a sum that a pair adds to one point it takes from the
        !> other; an image or mirror's share is dropped, since its own point meets an image of
        !> the first in its row). A row in three loops: offsets and distances, then dW/dr of
        !> the row in one batch (both vectorise; a partner beyond the support, the list's
        !> skin, gets dW/dr = 0 and adds nothing), then the sums. (Every pair from both sides,
        !> the rows without a scatter: coarsening of 10^5 0.153 s against 0.141 s, same level
        !> 0.605 against 0.554 s, whole passes, doc/performance.md.)
        subroutine pass(list)
            type(relax_list_t), intent(inout) :: list
            real(wp) :: step, on_z, f(3), sa(3)
            ! one point's partners: offsets, distances and dW/dr / r
            real(wp), allocatable :: rx(:, :), rs(:), dw(:), s(:, :)
            ! pairs that the moves (at most RELAX_MAX_STEP dx each) could bring below floor
            integer, allocatable :: close_a(:), close_b(:), more(:)
            ! each point's nearest partner and its distance (pair_gap)
            integer, allocatable :: nearest(:)
            real(wp), allocatable :: r_near(:)
            real(wp) :: r_watch
            integer :: a, b, p, m, first, n_close
            if (.not. holds_pairs(list)) then
                call build_neighbour_list(y, ny, n, dim, 2.0_wp * h + RELAX_SKIN * dx, list%nl, &
                    reach=2)
                call halve(list)
                list%y_ref = y(:, 1:ny)
                list%ny = ny
            end if
            ! the third axis only in 3D (whatever a 2D caller's points carry there)
            on_z = merge(1.0_wp, 0.0_wp, dim == 3)
            r_watch = -1.0_wp
            if (present(floor)) r_watch = (floor + 2.0_wp * RELAX_MAX_STEP) * dx
            n_close = 0
            allocate(close_a(max(n, 1)), close_b(max(n, 1)), s(3, max(ny, 1)))
            s = 0.0_wp
            if (present(pair_gap)) then
                allocate(nearest(ny), r_near(ny))
                nearest = 0
                r_near = huge(1.0_wp)
            end if
            m = maxval(list%start(2:n + 1) - list%start(1:n))
            allocate(rx(max(m, 1), 3), rs(max(m, 1)), dw(max(m, 1)))
            do a = 1, n
                first = list%start(a)
                m = list%start(a + 1) - first
                do p = 1, m
                    rx(p, 1) = y(1, a) - y(1, list%index(first + p - 1))
                    rx(p, 2) = y(2, a) - y(2, list%index(first + p - 1))
                    rx(p, 3) = on_z * (y(3, a) - y(3, list%index(first + p - 1)))
                    rs(p) = sqrt(rx(p, 1)**2 + rx(p, 2)**2 + rx(p, 3)**2)
                end do
                if (present(pair_gap)) then
                    do p = 1, m
                        b = list%index(first + p - 1)
                        if (rs(p) < r_near(a)) then
                            r_near(a) = rs(p)
                            nearest(a) = b
                        end if
                        if (rs(p) < r_near(b)) then
                            r_near(b) = rs(p)
                            nearest(b) = a
                        end if
                    end do
                end if
                do p = 1, m
                    if (rs(p) >= r_watch) cycle
                    if (n_close == size(close_a)) then
                        allocate(more(2 * n_close))
                        more(1:n_close) = close_a
                        call move_alloc(more, close_a)
                        allocate(more(2 * n_close))
                        more(1:n_close) = close_b
                        call move_alloc(more, close_b)
                    end if
                    n_close = n_close + 1
                    close_a(n_close) = a
                    close_b(n_close) = list%index(first + p - 1)
                end do
                call kernel%dwdr_many(rs(1:m), dw(1:m))
                do p = 1, m
                    dw(p) = dw(p) / max(rs(p), tiny(1.0_wp))
                end do
                sa = 0.0_wp
                do p = 1, m
                    b = list%index(first + p - 1)
                    f(1) = dw(p) * rx(p, 1)
                    f(2) = dw(p) * rx(p, 2)
                    f(3) = dw(p) * rx(p, 3)
                    sa = sa + f
                    s(:, b) = s(:, b) - f
                end do
                s(:, a) = s(:, a) + sa
            end do
            do a = 1, n
                d(:, a) = -RELAX_COEFFICIENT * h * h * vol * s(:, a)
                d(dim + 1:, a) = 0.0_wp
                step = norm2(d(:, a))
                if (step > RELAX_MAX_STEP * dx) then
                    d(:, a) = d(:, a) * (RELAX_MAX_STEP * dx / step)
                end if
            end do
            if (present(pair_gap)) then
                do a = 1, n
                    b = nearest(a)
                    if (b <= a .or. b > n) cycle
                    if (nearest(b) /= a .or. r_near(a) >= pair_gap * dx) cycle
                    f = 0.5_wp * (d(:, a) + d(:, b))
                    d(:, a) = f
                    d(:, b) = f
                end do
            end if
            if (present(allowed)) then
                do a = 1, n
                    if (.not. allowed(y(:, a) + d(:, a))) d(:, a) = 0.0_wp
                end do
            end if
            if (present(floor)) call keep_floor(close_a(1:n_close), close_b(1:n_close), &
                floor * dx)
        end subroutine pass

        !> list%start/index: the pairs (a, b > a) of list%nl's rows 1..n.
        subroutine halve(list)
            type(relax_list_t), intent(inout) :: list
            integer :: a, k, c
            if (allocated(list%start)) deallocate(list%start, list%index)
            allocate(list%start(n + 1), list%index(max(list%nl%start(n + 1) - 1, 1)))
            c = 0
            do a = 1, n
                list%start(a) = c + 1
                do k = list%nl%start(a), list%nl%start(a + 1) - 1
                    if (list%nl%index(k) <= a) cycle
                    c = c + 1
                    list%index(c) = list%nl%index(k)
                end do
            end do
            list%start(n + 1) = c + 1
        end subroutine halve

        !> Cancel the moves that bring a pair (of the pairs pa, pb that could come so close)
        !> closer than r_floor and closer than it was, both points' moves (an image's: its
        !> point's, moves_with; a mirror does not move here); repeated until none is left,
        !> since a point that stays may be approached by another.
        subroutine keep_floor(pa, pb, r_floor)
            integer, intent(in) :: pa(:), pb(:)
            real(wp), intent(in) :: r_floor
            logical :: changed
            real(wp) :: before(3), after(3), db(3)
            integer :: a, b, p
            changed = .true.
            do while (changed)
                changed = .false.
                do p = 1, size(pa)
                    a = pa(p)
                    ! the point that moves b (b itself, the point it is an image of, or none)
                    b = pb(p)
                    if (b > n) then
                        b = 0
                        if (present(moves_with)) b = moves_with(pb(p))
                    end if
                    db = 0.0_wp
                    if (b > 0) db = d(:, b)
                    before = y(:, a) - y(:, pb(p))
                    after = before + d(:, a) - db
                    before(dim + 1:) = 0.0_wp
                    after(dim + 1:) = 0.0_wp
                    if (sum(after**2) >= r_floor**2) cycle
                    if (sum(after**2) >= sum(before**2)) cycle
                    if (any(d(:, a) /= 0.0_wp)) then
                        d(:, a) = 0.0_wp
                        changed = .true.
                    end if
                    if (b > 0) then
                        if (any(d(:, b) /= 0.0_wp)) then
                            d(:, b) = 0.0_wp
                            changed = .true.
                        end if
                    end if
                end do
            end do
        end subroutine keep_floor

        !> Whether the list was built for these ny points and none has moved more than half
        !> the skin since.
        logical function holds_pairs(list)
            type(relax_list_t), intent(in) :: list
            integer :: k
            real(wp) :: limit2
            holds_pairs = list%ny == ny
            if (.not. holds_pairs) return
            limit2 = (0.5_wp * RELAX_SKIN * dx)**2
            do k = 1, ny
                if (sum((y(1:dim, k) - list%y_ref(1:dim, k))**2) >= limit2) then
                    holds_pairs = .false.
                    return
                end if
            end do
        end function holds_pairs
    end subroutine relax_displacements
end module sph_remesh_relax
