!> Virtual particles of a transition zone (thesis sec. 3.3, Figure 1-4): where two
!> resolution levels meet, each level's real particles near the interface need neighbours of
!> their own level on the other side. Those are virtual particles, made from the other
!> level's particles by one of two rules (&refinement virtual_rule).
!> The split rule (the default):
!>  - fine virtuals: each coarse particle gives 2^dim children at its position +- dx/4 per
!>    axis, each with a 2^-dim share of its mass. On a lattice these are the sites the
!>    refinement construction below gives; where the flow has deformed the coarse particles
!>    every one still gives exactly 2^dim, so the fine virtuals that turn real carry the
!>    coarse particles' mass. The child at + dx/4 along an axis is even along it (parity).
!>  - coarse virtuals: every fine particle of parity 0, translated by -dx/2 per axis, with
!>    2^dim times its mass: one in 2^dim of the fine particles, whatever their arrangement.
!>  Measured on the cylinder with a fine ring (input/cylinder_multires.nml, to 3000 s): the
!>  real mass wanders within +-2 % instead of falling by 17 %, and the drag is within 1 % of
!>  the uniformly fine run's instead of 39 % below it (doc/multiresolution.md).
!> The remeshing rule keeps the flow's disorder at the fine scale too:
!>  - fine virtuals from coarse particles: sph_refine's construction (old sites, edge
!>    midpoints, face and cube centres: 2^dim per coarse particle), translated by half a fine
!>    spacing along every axis. The construction alone yields the lattice {k dx_f} from a
!>    coarse lattice at (i + 1/2) dx, while the fine real particles sit at (k + 1/2) dx_f (both
!>    lattices start half a spacing from the box, as sph_initial makes them): untranslated,
!>    the virtual and real fine rows would be half a spacing out of step at the interface (a
!>    gap of 1.5 dx_f on one side, a clump on the other). The translation moves the whole set
!>    rigidly, so every relative position (the disorder) is kept.
!>  - coarse virtuals from fine particles: sph_coarsen's selection (one in 2^dim), translated
!>    back by half a fine spacing along every axis.
!> Lattice parity. Every particle carries its parity (one bit per axis: odd along that axis),
!> set where it is made and kept as it moves: on sph_initial's lattices from the site index
!> (sites i = 1, 2, ... at (i - 1/2) dx), for a fine virtual from the refinement key: the
!> child at a coarse particle's own site has parity 0, an edge midpoint is odd along the
!> edge, a face or cube centre along the axes it spans. The coarsening keeps, first, the
!> particles of parity 0 (sph_coarsen's given_match): on a lattice those are the sites
!> (2 k - 1/2) dx_f, which continue the coarse lattice (k - 1/2) dx shifted by dx_f / 2; among
!> refined particles they are the children at their parents' sites. Parity from positions
!> (sph_coarsen's own rule) would flip the whole kept set by one fine spacing whenever the flow
!> has carried the fine particles a quarter spacing past the lattice: the coarse virtuals
!> would jump by half a coarse spacing against the coarse real particles they continue, and
!> the fine virtuals refined from both would lose whole rows at the interface. Carried, the
!> kept set moves with the flow.
!> The driver hands in the source level's particles around the zone (real ones and the
!> previous step's virtual ones, so the construction is complete across the interface) and
!> keeps the new positions that lie in the zone.
!> Fields: gathered from the source level's particles with the moment properties of M4'
!> (thesis eq. 3.19): on a lattice, M4' interpolation reproduces every polynomial up to
!> degree two (its second moment vanishes). On the disordered sources of a transition zone
!> its weights lose that property, and they cannot serve as least-squares weights (the
!> vanishing second moment makes the moment matrix singular). So the weights are built on
!> the actual arrangement to have it: quadratic moving least squares with the positive M4
!> B-spline (tensor product, h = the source spacing) as weight, phi_k = W_k q(d_k)^T M^-1
!> q(0), q = (1, d, d d^T). A quadratic field (Poiseuille's profile) is reproduced to
!> round-off on any arrangement with enough sources. Where the moment matrix is not safely
!> invertible (one-sided or sparse sources) the linear form is used, and where that fails
!> too, the Shepard (normalised) mean; fallbacks are counted. "Safely" includes the weights'
!> amplification: sum |phi_k| above MAX_AMPLIFICATION (2; 1.25-1.5 inside a lattice) means
!> the stencil extrapolates (a target beyond one-sided sources, e.g. the first row next to a
!> wall), where a quadratic fit gave fine virtual particles 300 times the flow's speed.
!> Densities and masses outside the range of the sources that carry weight (least squares
!> extrapolating from one-sided sources) are clipped to that range, so no new extremes appear
!> (counted too).
!> Virtual particles have negative ids: -(1 + hash of what made them, 62 bits), so they never
!> collide with a real particle's id; a virtual that turns real gets a fresh global id.
!> Serial, no MPI.
module sph_transition
    use sph_kinds, only: wp, i8
    use sph_refine, only: refine_positions
    use sph_remesh_images, only: with_periodic_images
    use sph_coarsen, only: coarsen_select, id_hash
    use sph_key_sort, only: id_order   ! the stable id sort (serial)
    use sph_cell_list, only: neighbour_list_t, build_cross_list, build_neighbour_list
    use sph_solids, only: solids_t, solid_distance, solid_normal, SOLID_PLANE
    use sph_interpolation_kernels, only: INTERP_M4, interp_weight, interp_support, m4_bspline
    implicit none
    private
    !> largest sum of |weights| accepted from a least-squares stencil (see the header)
    real(wp), parameter :: MAX_AMPLIFICATION = 2.0_wp
    public :: fine_virtual_positions, coarse_virtual_positions, interpolate_fields
    public :: fine_virtual_split, coarse_virtual_parity
    public :: virtual_id, image_source_id, bisect, fit_to_bodies, fill_next_to_bodies, nearest_body

contains

    !> Id of a virtual particle of `level` made from the key (k1, k2): negative, 62 bits of
    !> hash, the same on any rank count (keys derive from the source particles' ids). The
    !> keys are hashed in turn (id_hash is a bijection), so two keys collide only by chance.
    !> (Hashed side by side, h(k1) xor h(k2 + level), every key with k1 = k2 + level gave
    !> the id of h(0): an edge between places a and 4 a has the key (4 a + 1, 4 a), and the
    !> refinement of a uniform state gave two virtual particles one id.)
    pure integer(i8) function virtual_id(level, k1, k2)
        integer, intent(in) :: level
        integer(i8), intent(in) :: k1, k2
        integer(i8) :: z
        z = id_hash(ieor(id_hash(ieor(id_hash(k1), k2)), int(level, i8)))
        virtual_id = -(1_i8 + iand(z, ishft(1_i8, 62) - 1_i8))
    end function virtual_id

    !> Source id for the remeshing rules, which need distinct ids below 2^61: a real id (below
    !> 2^55) as it is, a virtual one (negative) as 2^55 + its hash bits modulo 2^55; a periodic
    !> image (a ghost outside the box) gets its image's code (1..27, from which side of the box
    !> it lies on along each axis) in bits 56-60. Images are recognised by position only, so
    !> every rank count sees the same ids. Two virtual particles of one source set may (rarely:
    !> about n^2 / 2^56) share an id; the caller drops such duplicates.
    pure integer(i8) function image_source_id(id, x, box_lo, box_hi, dim)
        integer(i8), intent(in) :: id
        real(wp), intent(in) :: x(3), box_lo(3), box_hi(3)
        integer, intent(in) :: dim
        integer :: a, code, side
        code = 0
        do a = dim, 1, -1
            side = 1
            if (x(a) < box_lo(a)) side = 0
            if (x(a) >= box_hi(a)) side = 2
            code = 3 * code + side
        end do
        ! 13 = (1, 1, 1): inside on every axis
        if (dim == 2) code = code + 9
        image_source_id = id
        if (id < 0) image_source_id = ibset(iand(-id, ishft(1_i8, 55) - 1_i8), 55)
        if (code /= 13) image_source_id = image_source_id + shiftl(int(code, i8) + 1_i8, 56)
    end function image_source_id

    !> Fine virtual positions (spacing dx/2) from particles x(:, 1:n) of spacing dx: the
    !> refinement construction translated by dx/4 per axis (see the header). vid: their ids.
    subroutine fine_virtual_positions(dim, level, n, x, ids, dx, n_new, x_new, vid, parity, &
            stat, errmsg)
        integer, intent(in) :: dim, level, n
        real(wp), intent(in) :: x(:, :), dx
        integer(i8), intent(in) :: ids(:)
        integer, intent(out) :: n_new
        real(wp), allocatable, intent(out) :: x_new(:, :)
        integer(i8), allocatable, intent(out) :: vid(:)
        integer, allocatable, intent(out) :: parity(:)
        integer, intent(out) :: stat
        character(len=*), intent(out) :: errmsg
        integer(i8), allocatable :: key(:, :), sorted_ids(:)
        integer, allocatable :: order(:)
        integer :: k, a, corner
        call refine_positions(dim, n, x, ids, dx, n_new, x_new, key, stat, errmsg)
        if (stat /= 0) n_new = 0
        allocate(vid(max(n_new, 0)), parity(max(n_new, 0)))
        if (n_new == 0) return
        ! the corner a child's key starts from (its lowest id), found by bisection
        allocate(order(n))
        call id_order(ids, n, order)
        sorted_ids = ids(order)
        do k = 1, n_new
            parity(k) = 0
            if (iand(key(1, k), 3_i8) /= 0_i8) then
                corner = order(bisect(sorted_ids, shiftr(key(1, k), 2)))
                do a = 1, dim
                    if (abs(x_new(a, k) - x(a, corner)) > 0.25_wp * dx) &
                        parity(k) = ibset(parity(k), a - 1)
                end do
            end if
            x_new(1:dim, k) = x_new(1:dim, k) + 0.25_wp * dx
            vid(k) = virtual_id(level, key(1, k), key(2, k))
        end do
    end subroutine fine_virtual_positions

    !> New fine positions x(:, 1:n) (relative to origin, spacing dx_new) fitted to the bodies
    !> (solids that are not planes) as a fresh lattice is (sph_initial): a point closer than
    !> dx_new / 2 to a body's surface is pushed out along its normal to dx_new / 2, one
    !> deeper than dx_new / 2 inside is dropped (keep = .false.). The refinement of a uniform
    !> state constructs its points from the sources and their mirrors and shifts them by a
    !> quarter of the old spacing (fine_virtual_positions): next to a curved surface that
    !> shift carries the surface row into the body on one side, and dropping what lay inside
    !> left a band of L/50 around Morris' cylinder 41 particles short of a fresh start's 496,
    !> its viscous drag half of that run's. A pushed point closer than MIN_PUSHED_GAP dx_new
    !> (0.6: a fresh lattice's closest pairs next to a body) to a kept one is dropped too (the
    !> points unmoved first, then the pushed ones in their order: the result depends on
    !> positions and order only, not on ranks; neighbours across periodic faces included).
    subroutine fit_to_bodies(dim, n, x, origin, dx_new, solids, box, keep)
        integer, intent(in) :: dim, n
        real(wp), intent(inout) :: x(:, :)
        real(wp), intent(in) :: origin(3), dx_new
        type(solids_t), intent(in) :: solids
        !> the periodic lengths (x in [0, box); an axis of walls: a length so large that its
        !> images meet nothing), for the neighbours across periodic faces
        real(wp), intent(in) :: box(3)
        logical, intent(out) :: keep(:)
        real(wp), parameter :: MIN_PUSHED_GAP = 0.6_wp
        type(neighbour_list_t) :: nl
        real(wp), allocatable :: xi(:, :)
        integer, allocatable :: orig(:)
        integer :: ntot
        logical, allocatable :: pushed(:)
        real(wp) :: d, best, normal(3), y(3)
        integer :: k, s, nearest, t, j
        keep(1:n) = .true.
        if (.not. allocated(solids%list)) return
        if (all(solids%list(:)%shape == SOLID_PLANE)) return
        allocate(pushed(n))
        pushed = .false.
        do k = 1, n
            y = x(:, k) + origin
            y(dim + 1:) = 0.0_wp
            call nearest_body(solids, y, best, nearest)
            if (best >= 0.5_wp * dx_new) cycle
            if (best < -0.5_wp * dx_new) then
                keep(k) = .false.
                cycle
            end if
            normal = solid_normal(solids%list(nearest), y)
            normal(dim + 1:) = 0.0_wp
            x(:, k) = x(:, k) + (0.5_wp * dx_new - best) * normal
            pushed(k) = .true.
        end do
        if (.not. any(pushed)) return
        call with_periodic_images(dim, n, x, .true., box, MIN_PUSHED_GAP * dx_new, xi, orig, &
            ntot)
        call build_neighbour_list(xi, ntot, n, dim, MIN_PUSHED_GAP * dx_new, nl, &
            cell_size=0.5_wp * dx_new)
        do k = 1, n
            if (.not. pushed(k) .or. .not. keep(k)) cycle
            do t = nl%start(k), nl%start(k + 1) - 1
                j = orig(nl%index(t))
                if (j == k .or. .not. keep(j)) cycle
                if (pushed(j) .and. j > k) cycle
                keep(k) = .false.
                exit
            end do
        end do
    end subroutine fit_to_bodies

    !> Sites of the lattice of spacing dx_new (box_lo + (i - 1/2) dx_new, as sph_initial lays
    !> it) outside every body and within FILL_BAND dx_new of one, pushed out to dx_new / 2 as
    !> a fresh lattice's are, taken in site order where no point of x(:, keep) and no site
    !> taken before lies within fill_gap dx_new. The construction leaves irregular cells next
    !> to a curved surface without their centres (and the mirrors across it do not close
    !> them): refining a uniform state, the band around Morris' cylinder (L/25 -> L/50) had
    !> 23 particles in its first row where a fresh start has 66. Only sites within the box of
    !> the points x (padded by FILL_BAND dx_new) are looked at. Returns the sites (relative to
    !> box_lo), their lattice parities (odd index along an axis: its bit set) and linear
    !> indices (1 + (i - 1) + n1 ((j - 1) + n2 (k - 1)), for ids).
    subroutine fill_next_to_bodies(dim, n, x, keep, box_lo, box_hi, dx_new, solids, fill_gap, &
            box, n_fill, x_fill, parity_fill, site_fill, band)
        integer, intent(in) :: dim, n
        real(wp), intent(in) :: x(:, :), box_lo(3), box_hi(3), dx_new, fill_gap
        !> as fit_to_bodies' (the neighbours across periodic faces)
        real(wp), intent(in) :: box(3)
        logical, intent(in) :: keep(:)
        type(solids_t), intent(in) :: solids
        integer, intent(out) :: n_fill
        real(wp), allocatable, intent(out) :: x_fill(:, :)
        integer, allocatable, intent(out) :: parity_fill(:)
        integer(i8), allocatable, intent(out) :: site_fill(:)
        !> the band (in dx_new) whose sites are candidates (default FILL_BAND)
        real(wp), intent(in), optional :: band
        real(wp), parameter :: FILL_BAND = 1.5_wp
        real(wp) :: reach_band
        real(wp), allocatable :: xc(:, :), all_points(:, :), xi(:, :)
        integer, allocatable :: idx_c(:, :), orig(:)
        integer :: ntot
        integer :: n_sites(3), lo(3), hi(3), idx(3), a, i, j, k, s, nc, t, m
        real(wp) :: y(3), d, best, normal(3), xmin(3), xmax(3)
        type(neighbour_list_t) :: nl
        logical, allocatable :: taken(:)
        integer :: nearest
        n_fill = 0
        allocate(x_fill(3, 0), parity_fill(0), site_fill(0))
        reach_band = FILL_BAND
        if (present(band)) reach_band = band
        if (.not. allocated(solids%list)) return
        if (all(solids%list(:)%shape == SOLID_PLANE)) return
        if (.not. any(keep(1:n))) return
        n_sites = 1
        lo = 1
        hi = 1
        xmin = 0.0_wp
        xmax = 0.0_wp
        do a = 1, dim
            n_sites(a) = nint((box_hi(a) - box_lo(a)) / dx_new)
            xmin(a) = minval(x(a, 1:n), mask=keep(1:n)) - reach_band * dx_new
            xmax(a) = maxval(x(a, 1:n), mask=keep(1:n)) + reach_band * dx_new
            lo(a) = max(1, floor(xmin(a) / dx_new + 0.5_wp))
            hi(a) = min(n_sites(a), ceiling(xmax(a) / dx_new + 0.5_wp))
        end do
        ! candidates: sites outside the bodies and within the band of one, pushed out
        allocate(xc(3, 64), idx_c(3, 64))
        nc = 0
        do k = lo(3), hi(3)
            do j = lo(2), hi(2)
                do i = lo(1), hi(1)
                    idx = [i, j, k]
                    y = 0.0_wp
                    y(1:dim) = (real(idx(1:dim), wp) - 0.5_wp) * dx_new
                    call nearest_body(solids, y + box_lo, best, nearest)
                    if (best <= 0.0_wp .or. best >= reach_band * dx_new) cycle
                    if (best < 0.5_wp * dx_new) then
                        normal = solid_normal(solids%list(nearest), y + box_lo)
                        normal(dim + 1:) = 0.0_wp
                        y = y + (0.5_wp * dx_new - best) * normal
                    end if
                    if (nc == size(idx_c, 2)) then
                        xc = reshape([xc, spread(0.0_wp, 1, 3 * nc)], [3, 2 * nc])
                        idx_c = reshape([idx_c, spread(0, 1, 3 * nc)], [3, 2 * nc])
                    end if
                    nc = nc + 1
                    xc(:, nc) = y
                    idx_c(:, nc) = idx
                end do
            end do
        end do
        if (nc == 0) return
        ! the points, then the candidates; a candidate is taken when no point and no candidate
        ! taken before it lies within the gap
        m = count(keep(1:n))
        allocate(all_points(3, m + nc))
        all_points(:, 1:m) = x(:, pack([(i, i = 1, n)], keep(1:n)))
        all_points(dim + 1:, 1:m) = 0.0_wp
        all_points(:, m + 1:) = xc(:, 1:nc)
        call with_periodic_images(dim, m + nc, all_points, .true., box, fill_gap * dx_new, xi, &
            orig, ntot)
        call build_neighbour_list(xi, ntot, m + nc, dim, fill_gap * dx_new, nl, &
            cell_size=0.5_wp * dx_new)
        allocate(taken(nc))
        taken = .false.
        do i = 1, nc
            taken(i) = .true.
            do t = nl%start(m + i), nl%start(m + i + 1) - 1
                j = orig(nl%index(t))
                if (j == m + i) cycle
                if (j <= m) then
                    taken(i) = .false.
                else if (j < m + i) then
                    if (taken(j - m)) taken(i) = .false.
                end if
                if (.not. taken(i)) exit
            end do
        end do
        n_fill = count(taken)
        x_fill = xc(:, pack([(i, i = 1, nc)], taken))
        deallocate(parity_fill, site_fill)
        allocate(parity_fill(n_fill), site_fill(n_fill))
        j = 0
        do i = 1, nc
            if (.not. taken(i)) cycle
            j = j + 1
            parity_fill(j) = 0
            do a = 1, dim
                if (mod(idx_c(a, i), 2) == 1) parity_fill(j) = ibset(parity_fill(j), a - 1)
            end do
            site_fill(j) = 1 + (idx_c(1, i) - 1) + int(n_sites(1), i8) * ((idx_c(2, i) - 1) + &
                int(n_sites(2), i8) * (idx_c(3, i) - 1))
        end do
    end subroutine fill_next_to_bodies

    !> The body (a solid that is not a plane) nearest y and the signed distance to its
    !> surface (huge and 0 when there is none).
    pure subroutine nearest_body(solids, y, best, nearest)
        type(solids_t), intent(in) :: solids
        real(wp), intent(in) :: y(3)
        real(wp), intent(out) :: best
        integer, intent(out) :: nearest
        real(wp) :: d
        integer :: s
        best = huge(1.0_wp)
        nearest = 0
        do s = 1, size(solids%list)
            if (solids%list(s)%shape == SOLID_PLANE) cycle
            d = solid_distance(solids%list(s), y)
            if (d < best) then
                best = d
                nearest = s
            end if
        end do
    end subroutine nearest_body

    !> Position of value in the ascending list s where it is there; otherwise the first
    !> position holding a larger value (size(s) when none does, 1 when s is empty).
    pure integer function bisect(s, value) result(k)
        integer(i8), intent(in) :: s(:), value
        integer :: lo, hi
        lo = 1
        hi = size(s)
        do while (lo < hi)
            k = (lo + hi) / 2
            if (s(k) < value) then
                lo = k + 1
            else
                hi = k
            end if
        end do
        k = lo
    end function bisect

    !> Coarse virtual positions (spacing 2 dx) from particles x(:, 1:n) of spacing dx with
    !> lattice parities src_parity: the coarsening selection, parity 0 first, translated by
    !> -dx/2 per axis (see the header). vid: their ids; parity: theirs on the lattice of
    !> spacing 4 dx measured from `origin` (the box's lower corner: only a third level uses it).
    subroutine coarse_virtual_positions(dim, level, n, x, ids, src_parity, dx, origin, n_new, &
            x_new, vid, parity, stat, errmsg)
        integer, intent(in) :: dim, level, n
        real(wp), intent(in) :: x(:, :), dx, origin(3)
        integer(i8), intent(in) :: ids(:)
        integer, intent(in) :: src_parity(:)
        integer, intent(out) :: n_new
        real(wp), allocatable, intent(out) :: x_new(:, :)
        integer(i8), allocatable, intent(out) :: vid(:)
        integer, allocatable, intent(out) :: parity(:)
        integer, intent(out) :: stat
        character(len=*), intent(out) :: errmsg
        integer, allocatable :: kept(:), tag(:)
        integer :: k
        call coarsen_select(dim, n, x, ids, dx, n_new, kept, tag, stat, errmsg, &
            given_match=src_parity(1:n) == 0)
        if (stat /= 0) n_new = 0
        allocate(x_new(3, max(n_new, 1)), vid(max(n_new, 0)), parity(max(n_new, 0)))
        do k = 1, n_new
            x_new(:, k) = x(:, kept(k))
            x_new(1:dim, k) = x_new(1:dim, k) - 0.5_wp * dx
            parity(k) = coarse_parity(dim, x_new(:, k), dx, origin)
            vid(k) = virtual_id(level, ids(kept(k)), 0_i8)
        end do
    end subroutine coarse_virtual_positions

    !> Fine virtual positions by the split rule (see the header) from particles x(:, 1:n) of
    !> spacing dx: 2^dim children of each at +- dx/4 per axis. vid: their ids (from the
    !> source's id and the child's corner, so a child keeps its id from one update to the
    !> next); parity: bit a-1 set for the child at - dx/4 along axis a; parent: the source.
    pure subroutine fine_virtual_split(dim, level, n, x, ids, dx, n_new, x_new, vid, parity, &
            parent)
        integer, intent(in) :: dim, level, n
        real(wp), intent(in) :: x(:, :), dx
        integer(i8), intent(in) :: ids(:)
        integer, intent(out) :: n_new
        real(wp), allocatable, intent(out) :: x_new(:, :)
        integer(i8), allocatable, intent(out) :: vid(:)
        integer, allocatable, intent(out) :: parity(:), parent(:)
        integer :: i, corner, a, k, n_child
        n_child = 2**dim
        n_new = n * n_child
        allocate(x_new(3, max(n_new, 1)), vid(max(n_new, 0)), parity(max(n_new, 0)), &
            parent(max(n_new, 0)))
        k = 0
        do i = 1, n
            do corner = 0, n_child - 1
                k = k + 1
                x_new(:, k) = x(:, i)
                do a = 1, dim
                    x_new(a, k) = x_new(a, k) + merge(-0.25_wp, 0.25_wp, btest(corner, a - 1)) &
                        * dx
                end do
                parity(k) = corner
                parent(k) = i
                ! the corner's key is negative: ids are not negative, so no (source,
                ! corner) key can equal a key of two ids
                vid(k) = virtual_id(level, ids(i), -16_i8 - corner)
            end do
        end do
    end subroutine fine_virtual_split

    !> Coarse virtual positions by the split rule (see the header) from particles x(:, 1:n) of
    !> spacing dx with lattice parities src_parity: every particle of parity 0, translated by
    !> -dx/2 per axis. vid, parity (on the lattice of spacing 4 dx measured from origin, as
    !> in coarse_virtual_positions) and parent: the source of each.
    pure subroutine coarse_virtual_parity(dim, level, n, x, ids, src_parity, dx, origin, &
            n_new, x_new, vid, parity, parent)
        integer, intent(in) :: dim, level, n
        real(wp), intent(in) :: x(:, :), dx, origin(3)
        integer(i8), intent(in) :: ids(:)
        integer, intent(in) :: src_parity(:)
        integer, intent(out) :: n_new
        real(wp), allocatable, intent(out) :: x_new(:, :)
        integer(i8), allocatable, intent(out) :: vid(:)
        integer, allocatable, intent(out) :: parity(:), parent(:)
        integer :: i, k
        n_new = count(src_parity(1:n) == 0)
        allocate(x_new(3, max(n_new, 1)), vid(max(n_new, 0)), parity(max(n_new, 0)), &
            parent(max(n_new, 0)))
        k = 0
        do i = 1, n
            if (src_parity(i) /= 0) cycle
            k = k + 1
            x_new(:, k) = x(:, i)
            x_new(1:dim, k) = x_new(1:dim, k) - 0.5_wp * dx
            parity(k) = coarse_parity(dim, x_new(:, k), dx, origin)
            parent(k) = i
            vid(k) = virtual_id(level, ids(i), 0_i8)
        end do
    end subroutine coarse_virtual_parity

    !> Parity of a coarse particle (spacing 2 dx) at y on the lattice of spacing 4 dx from
    !> origin: bit a-1 set where y sits on an odd site along axis a.
    pure integer function coarse_parity(dim, y, dx, origin) result(parity)
        integer, intent(in) :: dim
        real(wp), intent(in) :: y(3), dx, origin(3)
        integer :: a
        parity = 0
        do a = 1, dim
            if (mod(nint((y(a) - origin(a)) / (2.0_wp * dx) + 0.5_wp), 2) == 1) &
                parity = ibset(parity, a - 1)
        end do
    end function coarse_parity

    !> f_dst(:, a) = the interpolant at x_dst(:, a) of the source values f_src(:, 1:n_src)
    !> (see the header: M4', linear MLS correction, h the source spacing). A target with no
    !> source in reach keeps f_dst = 0 and is counted in n_empty; n_fallback counts targets
    !> that needed the M4 or Shepard fallback.
    subroutine interpolate_fields(dim, h, n_src, x_src, f_src, n_dst, x_dst, f_dst, &
            n_fallback, n_empty, n_clipped, clip)
        integer, intent(in) :: dim, n_src, n_dst
        real(wp), intent(in) :: h, x_src(:, :), f_src(:, :), x_dst(:, :)
        real(wp), intent(out) :: f_dst(:, :)
        integer, intent(out) :: n_fallback, n_empty
        integer, intent(out) :: n_clipped   !< values clipped to their sources' range
        !> the fields to clip (default none): density and mass, never a velocity, whose
        !> profile next to a wall lies beyond all its one-sided sources
        logical, intent(in), optional :: clip(:)
        real(wp) :: lo_f, hi_f
        type(neighbour_list_t) :: nl
        integer :: a, k, j, nf
        integer, allocatable :: near(:)
        real(wp), allocatable :: dn(:, :)
        real(wp) :: phi_weights(64 * 27)
        integer :: n_near
        logical :: ok

        nf = size(f_src, 1)
        n_fallback = 0
        n_empty = 0
        n_clipped = 0
        if (n_dst <= 0) return
        f_dst(:, 1:n_dst) = 0.0_wp
        ! the tensor kernel's support is a cube of half-width 2 h
        call build_cross_list(x_dst, n_dst, x_src, n_src, dim, &
            interp_support(INTERP_M4) * h * (1.0_wp + 1.0e-12_wp), nl)
        allocate(near(size(phi_weights)), dn(3, size(phi_weights)))
        do a = 1, n_dst
            n_near = 0
            do k = nl%start(a), nl%start(a + 1) - 1
                j = nl%index(k)
                if (n_near == size(near)) exit
                n_near = n_near + 1
                near(n_near) = j
                dn(:, n_near) = (x_src(:, j) - x_dst(:, a)) / h
            end do
            if (n_near == 0) then
                n_empty = n_empty + 1
                cycle
            end if
            call mls_weights(2, dim, n_near, dn, phi_weights, ok)
            if (.not. ok) then
                n_fallback = n_fallback + 1
                call mls_weights(1, dim, n_near, dn, phi_weights, ok)
                if (.not. ok) call shepard_weights(dim, n_near, dn, phi_weights, ok)
                if (.not. ok) then
                    n_empty = n_empty + 1
                    cycle
                end if
            end if
            do k = 1, n_near
                f_dst(1:nf, a) = f_dst(1:nf, a) + phi_weights(k) * f_src(1:nf, near(k))
            end do
            ! no new extremes: a value outside the range of the sources with weight (one-sided
            ! sources at a cloud's edge make least squares extrapolate) is clipped to it
            do j = 1, nf
                if (.not. present(clip)) exit
                if (.not. clip(j)) cycle
                lo_f = huge(1.0_wp)
                hi_f = -huge(1.0_wp)
                do k = 1, n_near
                    if (.not. abs(phi_weights(k)) > 0.0_wp) cycle
                    lo_f = min(lo_f, f_src(j, near(k)))
                    hi_f = max(hi_f, f_src(j, near(k)))
                end do
                if (f_dst(j, a) < lo_f .or. f_dst(j, a) > hi_f) then
                    n_clipped = n_clipped + 1
                    f_dst(j, a) = min(max(f_dst(j, a), lo_f), hi_f)
                end if
            end do
        end do
    end subroutine interpolate_fields

    !> Moving-least-squares weights of the given degree (1 or 2), M4 B-spline weight W at the
    !> offsets d_k (in units of h): phi_k = W_k q(d_k)^T c with M c = q(0), so that the
    !> weights reproduce every polynomial of that degree. ok = .false. when the moment matrix
    !> is not safely invertible (relative pivot below 1e-8).
    pure subroutine mls_weights(degree, dim, n, d, phi, ok)
        integer, intent(in) :: degree, dim, n
        real(wp), intent(in) :: d(:, :)
        real(wp), intent(out) :: phi(:)
        logical, intent(out) :: ok
        real(wp) :: m(10, 10), rhs(10), w
        real(wp) :: q(10, n)
        integer :: k, r, i, nb
        nb = basis_size(degree, dim)
        m = 0.0_wp
        ! each neighbour's basis once, the moment matrix's upper triangle (it is symmetric:
        ! the full update and a second evaluation of the basis were most of a refresh of
        ! the virtual particles, itself a seventh of a sub-cycled multi-resolution step)
        do k = 1, n
            ! interp_weight(INTERP_M4, dim, d(:, k), 1.0_wp), the same product without its
            ! dispatch (a tenth of the refresh)
            w = m4_bspline(d(1, k))
            if (dim >= 2) w = w * m4_bspline(d(2, k))
            if (dim == 3) w = w * m4_bspline(d(3, k))
            phi(k) = w
            ! the basis (1, d_a, d_a d_b for a <= b), written in place and read back element by
            ! element (an array result copied as a whole stalled on the store of its elements)
            q(1, k) = 1.0_wp
            q(2:dim + 1, k) = d(1:dim, k)
            if (degree >= 2) then
                r = dim + 1
                do i = 1, dim
                    q(r + 1:r + dim - i + 1, k) = d(i, k) * d(i:dim, k)
                    r = r + dim - i + 1
                end do
            end if
            if (.not. w > 0.0_wp) cycle
            do r = 1, nb
                do i = 1, r
                    m(i, r) = m(i, r) + (w * q(i, k)) * q(r, k)
                end do
            end do
        end do
        do r = 1, nb - 1
            m(r + 1:nb, r) = m(r, r + 1:nb)
        end do
        rhs = 0.0_wp
        rhs(1) = 1.0_wp
        call solve_small(nb, m, rhs, ok)
        if (.not. ok) return
        do k = 1, n
            if (.not. phi(k) > 0.0_wp) cycle   ! outside the B-spline's support
            phi(k) = phi(k) * dot_product(rhs(1:nb), q(1:nb, k))
        end do
        ! a stencil that amplifies (one-sided sources: extrapolation) is refused, so the
        ! caller falls back to a lower degree
        ok = sum(abs(phi(1:n))) <= MAX_AMPLIFICATION
    end subroutine mls_weights

    pure integer function basis_size(degree, dim)
        integer, intent(in) :: degree, dim
        basis_size = 1 + dim
        if (degree >= 2) basis_size = basis_size + dim * (dim + 1) / 2
    end function basis_size

    !> Normalised M4 B-spline weights (zeroth order).
    pure subroutine shepard_weights(dim, n, d, phi, ok)
        integer, intent(in) :: dim, n
        real(wp), intent(in) :: d(:, :)
        real(wp), intent(out) :: phi(:)
        logical, intent(out) :: ok
        integer :: k
        real(wp) :: total
        do k = 1, n
            phi(k) = interp_weight(INTERP_M4, dim, d(:, k), 1.0_wp)
        end do
        total = sum(phi(1:n))
        ok = total > 0.0_wp
        if (ok) phi(1:n) = phi(1:n) / total
    end subroutine shepard_weights

    !> Solve m(1:n, 1:n) y = b in place (b becomes y) by Gaussian elimination with partial
    !> pivoting; ok = .false. if a pivot falls below 1e-8 of the largest entry.
    pure subroutine solve_small(n, m, b, ok)
        integer, intent(in) :: n
        real(wp), intent(inout) :: m(10, 10), b(10)
        logical, intent(out) :: ok
        integer :: i, k, piv
        real(wp) :: f, scale, row(10), t
        scale = maxval(abs(m(1:n, 1:n)))
        ok = scale > 0.0_wp
        if (.not. ok) return
        do k = 1, n
            piv = k - 1 + maxloc(abs(m(k:n, k)), 1)
            if (abs(m(piv, k)) < 1.0e-8_wp * scale) then
                ok = .false.
                return
            end if
            if (piv /= k) then
                row = m(k, :); m(k, :) = m(piv, :); m(piv, :) = row
                t = b(k); b(k) = b(piv); b(piv) = t
            end if
            do i = k + 1, n
                f = m(i, k) / m(k, k)
                m(i, k:n) = m(i, k:n) - f * m(k, k:n)
                b(i) = b(i) - f * b(k)
            end do
        end do
        do k = n, 1, -1
            b(k) = (b(k) - dot_product(m(k, k + 1:n), b(k + 1:n))) / m(k, k)
        end do
    end subroutine solve_small
end module sph_transition
