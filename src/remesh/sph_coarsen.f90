!> Fine-to-coarse particle selection (thesis sec. 3.2.2, with the tagging fixed as the errata
!> ask). Serial, no MPI, selection only: the fields of the deleted particles are handed on to
!> the kept ones by sph_remesh_interp.
!>
!> Rule. On a near-lattice of spacing dx the set to keep is a sublattice: every other particle
!> along each axis (N/2^dim particles at 2 dx). The thesis' tagging (steps 1-5: each particle
!> gets the lowest natural number absent among the tags of its already-tagged neighbours,
!> class KEPT_CLASS = 1 is kept) finds it only if the particles are visited in an order that
!> favours one sublattice consistently; with random (hashed) priorities class 1 is a random
!> maximal set instead (about 0.75-1.4 N/2^dim, mean nearest distance 1.6 dx, CV 0.18). So:
!>  1. Lattice parity. For each particle and axis a, its lattice coordinate is estimated from
!>     its "row" along a: the particles within r_row = 2.5 dx whose offsets on the other axes
!>     are below dx/2. s_a = x_a/dx + mean over the row (itself included, with 0) of
!>     dev = d_a/dx - nint(d_a/dx), d the minimum-image offset: s_a is the particle's lattice
!>     site plus the mean jitter of its row, so particle jitter drops out and rows sheared
!>     against each other (a developed channel flow) each keep their own phase. The parity is
!>     p_a = modulo(floor(s_a - PHASE_CUT), 2), PHASE_CUT = 0.25; deviations are summed as
!>     integers (units of 2^-30), so s_a does not depend on the summation order. A particle
!>     "matches" when p_a = 0 on every axis.
!>  2. Tagging order: matching particles first, then by h(id), h the splitmix64 finaliser of
!>     the global id (unsigned compare), then by id. Every key is a function of positions and
!>     ids only, so the order (and the kept set) depends neither on storage order nor on how
!>     particles are spread over ranks (each decision needs neighbours within r_row, and the
!>     tags of higher-priority neighbours within r_conflict: Jones-Plassmann style).
!>  3. Tagging neighbours: pairs closer than r_conflict = 1.75 dx (2D), 1.8 dx (3D): the
!>     lattice's axis, face and (3D) body diagonals (<= 1.56 dx in 2D, <= 1.73 dx + jitter in
!>     3D) are in, the 2 dx pairs of a sublattice (>= 1.9 dx with +-5 % jitter per axis; >= 1.8
!>     dx on a set refined from such a lattice) are out.
!> Class 1 is then the greedy maximal independent set in that order: on a near-lattice whose
!> parity is consistent it is exactly the matching sublattice (each matching particle comes
!> before all its tagging neighbours, which do not match). Whatever the input, no two kept
!> particles are closer than r_conflict (no clumps) and every particle lies within
!> r_conflict of a kept one (no holes); where the parity is not consistent (disordered sets,
!> a row whose sites sit at PHASE_CUT, a periodic box with an odd number of sites per axis)
!> the order falls back to the hashed one locally. Worst case: a whole lattice with sites at
!> 0.25 dx (mod dx) from the origin keeps about 0.76 N/4 in 2D.
!> Measured (periodic, +-5 % jitter per axis; ratios to the input set): 2D 16^2 and 32^2,
!> 3D 8^3 and 12^3: count N/2^dim exactly, mean nearest distance 2.04-2.05x, minimum pair
!> >= 1.0 x 2 dx mean, CV of the nearest distances about half the input's (the jitter is kept
!> in dx, so relative to 2 dx it halves); the same lattices refined by sph_refine and
!> coarsened at dx/2: count exact, mean 1.96-1.97x, CV 0.97-1.03x the refined set's.
!> Only dim = 2 and 3 are tuned; dim = 1 is refused.
!>
!> Count target (optional n_target). On a disordered set (a developed flow that has
!> sheared or clumped, or such a flow refined) class 1 is a random maximal set at radius
!> r_conflict = 0.875 of the new spacing: about 0.7-0.8 N/2^dim, not N/2^dim (measured on the
!> developed cylinder flow: 0.72-0.77), so every same-level remesh of such a flow lost about
!> a quarter of its particles. Given n_target, a second pass fills the gaps: in the same
!> order, a particle not yet kept is kept when no kept particle (either pass) lies within
!> r_fill < r_conflict, with r_fill the largest radius (bisection, FILL_STEPS halvings between
!> R_FILL_MIN dx and r_conflict) whose kept count reaches n_target. Where class 1 already
!> covers the set (a near-lattice: every other particle lies within 1.41 dx of a kept one)
!> nothing is added for r_fill above that; the gaps of a disordered set get particles at
!> r_fill (0.70-0.72 of the new spacing on the cylinder flow), so the kept set is spread
!> evenly at the count asked for, and no two kept particles are closer than R_FILL_MIN dx =
!> 0.4 of the new spacing. A radius that frees many at once (the diagonals of a lattice
!> whose parity is inconsistent, as Morris' L/25 cell with its 25 sites per periodic axis)
!> is trimmed back to n_target, the added particles with the largest id hashes dropped. If
!> even r_fill = R_FILL_MIN dx does not reach n_target (too few candidates), that set is
!> kept.
!>
!> Following the flow's spacing (optional follow_spacing, the driver's coarsening). A
!> developed flow is clumped (the cylinder flow at 1500-6000 s: nearest distances 0.69-0.75
!> dx on average, CoV 0.21-0.25), and a maximal set at a fixed radius is a hard-core set,
!> more regular than the flow (CoV about half the flow's, mean nearest distance 2.26-2.46x).
!> So the flow's clumping is carried to twice the spacing: a particle is "disordered" when
!> the mean |offset from a whole spacing| of its row neighbours (step 1's rows, integer sums)
!> reaches LATTICE_DEV = 0.15 dx on some axis (a 5 % jittered or sheared lattice: about
!> 0.03; the developed flow: 0.29 median); between two disordered particles the conflict
!> radius is r_conflict/dx times the smaller of their nearest distances (within r_conflict),
!> at least R_FILL_MIN dx, at most r_conflict; and a disordered particle's parity is ignored
!> (it is noise that would order the particles by stripes of space). The lattice rule above
!> is untouched elsewhere (the 3D body diagonals stay in conflict). The smaller radii make
!> class 1 larger than n_target (0.34-0.40 N on the flow), and the first n_target of it in
!> the tagging order are kept: a cut by id hash, even over space. Measured on the selection
!> alone (offline coarsening of the developed cylinder flow): mean ratio 2.01-2.09, CoV
!> 0.84-0.92 of the flow's; the driver then relaxes the set, which takes part of it back.
!> The cut is random, so over visiting orders the mean ratio scatters by about 0.025 at a
!> thousand kept particles (median 2.05 on a random sequential set of the flow's clumping).
!>
!> Periodic: with box (lengths of the axes, domain [0, box)) neighbours are found through
!> periodic images (minimum image); the box must exceed 2 r_row per axis. Ids must be >= 0 and
!> unique (ties in the order are broken by id; a repeated id is refused).
module sph_coarsen
    use sph_kinds, only: wp, i8
    use sph_cell_list, only: cell_grid_t, bin_particles, cell_runs, cell_runs_shaped
    use sph_remesh_images, only: with_periodic_images
    use sph_key_sort, only: sort_by_keys
    implicit none
    private
    public :: coarsen_select, coarsen_radii, id_hash, KEPT_CLASS, PHASE_CUT

    integer, parameter :: KEPT_CLASS = 1
    !> Lattice coordinate (in dx) at which the parity changes (see the module header).
    real(wp), parameter :: PHASE_CUT = 0.25_wp
    !> Deviations are summed as integers in units of 2^-DEV_BITS.
    integer, parameter :: DEV_BITS = 30
    !> Smallest fill radius (in dx: 0.4 of the new spacing 2 dx) and the bisection's steps.
    real(wp), parameter :: R_FILL_MIN = 0.8_wp
    integer, parameter :: FILL_STEPS = 20
    !> follow_spacing: a particle whose rows sit off whole spacings by LATTICE_DEV (in dx)
    !> or more on average, on some axis, is "disordered" (module header).
    real(wp), parameter :: LATTICE_DEV = 0.15_wp
    !> The low 16 bits (the limbs of id_hash's arithmetic modulo 2^64).
    integer(i8), parameter :: LIMB = int(z'FFFF', i8)

contains

    !> Tagging radius r_conflict and row radius r_row (in units of dx), per dimension (see
    !> the module header).
    pure subroutine coarsen_radii(dim, r_conflict, r_row)
        integer, intent(in) :: dim
        real(wp), intent(out) :: r_conflict, r_row
        r_row = 2.5_wp
        if (dim == 3) then
            r_conflict = 1.8_wp
        else
            r_conflict = 1.75_wp
        end if
    end subroutine coarsen_radii

    !> Select the particles kept when coarsening a set of spacing dx by 2 per axis.
    !> kept(1:n_kept): indices (ascending) of the kept particles; tag(1:n): the tag classes.
    !> given_match(1:n), when present, replaces the parity estimated from positions (step 1):
    !> a caller that knows each particle's lattice parity (particles carry it through a run,
    !> sph_transition) gets a kept set that moves with the flow instead of jumping when the
    !> flow has carried the particles past PHASE_CUT.
    !> n_target, when present, is the count to reach by the fill pass (module header); the
    !> particles it adds get tag KEPT_CLASS.
    !> follow_spacing (default false): the conflict radius between two disordered particles
    !> follows their nearest distances, and a class 1 above n_target is cut back to it (module
    !> header); the class 1 particles cut get tag 0.
    subroutine coarsen_select(dim, n, x, ids, dx, n_kept, kept, tag, stat, errmsg, box, &
            given_match, n_target, follow_spacing, n_disordered)
        integer, intent(in) :: dim, n
        real(wp), intent(in) :: x(:, :), dx
        integer(i8), intent(in) :: ids(:)
        integer, intent(out) :: n_kept
        integer, allocatable, intent(out) :: kept(:)
        integer, allocatable, intent(out) :: tag(:)
        integer, intent(out), optional :: stat
        character(len=*), intent(out), optional :: errmsg
        real(wp), intent(in), optional :: box(3)
        logical, intent(in), optional :: given_match(:)
        integer, intent(in), optional :: n_target
        logical, intent(in), optional :: follow_spacing
        !> particles whose rows sit off whole spacings (LATTICE_DEV): 0 on a near-lattice
        integer, intent(out), optional :: n_disordered
        real(wp) :: r_conflict, r_row, bx(3), rc2
        logical :: periodic, follow
        integer, allocatable :: astart(:), adj(:), order(:)
        real(wp), allocatable :: adj_r2(:), d_near(:)
        integer(i8), allocatable :: h(:), order_key(:)
        logical, allocatable :: match(:), disordered(:)
        integer(i8) :: seen
        integer :: i, k, p, j, t, n_class1
        !> the predecessors of particle i: pred(pstart(i):pstart(i + 1) - 1)
        integer, allocatable :: pstart(:), pred(:)
        integer, allocatable :: stack(:), cursor(:)   !< the depth-first tagging's path
        !> the fill pass's candidates (fill_candidates)
        integer, allocatable :: fill_order(:)
        real(wp), allocatable :: near_kept2(:)
        integer :: n_fill_order
        !> each candidate k's earlier candidates (by their place in fill_order) and squared
        !> distances: earlier(estart(k):estart(k + 1) - 1), earlier_r2 alike
        integer, allocatable :: estart(:), earlier(:)
        real(wp), allocatable :: earlier_r2(:)
        integer :: depth

        if (present(stat)) stat = 0
        if (present(n_disordered)) n_disordered = 0
        n_kept = 0
        allocate(kept(0), tag(max(n, 0)))
        periodic = present(box)
        follow = .false.
        if (present(follow_spacing)) follow = follow_spacing
        bx = 0.0_wp
        if (periodic) bx = box
        call coarsen_radii(dim, r_conflict, r_row)
        r_conflict = r_conflict * dx
        r_row = r_row * dx
        rc2 = r_conflict * r_conflict
        if (dim < 2 .or. dim > 3 .or. n < 0 .or. dx <= 0.0_wp) then
            call fail('coarsen_select: need dim 2 or 3, n >= 0, dx > 0')
            return
        end if
        if (periodic) then
            if (any(bx(1:dim) <= 2.0_wp * r_row)) then
                call fail('coarsen_select: periodic box shorter than 2 row radii (5 dx)')
                return
            end if
        end if
        if (n == 0) return
        if (any(ids(1:n) < 0_i8)) then
            call fail('coarsen_select: ids must be >= 0')
            return
        end if
        allocate(h(n), order(n), match(n), disordered(n), d_near(n))
        do i = 1, n
            h(i) = id_hash(ids(i))
            order(i) = i
        end do
        if (repeated_id(n, ids, h)) then
            call fail('coarsen_select: repeated id')
            return
        end if
        call adjacency_and_parity(dim, n, x, periodic, bx, dx, r_row, rc2, astart, adj, &
            adj_r2, match, disordered, d_near)
        if (present(n_disordered)) n_disordered = count(disordered)
        if (present(given_match)) match = given_match(1:n)
        ! a disordered particle's parity is noise that would order it by stripes of space
        if (follow) match = match .and. .not. disordered
        ! the order's two keys in one integer, compared signed: "not matching" as the top
        ! bit, then h's top 63 bits, the top bit flipped (predecessors read one array for
        ! two, and their branch on match went)
        allocate(order_key(n))
        do i = 1, n
            order_key(i) = ieor(ior(shiftl(merge(0_i8, 1_i8, match(i)), 63), shiftr(h(i), 1)), &
                ibset(0_i8, 63))
        end do

        ! The greedy tagging in the order `order`: a particle's tag is the lowest absent
        ! among the tags of its tagging neighbours before it in the order (its
        ! predecessors). Taken in that order the particles are visited at random places in
        ! memory (the hashed order), which cost half of the selection in cache misses. So
        ! the particles are swept in storage order instead, and a particle whose
        ! predecessors are not all tagged yet has them tagged first, depth first (an
        ! explicit stack): the tags, and so the kept set, are those of the greedy pass
        ! exactly, since a particle's tag depends only on its predecessors' tags, and each
        ! particle is tagged once (sweeps that skipped a particle until its predecessors
        ! were tagged took 15 rounds, 3.2 visits a particle). The tags seen are the bits of
        ! one integer (tags 1-64; 65 when all are taken): the lowest absent tag is its
        ! lowest clear bit. Which of two neighbours comes first is decided from their keys
        ! (comes_before); the whole order is sorted only when the count asks for it (the
        ! fill pass and the cut below), as a near-lattice's class 1 has it exactly.
        call predecessors()
        tag = 0
        allocate(stack(n), cursor(n))
        do i = 1, n
            if (tag(i) /= 0) cycle
            depth = 1
            stack(1) = i
            cursor(1) = pstart(i)
            do while (depth > 0)
                k = stack(depth)
                ! the next predecessor not yet tagged goes first
                do while (cursor(depth) < pstart(k + 1))
                    if (tag(pred(cursor(depth))) == 0) exit
                    cursor(depth) = cursor(depth) + 1
                end do
                if (cursor(depth) < pstart(k + 1)) then
                    j = pred(cursor(depth))
                    depth = depth + 1
                    stack(depth) = j
                    cursor(depth) = pstart(j)
                    cycle
                end if
                seen = 0_i8
                do p = pstart(k), pstart(k + 1) - 1
                    t = tag(pred(p))
                    if (t <= 64) seen = ibset(seen, t - 1)
                end do
                t = 65
                if (seen /= -1_i8) t = trailz(not(seen)) + 1
                tag(k) = t
                depth = depth - 1
            end do
        end do
        n_kept = count(tag(1:n) == KEPT_CLASS)
        if (present(n_target)) then
            if (n_kept < n_target) then
                call sort_order(order)
                call fill_to_target(n_target)
            else if (follow .and. n_kept > n_target) then
                ! the first n_target of class 1 in the tagging order stay
                call sort_order(order)
                n_class1 = 0
                do k = 1, n
                    i = order(k)
                    if (tag(i) /= KEPT_CLASS) cycle
                    n_class1 = n_class1 + 1
                    if (n_class1 > n_target) tag(i) = 0
                end do
                n_kept = n_target
            end if
        end if
        deallocate(kept)
        allocate(kept(n_kept))
        kept = pack([(i, i = 1, n)], tag(1:n) == KEPT_CLASS)

    contains

        !> The fill pass (module header): the largest r_fill whose kept count reaches want;
        !> tag and n_kept updated.
        subroutine fill_to_target(want)
            integer, intent(in) :: want
            logical, allocatable :: keep(:), best(:), best_fill(:)
            real(wp) :: lo, hi, r_fill
            integer :: step, n_fill, n_class
            integer, allocatable :: added(:), ord(:)
            integer(i8), allocatable :: hk(:, :)
            call fill_candidates()
            n_class = count(tag(1:n) == KEPT_CLASS)
            lo = R_FILL_MIN * dx
            hi = r_conflict
            call fill(lo, keep, n_fill)
            n_fill = n_fill + n_class
            best_fill = keep
            if (n_fill >= want) then
                do step = 1, FILL_STEPS
                    r_fill = 0.5_wp * (lo + hi)
                    call fill(r_fill, keep, n_fill)
                    n_fill = n_fill + n_class
                    if (n_fill >= want) then
                        lo = r_fill
                        best_fill = keep
                    else
                        hi = r_fill
                    end if
                end do
            end if
            best = tag(1:n) == KEPT_CLASS
            best(fill_order(1:n_fill_order)) = best_fill(1:n_fill_order)
            ! r_fill can add many at once (a lattice whose parity is inconsistent: the
            ! diagonals come free together): keep want, dropping the added particles with
            ! the largest id hashes, so that no region is preferred
            if (count(best) > want) then
                added = pack([(i, i = 1, n)], best .and. tag(1:n) /= KEPT_CLASS)
                allocate(hk(2, size(added)), ord(size(added)))
                do i = 1, size(added)
                    hk(:, i) = [ieor(h(added(i)), ibset(0_i8, 63)), ids(added(i))]
                    ord(i) = i
                end do
                call sort_by_keys(hk, ord)
                best(added(ord(size(added) - (count(best) - want) + 1:))) = .false.
            end if
            where (best .and. tag(1:n) /= KEPT_CLASS) tag(1:n) = KEPT_CLASS
            n_kept = count(tag(1:n) == KEPT_CLASS)
        end subroutine fill_to_target

        !> The particles a fill may add, in tagging order (fill_order), with the squared
        !> distance to their nearest class 1 neighbour (near_kept2): one with a class 1
        !> particle closer than R_FILL_MIN dx is never free (every fill radius is at least
        !> that). A fill pass at r then skips at once those whose nearest class 1 neighbour
        !> lies within r; the rest can be blocked only by a candidate before them in the
        !> order (a later one is not decided yet, and no other particle is ever added), so
        !> each candidate's earlier candidates are listed once here (estart, earlier,
        !> earlier_r2), and the passes read those short lists in order instead of the whole
        !> adjacency at hashed places in memory (the fill's 21 passes over every particle in
        !> hashed order were half of a disordered set's selection; then, over the
        !> adjacency of the candidates, a quarter of a same-level remesh of 10^5 jittered
        !> particles).
        subroutine fill_candidates()
            integer :: kk, ii, pp, nf, jj, ne, ne_row
            integer, allocatable :: place(:), more(:)
            real(wp), allocatable :: more_r2(:)
            real(wp) :: d2
            allocate(near_kept2(n), fill_order(n), place(n), estart(n + 1))
            allocate(earlier(max(n, 1)), earlier_r2(max(n, 1)))
            place = 0
            nf = 0
            ne = 0
            ! one sweep over the adjacency: a particle's earlier candidates are those placed
            ! already (the order is the sweep's); its row is dropped again when it turns out
            ! no candidate itself
            do kk = 1, n
                ii = order(kk)
                if (tag(ii) == KEPT_CLASS) cycle
                if (ne + astart(ii + 1) - astart(ii) > size(earlier)) then
                    allocate(more(2 * (ne + astart(ii + 1) - astart(ii))))
                    more(1:ne) = earlier(1:ne)
                    call move_alloc(more, earlier)
                    allocate(more_r2(size(earlier)))
                    more_r2(1:ne) = earlier_r2(1:ne)
                    call move_alloc(more_r2, earlier_r2)
                end if
                d2 = huge(1.0_wp)
                ne_row = ne
                do pp = astart(ii), astart(ii + 1) - 1
                    if (tag(adj(pp)) == KEPT_CLASS) d2 = min(d2, adj_r2(pp))
                    jj = place(adj(pp))
                    if (jj > 0) then
                        ne_row = ne_row + 1
                        earlier(ne_row) = jj
                        earlier_r2(ne_row) = adj_r2(pp)
                    end if
                end do
                near_kept2(ii) = d2
                if (d2 < (R_FILL_MIN * dx)**2) cycle
                nf = nf + 1
                fill_order(nf) = ii
                place(ii) = nf
                estart(nf) = ne + 1
                ne = ne_row
            end do
            n_fill_order = nf
            estart(nf + 1) = ne + 1
        end subroutine fill_candidates

        !> Which candidates (by their place in fill_order) a fill at radius r adds, and how
        !> many: in order, each with no kept particle within r (fill_candidates).
        subroutine fill(r, keep, n_keep)
            real(wp), intent(in) :: r
            logical, allocatable, intent(inout) :: keep(:)
            integer, intent(out) :: n_keep
            integer :: kk, ii, pp
            logical :: free
            if (.not. allocated(keep)) allocate(keep(max(n_fill_order, 1)))
            n_keep = 0
            do kk = 1, n_fill_order
                ii = fill_order(kk)
                keep(kk) = .false.
                if (near_kept2(ii) < r * r) cycle
                free = .true.
                do pp = estart(kk), estart(kk + 1) - 1
                    if (keep(earlier(pp)) .and. earlier_r2(pp) < r * r) then
                        free = .false.
                        exit
                    end if
                end do
                keep(kk) = free
                if (free) n_keep = n_keep + 1
            end do
        end subroutine fill

        !> pstart/pred: each particle's tagging neighbours before it in the order; with
        !> follow, a pair of disordered particles only within their own radius (module
        !> header).
        subroutine predecessors()
            integer :: a, q, b, np
            real(wp) :: rp
            allocate(pstart(n + 1), pred(max(astart(n + 1) - 1, 1)))
            np = 0
            do a = 1, n
                pstart(a) = np + 1
                do q = astart(a), astart(a + 1) - 1
                    b = adj(q)
                    if (.not. comes_before(b, a)) cycle
                    if (follow) then
                        if (disordered(a) .and. disordered(b)) then
                            rp = min(r_conflict, max(R_FILL_MIN * dx, &
                                r_conflict / dx * min(d_near(a), d_near(b))))
                            if (adj_r2(q) >= rp * rp) cycle
                        end if
                    end if
                    np = np + 1
                    pred(np) = b
                end do
            end do
            pstart(n + 1) = np + 1
        end subroutine predecessors

        !> Whether particle b comes before particle a in the tagging order: matching first,
        !> then by h (unsigned), as sort_order sorts (h never ties: see there). Compared by
        !> order_key first, h's last bit deciding only when the keys tie.
        pure logical function comes_before(b, a)
            integer, intent(in) :: b, a
            if (order_key(b) /= order_key(a)) then
                comes_before = order_key(b) < order_key(a)
            else
                comes_before = iand(h(b), 1_i8) < iand(h(a), 1_i8)
            end if
        end function comes_before

        !> Sort indices in the tagging order: match first, then h compared as unsigned (the
        !> module header's order; its last key, the id, never decides: id_hash is a
        !> bijection, an added constant, xor-shifts and products by odd numbers modulo 2^64,
        !> and the ids are unique, so no two hashes tie).
        subroutine sort_order(o)
            integer, intent(inout) :: o(:)
            integer(i8), allocatable :: keys(:, :)
            integer :: c
            allocate(keys(2, n))
            do c = 1, n
                keys(:, c) = [merge(0_i8, 1_i8, match(c)), ieor(h(c), ibset(0_i8, 63))]
            end do
            call sort_by_keys(keys, o)
        end subroutine sort_order

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

    !> coarsen_select's tagging neighbours within sqrt(rc2) (through periodic images if
    !> periodic), deduplicated, and the lattice parity match of every particle from its rows,
    !> with the disordered flags and nearest distances (module header). The pairs within
    !> r_row are visited straight from the cells (cells of r_row / 3 in 2D, the positions
    !> copied in the cell order), not through a stored neighbour list: the list's 40 entries
    !> a particle were mostly new pages to touch, and a second pass. A procedure of the module
    !> with its arrays as arguments, not one nested in coarsen_select: nested, it ran at half
    !> the speed whenever the compiler chose not to inline it (which it did when
    !> coarsen_select's other code changed), reading the host's arrays through their
    !> descriptors.
    subroutine adjacency_and_parity(dim, n, x, periodic, bx, dx, r_row, rc2, astart, adj, &
            adj_r2, match, disordered, d_near)
        integer, intent(in) :: dim, n
        real(wp), intent(in) :: x(:, :), bx(3), dx, r_row, rc2
        logical, intent(in) :: periodic
        integer, allocatable, intent(out) :: astart(:), adj(:)
        real(wp), allocatable, intent(out) :: adj_r2(:)
        logical, intent(out) :: match(:), disordered(:)
        real(wp), intent(out) :: d_near(:)
        real(wp), allocatable :: xa(:, :), ys(:, :), adj_r2_more(:)
        integer, allocatable :: orig(:), adj_more(:)
        type(cell_grid_t) :: grid
        integer :: a, m, ntot, b, ax, row_count(3), q, r, n_runs, first(25), last(25), reach
        integer :: k, row_reach(0:3)
        real(wp) :: cell, gap
        integer(i8) :: dev_sum(3), dev_abs(3), dev
        real(wp) :: d(3), r2, u, scale, half, rr2, r2_near
        logical :: in_row(3)
        scale = 2.0_wp**DEV_BITS
        half = 0.5_wp * dx
        rr2 = r_row * r_row
        call with_periodic_images(dim, n, x, periodic, bx, r_row, xa, orig, ntot)
        ! cells of r_row / 3 in 2D (an eighth less area to scan than r_row / 2 with reach 2),
        ! r_row / 2 in 3D (49 runs of cells otherwise)
        reach = merge(3, 2, dim == 2)
        call bin_particles(xa, ntot, dim, r_row / reach, grid)
        ! 2D: per row of cells k away, how many cells either side can hold a pair that
        ! counts: one in a row along the run axis (|across| < half, within r_row), along the
        ! other axis (|along| < half) or a conflict (within sqrt(rc2)); k - 1 cells is the
        ! least distance across, L / cell + 1 cells covers any distance below L along. A
        ! cross and a disc instead of the square: 37 cells of 49
        if (dim == 2) then
            cell = 1.0_wp / grid%inv_size
            do k = 0, reach
                gap = max(k - 1, 0) * cell
                row_reach(k) = -1
                if (gap < half) row_reach(k) = reach
                if (gap < r_row) row_reach(k) = max(row_reach(k), 1 + floor(half / cell))
                if (gap * gap < rc2) row_reach(k) = max(row_reach(k), &
                    1 + floor(sqrt(rc2 - gap * gap) / cell))
                row_reach(k) = min(row_reach(k), reach)
            end do
        end if
        allocate(ys(max(ntot, 1), 3))
        do q = 1, ntot
            ys(q, :) = xa(:, grid%sorted(q))
        end do
        ! about 8 (2D) or 18 (3D) tagging neighbours a particle; grown when short
        allocate(astart(n + 1), adj(max(2 * 3**dim * n, 1)), adj_r2(max(2 * 3**dim * n, 1)))
        m = 0
        d = 0.0_wp
        do a = 1, n
            astart(a) = m + 1
            dev_sum = 0_i8
            dev_abs = 0_i8
            row_count = 1
            r2_near = rc2
            if (dim == 2) then
                call cell_runs_shaped(grid, xa(:, a), row_reach(0:reach), first, last, n_runs)
            else
                call cell_runs(grid, xa(:, a), reach, first, last, n_runs)
            end if
            do r = 1, n_runs
                do q = first(r), last(r)
                    ! (2D without the third axis' zeros)
                    if (dim == 2) then
                        d(1) = ys(q, 1) - xa(1, a)
                        d(2) = ys(q, 2) - xa(2, a)
                        r2 = d(1)**2 + d(2)**2
                    else
                        d = ys(q, :) - xa(:, a)
                        r2 = d(1)**2 + d(2)**2 + d(3)**2
                    end if
                    if (r2 >= rr2) cycle
                    b = orig(grid%sorted(q))
                    if (b == a) cycle
                    ! a row along an axis: within half a spacing on the other axes
                    if (dim == 2) then
                        in_row(1) = abs(d(2)) < half
                        in_row(2) = abs(d(1)) < half
                    else
                        in_row(1) = abs(d(2)) < half .and. abs(d(3)) < half
                        in_row(2) = abs(d(1)) < half .and. abs(d(3)) < half
                        in_row(3) = abs(d(1)) < half .and. abs(d(2)) < half
                    end if
                    do ax = 1, dim
                        if (.not. in_row(ax)) cycle
                        u = d(ax) / dx
                        dev = nearest_i8((u - round_half_away(u)) * scale)
                        dev_sum(ax) = dev_sum(ax) + dev
                        dev_abs(ax) = dev_abs(ax) + abs(dev)
                        row_count(ax) = row_count(ax) + 1
                    end do
                    ! one image of b at most: two lie a box length (> 2 r_row) apart
                    if (r2 >= rc2) cycle
                    if (m == size(adj)) then
                        allocate(adj_more(2 * m), adj_r2_more(2 * m))
                        adj_more(1:m) = adj
                        adj_r2_more(1:m) = adj_r2
                        call move_alloc(adj_more, adj)
                        call move_alloc(adj_r2_more, adj_r2)
                    end if
                    m = m + 1
                    adj(m) = b
                    adj_r2(m) = r2
                    r2_near = min(r2_near, r2)
                end do
            end do
            match(a) = .true.
            disordered(a) = .false.
            do ax = 1, dim
                u = x(ax, a) / dx + real(dev_sum(ax), wp) / (scale * row_count(ax))
                if (modulo(floor(u - PHASE_CUT), 2) /= 0) match(a) = .false.
                ! mean |offset| over the row (itself not counted); no row: lattice-like
                if (row_count(ax) > 1) then
                    if (real(dev_abs(ax), wp) >= LATTICE_DEV * scale * (row_count(ax) - 1)) &
                        disordered(a) = .true.
                end if
            end do
            d_near(a) = sqrt(r2_near)
        end do
        astart(n + 1) = m + 1
    end subroutine adjacency_and_parity

    !> anint(u) (halves away from zero) without the library call that gfortran makes of it
    !> (about 5 % of a coarsening's selection); exact for |u| < 2^52.
    pure elemental real(wp) function round_half_away(u) result(r)
        real(wp), intent(in) :: u
        r = aint(u + sign(0.5_wp, u))
        ! u + 0.5 rounds up to the next integer when u is the largest double below a half
        if (abs(r - u) > 0.5_wp) r = r - sign(1.0_wp, u)
    end function round_half_away

    !> nint(u, i8), as round_half_away.
    pure elemental integer(i8) function nearest_i8(u)
        real(wp), intent(in) :: u
        nearest_i8 = int(round_half_away(u), i8)
    end function nearest_i8

    !> Does an id occur twice among ids(1:n)? An open-addressing table of 2^k >= 2 n slots,
    !> probed from each id's hash h (id_hash): O(n), where sorting took a fifth of a
    !> coarsening's selection.
    pure logical function repeated_id(n, ids, h) result(repeated)
        integer, intent(in) :: n
        integer(i8), intent(in) :: ids(:), h(:)
        integer(i8), allocatable :: table(:)
        integer :: bits, slot, i
        repeated = .false.
        bits = 1
        do while (2**bits < 2 * n)
            bits = bits + 1
        end do
        ! ids are >= 0: -1 marks a free slot
        allocate(table(0:2**bits - 1), source=-1_i8)
        do i = 1, n
            slot = int(ibits(h(i), 0, bits))
            do
                if (table(slot) == -1_i8) then
                    table(slot) = ids(i)
                    exit
                end if
                if (table(slot) == ids(i)) then
                    repeated = .true.
                    return
                end if
                slot = iand(slot + 1, 2**bits - 1)
            end do
        end do
    end function repeated_id

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

    !> Sum of 16-bit limb sums s0..s3 (each < 2^40) with carries, modulo 2^64.
    pure integer(i8) function assemble(s0, s1, s2, s3) result(v)
        integer(i8), intent(in) :: s0, s1, s2, s3
        integer(i8) :: w0, w1, w2, w3
        w0 = iand(s0, LIMB)
        w1 = s1 + shiftr(s0, 16)
        w2 = s2 + shiftr(w1, 16)
        w3 = s3 + shiftr(w2, 16)
        v = from_hex(iand(w3, LIMB), iand(w2, LIMB), iand(w1, LIMB), w0)
    end function assemble

    pure integer(i8) function add64(a, b)
        integer(i8), intent(in) :: a, b
        add64 = assemble(iand(a, LIMB) + iand(b, LIMB), &
            iand(shiftr(a, 16), LIMB) + iand(shiftr(b, 16), LIMB), &
            iand(shiftr(a, 32), LIMB) + iand(shiftr(b, 32), LIMB), &
            shiftr(a, 48) + shiftr(b, 48))
    end function add64

    !> a b modulo 2^64 from the products of 16-bit limbs, written out (scalars: the limb
    !> arrays of a loop version cost 150 ns a hash, a tenth of a coarsening's selection).
    pure integer(i8) function mul64(a, b)
        integer(i8), intent(in) :: a, b
        integer(i8) :: a0, a1, a2, a3, b0, b1, b2, b3
        a0 = iand(a, LIMB)
        a1 = iand(shiftr(a, 16), LIMB)
        a2 = iand(shiftr(a, 32), LIMB)
        a3 = shiftr(a, 48)
        b0 = iand(b, LIMB)
        b1 = iand(shiftr(b, 16), LIMB)
        b2 = iand(shiftr(b, 32), LIMB)
        b3 = shiftr(b, 48)
        ! each product < 2^32; the sums and the carries stay below 2^40
        mul64 = assemble(a0 * b0, a0 * b1 + a1 * b0, a0 * b2 + a1 * b1 + a2 * b0, &
            a0 * b3 + a1 * b2 + a2 * b1 + a3 * b0)
    end function mul64
end module sph_coarsen
