!> Coarse-to-fine particle positions (thesis sec. 3.2.1, with the count corrected as in the
!> errata). Serial, no MPI, positions only: the fields are handed on by sph_remesh_interp.
!>
!> Rule. Two old particles are neighbours (an "edge") when closer than EDGE_FACTOR * dx
!> (1.2 dx: a lattice's nearest neighbours at dx are in, its face diagonals at 1.41 dx out;
!> with +-5 % jitter per axis edges stay below 1.11 dx and diagonals above 1.27 dx). The new
!> set is
!>  - every old position (key (4 id, id));
!>  - the midpoint of every edge (key (4 min id + 1, max id));
!>  - the centre of every "face": a chordless 4-cycle a-b-c-d, found as a non-adjacent pair
!>    (a, c) with exactly two common neighbours b, d that are not adjacent themselves; key
!>    (4 id_lo + 2, id of the corner opposite the lowest-id corner id_lo);
!>  - in 3D the centre of every "cube": a pair (a, g), g not adjacent to a and not a face
!>    partner of a, adjacent to exactly three face partners c1..c3 of a; its 8 corners are
!>    a, g, the c's and the common neighbours of a with the c's; key (4 id_lo + 3, id of the
!>    corner opposite id_lo).
!> Each centre is the mean of its corners. On a lattice of N sites (periodic) this gives
!> N + dim N + (dim (dim - 1) / 2) N + [dim = 3] N = 2^dim N: 4N in 2D, 8N in 3D, a lattice
!> of spacing dx/2. Midpoints with the old sites give only N + dim N (3N in 2D, not 4N:
!> each site has 2 dim neighbours, each edge shared by two sites), leaving the cell centres
!> empty (errata).
!>
!> Keys. The low two bits of key(1) give the kind (0 site, 1 edge, 2 face, 3 cube), the rest
!> the lowest corner id; key(2) the opposite corner. A face is fixed by its diagonal (two
!> common neighbours only), a cube by its body diagonal, so keys are unique and depend only on
!> positions and ids, not on the storage order. Ids must lie in [0, 2^61). Positions of
!> centres are summed in id order from the lowest-id corner, so they are identical (bitwise)
!> whatever the input order. Every diagonal pair is examined from its lower-id end, so also
!> the irregular cases are decided independently of the order.
!>
!> Irregular neighbourhoods (a diagonal pair with more than two common neighbours, a cube
!> candidate with a wrong corner count) produce no centre and are counted (n_irregular):
!> on strongly disordered sets the count falls short of 2^dim N by that much.
!>
!> Thinning (with or without solids). A point is dropped when a point kept before it lies
!> within MIN_GAP = 0.4 new spacings (issue 10's floor; at 0.5 the pairs of a clumped flow
!> between the two went too, and the refined set came out more regular than the flow: its
!> nearest-distance CoV 0.168 against the flow's 0.229, Morris' L/25 cylinder at 1500 s).
!> Old positions that were not moved come first (among
!> themselves in key order: only the old set's own clumps are thinned there), the
!> constructed points (midpoints, centres) and those moved by the wall rule follow in the
!> order of their keys (a sequential greedy pass in key order, computed in rounds:
!> independent of storage order and ranks). On a lattice jittered by +-5 % nothing is dropped
!> (all pairs >= 0.9 dx_new). On clumped sets it matters: an old particle lying between two
!> neighbours closer than EDGE_FACTOR dx (three in a row 0.55 dx apart) sits on their
!> midpoint, and near-coincident pairs give midpoints and centres on top of each other
!> (Morris' cylinder at L/50, 1500 s: 50 new pairs below 0.4 dx_new, the closest 0.022,
!> in the clumps next to the periodic face x = 0; now none below 0.4 dx_new).
!>
!> Walls and bodies (optional solids, signed distance d > 0 in the fluid and normal n from
!> sph_solids; positions + origin are absolute). The rule above keeps every old particle, so
!> next to a surface the first new row would be where the old first row was: dx/2 = one NEW
!> spacing from it, while the regenerated wall particles sit at -dx_new/2, -3 dx_new/2, ...
!> (a gap of a whole new spacing instead of half of one). So:
!>  1. Mirrors. Every particle with 0 <= d < MIRROR_DEPTH dx (2 dx: two old rows) is mirrored
!>     across each such surface (sph_solids' solid_reflect: x - 2 d n) with id c span + id,
!>     span = 1 + the largest id, c the solid's number (a body's only where solid_mirrors
!>     allows: its images fill its inside once); the construction runs on the set and
!>     its mirrors, so the cells that straddle a surface (a particle, its mirror and their
!>     neighbours) get their midpoints and centres, ON the surface (d = 0 for a plane: a new
!>     row at the wall, as dense as the others). A particle and its own mirror are an edge
!>     when closer than MIRROR_EDGE = 2 dx (other pairs: EDGE_FACTOR dx): a developed flow
!>     keeps its first row 0.25-1 dx off a body, and with EDGE_FACTOR alone only the
!>     particles within 0.6 dx put their midpoints on the surface row (Morris' L/25 cylinder
!>     at 6000 s refined to 44 particles within one new spacing of the cylinder where the
!>     run made at L/50 holds 66; now 66). What lies deeper than dx/4 inside a solid
!>     (the mirrors' own rows, at <= -dx/2) is dropped. Next to a corner of paired planes
!>     (rule 2) a particle is also mirrored across two (in 3D three) of them that meet at
!>     right angles (codes above the solids' numbers), so that the corner's cell gets its
!>     centre too.
!>  2. Paired planes (facing walls: opposite normals, sph_solids' facing_plane). Between two
!>     walls M old rows apart the construction has 2 M + 1 rows, 0, dx/2, ..., M dx, one on
!>     each surface, where the lattice of spacing dx/2 has 2 M, at dx/4, 3 dx/4, ...,
!>     M dx - dx/4. So the row on the lower-numbered plane of each pair is dropped (d <
!>     SURFACE_TOL dx: the mirrors put it there exactly) and every point is shifted by dx/4
!>     towards that plane: a uniform shift keeps the set's disorder as it is, and a lattice
!>     between the walls (a developed channel flow) refines to the lattice, 2^dim N exactly,
!>     first rows half a new spacing off each wall (pair_map: the few points that the flow's
!>     disorder puts closer than dx/2 to the dropped plane, or behind the other one, are
!>     squeezed so that none ends closer than dx/8, continuously and monotonically). Within
!>     the band of any other solid (a body in a channel) the shift's component along that
!>     solid's normal fades out linearly towards its surface, where its own band map (3)
!>     puts the surface row; that band ends half-way to the next solid, so the walls' rows
!>     get the whole shift. (Fading the whole shift over 20 new spacings, a first version,
!>     left the first rows 0.35 and 0.65 new spacings off the walls of a channel whose body
!>     lay 7 old spacings from them.) In a closed box every pair drops one surface row: the
!>     lattice again, the corners' centres from the corner mirrors. Before, the band map (3)
!>     applied to the walls too: both surface rows stayed, 2 M + 1 rows compressed by
!>     (M - 1/2) / M (200 -> 820, not 800, for the L/20 Poiseuille channel, the refined
!>     flow's masses 1/40 smaller and its error at 1 s 1.17x that of the run made at L/40
!>     throughout).
!>  3. Band map (other solids: bodies, a plane that faces none). A new position at distance d1
!>     from its nearest such solid is moved along that solid's normal to g(d1) = dx/4 + d1 (b
!>     - dx/4) / b when d1 < b (d1 < 0 counts as 0), b = min(WALL_BAND dx_new, (d1 + d2) /
!>     2), d2 the distance to the next solid (or to the body's own next periodic image,
!>     next_image_distance): the row on the surface goes to half a NEW
!>     spacing, the rows behind it are compressed evenly by (b - dx/4) / b (1 - 1/40 for
!>     WALL_BAND = 20 new spacings, 10 old ones), beyond b nothing moves; b ends half-way to the next
!>     solid, where the maps of both are the identity, so the map is continuous and monotone.
!>     The map is smooth, so the disorder of the old set (and of the midpoint construction
!>     inside) is kept; only distances along the normal shrink slightly in the band.
!>  4. Thinning (below). Next to a curved or staircase surface (Morris' lattice bodies leave
!>     particles 0.1 dx from it) a particle and its mirror are close, and their cells give
!>     clumps and, where d < 0 collapses onto dx/4, duplicates; the moved points (old ones
!>     included; a uniform shift does not count as a move) are thinned like the constructed
!>     ones. Nothing is dropped next to a plane wall (all pairs >= 0.97 dx_new there).
!>     Morris' cylinder lattice (t = 0; scripts/validate's remesh_disorder, with the mirror
!>     edges of rule 1): L/50 2184 -> 8775 (4.02 N), minimum pair 0.51 dx_new; L/25 544 ->
!>     2177 (4.00 N), 0.53 dx_new; the particles left where clumps were thinned carry up to
!>     twice the median mass.
!> Result: first row at dx/4 = dx_new/2 from each surface (exactly for a plane; for
!> a curved surface the mirrored cells are centred on it to O(dx^2 / R)), no gap, nothing
!> inside; between paired planes 2^dim N (the lattice where the old set is one); next to a
!> body or a lone plane about one new row more per surface, less the half row the set lacked
!> next to it. The conservative transfer
!> (sph_remesh_driver) mirrors the old and new particles next to solids in the same way, so
!> the particles of the first row get a full stencil and masses that match their volume.
!>
!> Gap filling (optional n_target, rule 5). A developed flow that has clumped (Morris' cylinder
!> at 1500 s: pairs 0.1 dx apart, gaps between the clumps wider than EDGE_FACTOR dx) gives no
!> midpoints across its gaps and no centres in its irregular cells: 2.66 N (L/25) and 2.79 N
!> (L/50) instead of 4 N. Given n_target, the midpoints and then the quarter points of the old
!> pairs EDGE_FACTOR dx to FILL_PAIR_MAX = 2 dx apart are candidates (edge keys: such a pair
!> is no edge; the quarter points marked in key(2)'s top bits, and used only when the
!> midpoints cannot reach n_target: a regular clumping), not within dx/4 of a solid,
!> taken in key order when no point lies within FILL_GAP = 0.45 new spacings, and if that
!> takes more than n_target, the taken ones with the largest key hashes are dropped down to
!> it: the added points are a hashed choice among the free candidates, as disordered as the
!> clumps around them. (The largest radius that still reached n_target, found by bisection
!> before, packed the gaps evenly, and the filled third of the set made it more regular than
!> the flow: mean nearest distance 0.536 of the original's and CoV 0.229 -> 0.168 on the L/25
!> cylinder at 1500 s, against issue 10's 0.5 +- 5 % and 25 %; now 0.502 and 0.237, and
!> 0.495-0.51 with CoV within 15 % of the flow's at 1500 and 6000 s, L/25 and L/50.)
!> Nothing changes where the
!> construction is at most FILL_SLACK = 1 % short of n_target (lattices: Morris' L/50 cell at
!> t = 0 had 3.97 N before the mirror edges of rule 1, its irregular cells next to the
!> cylinder having no centre; the developed Poiseuille flow); the cylinder at 1500 s gets
!> 4 N, minimum pair 0.4 new spacings.
!>
!> Periodic: with box (lengths of the axes, domain [0, box)) neighbours are searched through
!> periodic images and new positions wrapped into the box; the box must exceed 4 EDGE_FACTOR
!> dx per axis so that no 4-cycle wraps around it. Without box the set is open and particles
!> at its edges get fewer children.
module sph_refine
    use sph_kinds, only: wp, i8
    use sph_cell_list, only: neighbour_list_t, build_neighbour_list
    use sph_remesh_images, only: with_periodic_images
    use sph_coarsen, only: id_hash
    use sph_key_sort, only: sort_by_keys
    use sph_solids, only: solids_t, solid_distance, solid_normal, solid_reflect, facing_plane, &
        corner_planes, MAX_CORNER_COMBOS, next_image_distance, solid_mirrors
    implicit none
    private
    public :: refine_positions, wall_map, EDGE_FACTOR, MIRROR_DEPTH, WALL_BAND, MIN_GAP
    public :: largest_remesh_id

    real(wp), parameter :: EDGE_FACTOR = 1.2_wp
    integer, parameter :: max_partners = 64
    !> wall rule (see the header): particles within MIRROR_DEPTH old spacings of a surface are
    !> mirrored; new positions within WALL_BAND new spacings of it are moved
    real(wp), parameter :: MIRROR_DEPTH = 2.0_wp
    !> a particle and its own mirror across one surface are an edge when closer than this
    !> (in old spacings; others EDGE_FACTOR): a developed flow's first row lies 0.25-1 old
    !> spacings off a body, and only the particles within EDGE_FACTOR / 2 of it put their
    !> midpoints on the surface row (header, rule 1)
    real(wp), parameter :: MIRROR_EDGE = 2.0_wp
    !> a particle within this (in old spacings) of the plane of a box's face counts as level
    !> with it: its image across the next face is kept (sph_solids' solid_mirrors), and makes
    !> the surface row of the face where no fluid lies beyond it
    real(wp), parameter :: MIRROR_LEVEL = 0.25_wp
    real(wp), parameter :: WALL_BAND = 20.0_wp
    !> smallest distance (in new spacings) a constructed or moved point keeps from the points
    !> kept before it (thinning, see the header)
    real(wp), parameter :: MIN_GAP = 0.4_wp
    !> gap filling (header, rule 5): the farthest old pairs whose midpoints are candidates
    !> (in old spacings), and the distance (in new spacings) a filled point keeps from every
    !> point
    real(wp), parameter :: FILL_PAIR_MAX = 2.0_wp
    real(wp), parameter :: FILL_FRACTION(0:2) = [0.5_wp, 0.25_wp, 0.75_wp]
    real(wp), parameter :: FILL_GAP = 0.45_wp
    !> the construction is kept as it is when at most this fraction short of the target
    real(wp), parameter :: FILL_SLACK = 0.01_wp
    !> paired planes (header, rule 2): a point closer than this (in old spacings) to the plane
    !> whose surface row is dropped lies on it (the mirror construction puts it there exactly)
    real(wp), parameter :: SURFACE_TOL = 1.0e-6_wp

    !> Points in cells that grow one point at a time (linked lists: head per cell, next per
    !> point), wrapping across the box when periodic: the gap filling's lookups.
    type :: point_cells_t
        integer :: dim = 2
        integer :: nc(3) = 1
        logical :: periodic = .false.
        real(wp) :: lo(3) = 0.0_wp, inv(3) = 0.0_wp, box(3) = 0.0_wp
        integer, allocatable :: head(:), next(:)
    end type point_cells_t

contains

    !> New positions at spacing dx/2 from the particles x(:, 1:n) of spacing dx (see the module
    !> header). solids, origin: the walls and bodies (absolute coordinates = x + origin); with
    !> them the fluid next to each surface is refined by the wall rule of the header, with a
    !> band of band_width new spacings (default WALL_BAND); band_width = 0 (same-level
    !> remeshing) moves nothing and drops the new row on the surface instead (d < dx/4).
    subroutine refine_positions(dim, n, x, ids, dx, n_new, x_new, key, stat, errmsg, box, &
            n_irregular, solids, origin, band_width, n_target)
        integer, intent(in) :: dim, n
        real(wp), intent(in) :: x(:, :), dx
        integer(i8), intent(in) :: ids(:)
        integer, intent(out) :: n_new
        real(wp), allocatable, intent(out) :: x_new(:, :)
        integer(i8), allocatable, intent(out) :: key(:, :)
        integer, intent(out), optional :: stat
        character(len=*), intent(out), optional :: errmsg
        real(wp), intent(in), optional :: box(3)
        integer, intent(out), optional :: n_irregular
        type(solids_t), intent(in), optional :: solids
        real(wp), intent(in), optional :: origin(3), band_width
        integer, intent(in), optional :: n_target
        real(wp), allocatable :: xa(:, :)
        integer(i8), allocatable :: ida(:)
        logical, allocatable :: keep(:), moved(:)
        integer, allocatable :: partner(:)
        integer :: combos(3, MAX_CORNER_COMBOS)
        real(wp) :: org(3), d, band, wb, y(3)
        integer(i8) :: span
        integer :: na, a, s, c, k, ns, st, n_codes, n_combos, n_mirror_edges
        integer, allocatable :: mirror_edges(:, :)
        logical :: pairs_on

        st = 0
        ns = 0
        if (present(solids)) then
            if (allocated(solids%list)) ns = size(solids%list)
        end if
        org = 0.0_wp
        if (present(origin)) org = origin
        wb = WALL_BAND
        if (present(band_width)) wb = band_width
        if (ns == 0) then
            call construct_positions(dim, n, x, ids, dx, n_new, x_new, key, st, errmsg, box, &
                n_irregular)
        else
            ! facing planes (a channel's walls): one surface row of each pair is dropped and
            ! the set shifted by a quarter of an old spacing (header, rule 2); not without a
            ! band (same-level remeshing drops the rows on all surfaces)
            band = wb * 0.5_wp * dx
            partner = [(facing_plane(solids, s), s = 1, ns)]
            pairs_on = band > 0.25_wp * dx .and. any(partner > 0)
            ! mirror codes: s (one surface), then pairs and triples of planes at right angles
            n_codes = ns + ns**2 + ns**3
            ! the set and its mirror images across every surface within MIRROR_DEPTH dx
            span = 1_i8
            if (n > 0) span = maxval(ids(1:n)) + 1_i8
            if (span - 1_i8 > largest_remesh_id(ns)) then
                n_new = 0
                allocate(x_new(3, 0), key(2, 0))
                st = 1
                if (present(errmsg)) write(errmsg, '(a,i0,a,i0,a,i0,a)') &
                    'refine_positions: the particles'' ids reach ', span - 1_i8, &
                    ', above the largest a remesh with ', ns, ' solids encodes (', &
                    largest_remesh_id(ns), ')'
                if (present(stat)) then
                    stat = st
                    return
                end if
                error stop 'refine_positions: ids too large for mirrors'
            end if
            allocate(xa(3, n * (ns + 1)), ida(n * (ns + 1)))
            xa(:, 1:n) = x(:, 1:n)
            ida(1:n) = ids(1:n)
            na = n
            allocate(mirror_edges(2, n))
            n_mirror_edges = 0
            do s = 1, ns
                do a = 1, n
                    d = solid_distance(solids%list(s), x(:, a) + org)
                    if (d < 0.0_wp .or. d >= MIRROR_DEPTH * dx) cycle
                    if (.not. solid_mirrors(solids%list(s), x(:, a) + org, &
                        MIRROR_LEVEL * dx, solids, s)) cycle
                    call add_mirror(solid_reflect(solids%list(s), x(:, a) + org), s, a)
                    if (2.0_wp * d < MIRROR_EDGE * dx) call add_mirror_edge(a, na)
                end do
            end do
            ! the corners of paired planes: mirrored across two (and in 3D three) of them at
            ! right angles too, so that the corner's cell gets its centre, which the kept
            ! surfaces' rows need (without it a closed box lacks the particle of one corner)
            if (pairs_on) then
                do a = 1, n
                    call corner_planes(solids, x(:, a) + org, MIRROR_DEPTH * dx, combos, &
                        n_combos, among=partner > 0)
                    do c = 1, n_combos
                        y = solid_reflect(solids%list(combos(2, c)), &
                            solid_reflect(solids%list(combos(1, c)), x(:, a) + org))
                        if (combos(3, c) == 0) then
                            call add_mirror(y, ns + (combos(1, c) - 1) * ns + combos(2, c), a)
                        else
                            call add_mirror(solid_reflect(solids%list(combos(3, c)), y), &
                                ns + ns**2 + ((combos(1, c) - 1) * ns + combos(2, c) - 1) * &
                                ns + combos(3, c), a)
                        end if
                    end do
                end do
            end if
            call construct_positions(dim, na, xa, ida, dx, n_new, x_new, key, st, errmsg, box, &
                n_irregular, mirror_edges(:, 1:n_mirror_edges))
            if (st == 0) then
                ! drop what lies inside a solid (and the dropped rows of paired planes), shift
                ! between paired planes, move the rest of the wall band (header)
                allocate(keep(n_new), moved(n_new))
                do k = 1, n_new
                    call wall_rule(x_new(:, k), keep(k), moved(k))
                end do
                n_new = count(keep)
                moved = pack(moved, keep)
                x_new = x_new(:, pack([(k, k = 1, size(keep))], keep))
                key = key(:, pack([(k, k = 1, size(keep))], keep))
            end if
        end if
        if (present(stat)) stat = st
        if (st /= 0) return
        if (present(box)) then
            do k = 1, n_new
                x_new(1:dim, k) = x_new(1:dim, k) &
                    - box(1:dim) * floor(x_new(1:dim, k) / box(1:dim))
            end do
        end if
        if (.not. allocated(moved)) then
            allocate(moved(n_new))
            moved = .false.
        end if
        call thin()
        ! within FILL_SLACK of the target the construction stands: its few missing centres
        ! (irregular cells next to a body of a lattice) are not worth the irregular points
        if (present(n_target)) then
            if (real(n_new, wp) < (1.0_wp - FILL_SLACK) * n_target) call fill_gaps(n_target)
        end if
        call in_key_order()

    contains

        !> The wall rule (header, rules 2 and 3) for the point z (relative to the origin): keep
        !> it or not, and where it goes; moved_z when it moves other than by the uniform shift
        !> between paired planes.
        subroutine wall_rule(z, keep_z, moved_z)
            real(wp), intent(inout) :: z(3)
            logical, intent(out) :: keep_z, moved_z
            real(wp) :: dist(ns), yz(3), d_1, d_2, b_1, sh(3), fz, ph, nb(3)
            integer :: sz, s_1, tz
            moved_z = .false.
            yz = z + org
            do sz = 1, ns
                dist(sz) = solid_distance(solids%list(sz), yz)
            end do
            ! the nearest solid (d_1, s_1; not a paired plane) and the next one (d_2)
            d_1 = huge(1.0_wp)
            s_1 = 0
            do sz = 1, ns
                if (pairs_on .and. partner(sz) > 0) cycle
                if (dist(sz) < d_1) then
                    d_1 = dist(sz)
                    s_1 = sz
                end if
            end do
            ! (a body's own next periodic image counts as a next solid: without it, in a box
            ! of 10-20 spacings the bands of a body and its image overlapped, each moved its
            ! points towards its own body, and a gap opened along the periodic faces, where
            ! the nearest image changes: 12,000 irregular cells refining a 3D lattice of 968
            ! around a sphere, CoV 0.20)
            d_2 = huge(1.0_wp)
            if (s_1 > 0) d_2 = next_image_distance(solids%list(s_1), yz)
            do sz = 1, ns
                if (sz /= s_1) d_2 = min(d_2, dist(sz))
            end do
            ! without a band (same-level remeshing) the row on the surface is dropped
            if (band > 0.25_wp * dx) then
                keep_z = d_1 > -0.25_wp * dx
            else
                keep_z = d_1 > 0.25_wp * dx
            end if
            ! each pair from its lower-numbered plane, whose row on the surface goes
            sh = 0.0_wp
            if (pairs_on) then
                do sz = 1, ns
                    tz = partner(sz)
                    if (tz < sz) cycle
                    if (dist(sz) < SURFACE_TOL * dx .or. dist(tz) <= -0.25_wp * dx) &
                        keep_z = .false.
                    fz = pair_map(dist(sz), dist(sz) + dist(tz), dx)
                    if (abs(fz - dist(sz) + 0.25_wp * dx) > SURFACE_TOL * dx) moved_z = .true.
                    sh = sh + (fz - dist(sz)) * solids%list(sz)%normal
                end do
            end if
            if (.not. keep_z) return
            ! band, up to half-way to the next solid (map continuous where they meet)
            b_1 = huge(1.0_wp)
            if (s_1 > 0) b_1 = min(band, 0.5_wp * (max(d_1, 0.0_wp) + d_2))
            ! within a body's band the shift's part along the body's normal fades out towards
            ! its surface, where the band map below puts the surface row (a body in a channel)
            if (any(sh /= 0.0_wp)) then
                if (s_1 > 0 .and. d_1 < b_1) then
                    nb = solid_normal(solids%list(s_1), yz)
                    ph = max(d_1, 0.0_wp) / b_1
                    sh = sh - (1.0_wp - ph) * dot_product(sh, nb) * nb
                    moved_z = .true.
                end if
                z = z + sh
                z(dim + 1:) = 0.0_wp
            end if
            if (s_1 == 0) return
            ! (a band of exactly dx / 4, half-way to a solid half an old spacing away, maps
            ! the surface row to the half-way point: the slot under a body level with a row)
            if (d_1 < b_1 .and. b_1 > (0.25_wp - SURFACE_TOL) * dx) then
                z = z + (wall_map(max(d_1, 0.0_wp), dx, b_1) - d_1) &
                    * solid_normal(solids%list(s_1), yz)
                z(dim + 1:) = 0.0_wp
                moved_z = .true.
            end if
        end subroutine wall_rule

        !> Append the mirror image y (absolute) of particle a with mirror code c to xa / ida
        !> (grown when full).
        subroutine add_mirror(y_abs, c, a_orig)
            real(wp), intent(in) :: y_abs(3)
            integer, intent(in) :: c, a_orig
            real(wp), allocatable :: xa_more(:, :)
            integer(i8), allocatable :: ida_more(:)
            if (na == size(ida)) then
                allocate(xa_more(3, 2 * na), ida_more(2 * na))
                xa_more(:, 1:na) = xa(:, 1:na)
                ida_more(1:na) = ida(1:na)
                call move_alloc(xa_more, xa)
                call move_alloc(ida_more, ida)
            end if
            na = na + 1
            xa(:, na) = y_abs - org
            xa(dim + 1:, na) = 0.0_wp
            ida(na) = int(c, i8) * span + ids(a_orig)
        end subroutine add_mirror

        !> Particle a and its mirror xa(:, k) form an edge (MIRROR_EDGE).
        subroutine add_mirror_edge(a_orig, k)
            integer, intent(in) :: a_orig, k
            integer, allocatable :: more(:, :)
            if (n_mirror_edges == size(mirror_edges, 2)) then
                allocate(more(2, 2 * n_mirror_edges + 1))
                more(:, 1:n_mirror_edges) = mirror_edges(:, 1:n_mirror_edges)
                call move_alloc(more, mirror_edges)
            end if
            n_mirror_edges = n_mirror_edges + 1
            mirror_edges(:, n_mirror_edges) = [a_orig, k]
        end subroutine add_mirror_edge

        !> The points in key order: the caller's fresh ids follow the keys (sph_global_ids),
        !> so its sorts of the keys and then of the ids find them in order (one pass each
        !> instead of a full sort of 4 N keys, twice).
        subroutine in_key_order()
            integer, allocatable :: order(:)
            integer :: i
            if (n_new < 2) return
            order = [(i, i = 1, n_new)]
            call sort_by_keys(key(:, 1:n_new), order)
            x_new = x_new(:, order)
            key = key(:, order)
        end subroutine in_key_order

        !> Gap filling (header, rule 5): midpoints (then, if needed, quarter points) of the
        !> old pairs EDGE_FACTOR dx to FILL_PAIR_MAX dx apart, in key order, each kept when no
        !> point lies within FILL_GAP dx/2; down to want by the hash of their keys.
        subroutine fill_gaps(want)
            integer, intent(in) :: want
            real(wp), allocatable :: xo(:, :), yc(:, :)
            integer(i8), allocatable :: kc(:, :), hk(:, :)
            integer, allocatable :: oo(:), order(:), idx(:), ord(:)
            logical, allocatable :: take(:), best(:), allowed(:)
            type(neighbour_list_t) :: nl
            type(point_cells_t) :: pc
            logical :: periodic, taken, mv
            real(wp) :: bx(3), r2, r_fill, dd(3), lo(3), hi(3)
            integer :: no, nc, i, j, t, n_best, s, f, n_took
            periodic = present(box)
            bx = 0.0_wp
            if (periodic) bx = box
            ! candidates: midpoints of the old pairs in [EDGE_FACTOR, FILL_PAIR_MAX) dx
            call with_periodic_images(dim, n, x, periodic, bx, FILL_PAIR_MAX * dx, xo, oo, no)
            call build_neighbour_list(xo, no, n, dim, FILL_PAIR_MAX * dx, nl, reach=2)
            allocate(yc(3, max(3 * nl%n_pairs, 1)), kc(2, max(3 * nl%n_pairs, 1)))
            nc = 0
            do i = 1, n
                do t = nl%start(i), nl%start(i + 1) - 1
                    j = oo(nl%index(t))
                    if (ids(j) <= ids(i)) cycle
                    dd = xo(:, nl%index(t)) - x(:, i)
                    dd(dim + 1:) = 0.0_wp
                    r2 = sum(dd * dd)
                    if (r2 < (EDGE_FACTOR * dx)**2) cycle
                    ! the midpoint, then the quarter points (a gap of 1.2-2 dx holds up to
                    ! three new spacings); edge keys, the pair being no edge (too far
                    ! apart), with the quarter points told apart in key(2)'s top bits
                    do f = 0, 2
                        nc = nc + 1
                        yc(:, nc) = x(:, i) + FILL_FRACTION(f) * dd
                        if (periodic) yc(1:dim, nc) = yc(1:dim, nc) &
                            - bx(1:dim) * floor(yc(1:dim, nc) / bx(1:dim))
                        kc(:, nc) = [4_i8 * ids(i) + 1_i8, ids(j) + int(f, i8) * 2_i8**61]
                    end do
                end do
            end do
            if (nc == 0) return
            ! not inside or on a solid (the wall rule's row on the surface is its own)
            allocate(take(nc))
            take = .true.
            if (ns > 0) then
                do i = 1, nc
                    do s = 1, ns
                        if (solid_distance(solids%list(s), yc(:, i) + org) < 0.25_wp * dx) &
                            take(i) = .false.
                    end do
                end do
            end if
            ! and where the wall rule puts the constructed points (the shift between paired
            ! planes: a candidate left where it was would sit between the shifted points)
            if (ns > 0) then
                do i = 1, nc
                    if (.not. take(i)) cycle
                    call wall_rule(yc(:, i), taken, mv)
                    take(i) = taken
                    if (periodic) yc(1:dim, i) = yc(1:dim, i) &
                        - bx(1:dim) * floor(yc(1:dim, i) / bx(1:dim))
                end do
            end if
            ! nor within r_fill of a refined point: such a candidate is never taken, and so
            ! never keeps another out, and the greedy pass takes the same ones from the rest
            ! alone (on a disordered set 60 % of the 10 or so a particle). The refined
            ! points and the candidates taken are looked up in cells as they come
            ! (point_cells_t), not through a neighbour list of every candidate and refined
            ! point with their images, which was most of the refinement's time there.
            r_fill = FILL_GAP * 0.5_wp * dx
            ! (the cells' extent without a box: every refined point and candidate)
            lo = min(minval(x_new(:, 1:n_new), dim=2), minval(yc(:, 1:nc), dim=2))
            hi = max(maxval(x_new(:, 1:n_new), dim=2), maxval(yc(:, 1:nc), dim=2))
            call cells_init(pc, dim, periodic, bx, lo, hi, 0.5_wp * dx, n_new)
            do i = 1, n_new
                call cells_add(pc, i, x_new(:, i))
            end do
            do i = 1, nc
                if (take(i)) take(i) = .not. any_within(pc, x_new, yc(:, i), r_fill)
            end do
            yc = yc(:, pack([(i, i = 1, nc)], take))
            kc = kc(:, pack([(i, i = 1, nc)], take))
            nc = size(kc, 2)
            if (nc == 0) return
            ! key order (a pair can appear twice through images of a small box: once kept)
            allocate(order(nc))
            order = [(i, i = 1, nc)]
            call sort_by_keys(kc, order)
            yc = yc(:, order)
            kc = kc(:, order)
            ! the midpoints alone when they reach want (they keep more of the flow's own
            ! spacing), with the quarter points otherwise
            allocate(allowed(nc))
            allowed = kc(2, 1:nc) < 2_i8**61
            call fill_greedy(dim, periodic, bx, lo, hi, 0.5_wp * dx, r_fill, yc, allowed, best, &
                n_took)
            if (n_new + n_took < want) then
                allowed = .true.
                call fill_greedy(dim, periodic, bx, lo, hi, 0.5_wp * dx, r_fill, yc, allowed, &
                    best, n_took)
            end if
            n_best = n_new + n_took
            ! keep want, chosen by a hash of the keys so that no region is preferred
            if (n_best > want) then
                idx = pack([(i, i = 1, nc)], best)
                allocate(hk(2, size(idx)), ord(size(idx)))
                do i = 1, size(idx)
                    hk(:, i) = [id_hash(ieor(kc(1, idx(i)), id_hash(kc(2, idx(i))))), &
                        int(idx(i), i8)]
                    ord(i) = i
                end do
                call sort_by_keys(hk, ord)
                best(idx(ord(want - n_new + 1:))) = .false.
            end if
            n_best = n_new + count(best)
            x_new = reshape([x_new(:, 1:n_new), pack(yc(:, 1:nc), spread(best, 1, 3))], &
                [3, n_best])
            key = reshape([key(:, 1:n_new), pack(kc(:, 1:nc), spread(best, 1, 2))], [2, n_best])
            n_new = n_best

        end subroutine fill_gaps

        !> Thinning (header, rule 4): a point is dropped when a point kept before it lies
        !> within MIN_GAP dx/2. Old positions that were not moved come first, among themselves
        !> in key order (they are closer than that only where the old set has clumped: two
        !> particles 0.016 dx apart in Morris' cylinder at L/50, 6000 s); the constructed
        !> (midpoint, centre) and moved points follow in key order. Each is kept or dropped
        !> after every earlier one within reach is decided (rounds of the sequential greedy
        !> rule: the result is that of one pass in that order, whatever the storage order).
        subroutine thin()
            real(wp), allocatable :: xi(:, :)
            integer, allocatable :: orig(:), state(:)
            type(neighbour_list_t) :: nl
            logical :: periodic, decided, lose
            logical, allocatable :: cand(:)
            real(wp) :: bx(3), rmin
            integer :: ntot, i, j, t
            integer, parameter :: undecided = 0, kept = 1, dropped = 2
            if (n_new == 0) return
            allocate(cand(n_new), state(n_new))
            do i = 1, n_new
                cand(i) = moved(i) .or. iand(key(1, i), 3_i8) /= 0_i8
            end do
            rmin = MIN_GAP * 0.5_wp * dx
            periodic = present(box)
            bx = 0.0_wp
            if (periodic) bx = box
            call with_periodic_images(dim, n_new, x_new, periodic, bx, rmin, xi, orig, ntot)
            ! cells of a new spacing (about a point each): cells of the radius would hold a
            ! tenth of one, and counting them took most of the thinning's time
            call build_neighbour_list(xi, ntot, n_new, dim, rmin, nl, cell_size=0.5_wp * dx)
            state = undecided
            do while (any(state == undecided))
                do i = 1, n_new
                    if (state(i) /= undecided) cycle
                    decided = .true.
                    lose = .false.
                    do t = nl%start(i), nl%start(i + 1) - 1
                        j = orig(nl%index(t))
                        if (j == i) cycle
                        ! j counts only when it comes before i: an old unmoved point before
                        ! every other, then key order within each class
                        if (cand(j) .eqv. cand(i)) then
                            if (.not. key_before(key(:, j), key(:, i))) cycle
                        else if (cand(j)) then
                            cycle
                        end if
                        if (state(j) == kept) then
                            lose = .true.
                            exit
                        end if
                        if (state(j) == undecided) decided = .false.
                    end do
                    if (lose) then
                        state(i) = dropped
                    else if (decided) then
                        state(i) = kept
                    end if
                end do
            end do
            if (all(state == kept)) return
            x_new = x_new(:, pack([(i, i = 1, n_new)], state == kept))
            key = key(:, pack([(i, i = 1, n_new)], state == kept))
            n_new = count(state == kept)
        end subroutine thin

        pure logical function key_before(ka, kb)
            integer(i8), intent(in) :: ka(2), kb(2)
            key_before = ka(1) < kb(1) .or. (ka(1) == kb(1) .and. ka(2) < kb(2))
        end function key_before
    end subroutine refine_positions

    !> The gap filling's greedy pass (refine_positions, fill_gaps) over candidates y(:, 1:m)
    !> that no refined point covers: in order, an allowed one is taken when no candidate
    !> taken before lies within r (periodic images included); cells as cells_init.
    subroutine fill_greedy(dim, periodic, box, lo, hi, cell_size, r, y, allowed, took, &
            n_took)
        integer, intent(in) :: dim
        logical, intent(in) :: periodic
        real(wp), intent(in) :: box(3), lo(3), hi(3), cell_size, r, y(:, :)
        logical, intent(in) :: allowed(:)
        logical, allocatable, intent(inout) :: took(:)
        integer, intent(out) :: n_took
        type(point_cells_t) :: taken
        integer :: c
        if (allocated(took)) deallocate(took)
        allocate(took(size(allowed)))
        took = .false.
        call cells_init(taken, dim, periodic, box, lo, hi, cell_size, size(allowed))
        do c = 1, size(allowed)
            if (.not. allowed(c)) cycle
            if (any_within(taken, y, y(:, c), r)) cycle
            took(c) = .true.
            call cells_add(taken, c, y(:, c))
        end do
        n_took = count(took)
    end subroutine fill_greedy

    !> Start empty cells of at least cell_size: over [0, box) when periodic (the cells
    !> wrap), else over [lo, hi] (a point outside goes to the nearest cell); room for points
    !> 1..n_points.
    subroutine cells_init(pc, dim, periodic, box, lo, hi, cell_size, n_points)
        type(point_cells_t), intent(out) :: pc
        integer, intent(in) :: dim, n_points
        logical, intent(in) :: periodic
        real(wp), intent(in) :: box(3), lo(3), hi(3), cell_size
        integer :: a
        pc%dim = dim
        pc%periodic = periodic
        pc%box = box
        pc%nc = 1
        pc%lo = 0.0_wp
        pc%inv = 0.0_wp
        do a = 1, dim
            if (periodic) then
                pc%nc(a) = max(1, int(box(a) / cell_size))
                pc%inv(a) = pc%nc(a) / box(a)
            else
                pc%lo(a) = lo(a)
                pc%nc(a) = max(1, int((hi(a) - lo(a)) / cell_size))
                pc%inv(a) = pc%nc(a) / max(hi(a) - lo(a), tiny(1.0_wp))
            end if
        end do
        allocate(pc%head(product(pc%nc)), pc%next(max(n_points, 1)))
        pc%head = 0
    end subroutine cells_init

    !> The cell of y, 0-based per axis.
    pure function cell_of(pc, y) result(c)
        type(point_cells_t), intent(in) :: pc
        real(wp), intent(in) :: y(3)
        integer :: c(3), a
        c = 0
        do a = 1, pc%dim
            c(a) = min(max(int((y(a) - pc%lo(a)) * pc%inv(a)), 0), pc%nc(a) - 1)
        end do
    end function cell_of

    !> Point k (at y) into its cell.
    subroutine cells_add(pc, k, y)
        type(point_cells_t), intent(inout) :: pc
        integer, intent(in) :: k
        real(wp), intent(in) :: y(3)
        integer :: c(3), cell
        c = cell_of(pc, y)
        cell = 1 + c(1) + pc%nc(1) * (c(2) + pc%nc(2) * c(3))
        pc%next(k) = pc%head(cell)
        pc%head(cell) = k
    end subroutine cells_add

    !> The cells within one of y's (each once; 3^dim of them away from the cells' edges)
    !> with the shift s of the images they hold there: the image of a point x is x + s box,
    !> s in {-1, 0, 1} per axis, as with_periodic_images makes it.
    subroutine cells_around(pc, y, cells, shifts, n_cells)
        type(point_cells_t), intent(in) :: pc
        real(wp), intent(in) :: y(3)
        integer, intent(out) :: cells(27), shifts(3, 27), n_cells
        integer :: c(3), k(3), s(3), a, ox, oy, oz, oz_max
        logical :: inside
        n_cells = 0
        c = cell_of(pc, y)
        oz_max = merge(1, 0, pc%dim == 3)
        do oz = -oz_max, oz_max
            do oy = -1, 1
                do ox = -1, 1
                    k = c + [ox, oy, oz]
                    s = 0
                    inside = .true.
                    do a = 1, pc%dim
                        if (k(a) < 0) then
                            k(a) = k(a) + pc%nc(a)
                            s(a) = -1
                        else if (k(a) >= pc%nc(a)) then
                            k(a) = k(a) - pc%nc(a)
                            s(a) = 1
                        end if
                        if (s(a) /= 0 .and. .not. pc%periodic) inside = .false.
                    end do
                    if (.not. inside) cycle
                    n_cells = n_cells + 1
                    cells(n_cells) = 1 + k(1) + pc%nc(1) * (k(2) + pc%nc(2) * k(3))
                    shifts(:, n_cells) = s
                end do
            end do
        end do
    end subroutine cells_around

    !> Does a point added to the cells (positions xs) or a periodic image of one lie within
    !> r of y (r at most a cell)? The offset is image - y, term for term as the neighbour
    !> lists' images give it.
    logical function any_within(pc, xs, y, r) result(found)
        type(point_cells_t), intent(in) :: pc
        real(wp), intent(in) :: xs(:, :), y(3), r
        integer :: cells(27), shifts(3, 27), n_cells, q, t, c(3), oy, base
        real(wp) :: dd(3)
        found = .false.
        c = cell_of(pc, y)
        if (pc%dim == 2 .and. all(c(1:2) >= 1 .and. c(1:2) <= pc%nc(1:2) - 2)) then
            ! away from the cells' edges (most queries): the nine cells, no image. (The
            ! general loop below with zero shifts gives the same; written out, the gap
            ! filling of a disordered set ran 12 % faster.)
            do oy = -1, 1
                base = 1 + c(1) + pc%nc(1) * (c(2) + oy)
                do q = base - 1, base + 1
                    t = pc%head(q)
                    do while (t > 0)
                        dd(1:2) = xs(1:2, t) - y(1:2)
                        dd(3) = 0.0_wp
                        if (sum(dd * dd) < r * r) then
                            found = .true.
                            return
                        end if
                        t = pc%next(t)
                    end do
                end do
            end do
            return
        end if
        call cells_around(pc, y, cells, shifts, n_cells)
        do q = 1, n_cells
            t = pc%head(cells(q))
            do while (t > 0)
                dd = (xs(:, t) + real(shifts(:, q), wp) * pc%box) - y
                dd(pc%dim + 1:) = 0.0_wp
                if (sum(dd * dd) < r * r) then
                    found = .true.
                    return
                end if
                t = pc%next(t)
            end do
        end do
    end function any_within

    !> Wall distance after the wall rule: d in [0, band) -> dx/4 + d (band - dx/4) / band
    !> (dx the OLD spacing: the first new layer at half a new spacing), identity beyond.
    pure real(wp) function wall_map(d, dx, band) result(g)
        real(wp), intent(in) :: d, dx, band
        if (d >= band) then
            g = d
        else
            g = 0.25_wp * dx + d * (band - 0.25_wp * dx) / band
        end if
    end function wall_map

    !> Between two paired planes (header, rule 2): the new distance from the plane whose
    !> surface row is dropped, for a point at distance xi from it and width - xi from the
    !> other: xi - dx/4 for dx/2 <= xi <= width (the lattice's rows: a uniform shift), and,
    !> continuous and increasing, dx/8 + xi/4 closer to that plane (from the flow's disorder
    !> only) and width - dx/4 + (xi - width)/2 behind the other (down to dx/8 from it).
    pure real(wp) function pair_map(xi, width, dx) result(f)
        real(wp), intent(in) :: xi, width, dx
        if (xi < 0.5_wp * dx) then
            f = 0.125_wp * dx + 0.25_wp * xi
        else if (xi <= width) then
            f = xi - 0.25_wp * dx
        else
            f = width - 0.25_wp * dx + 0.5_wp * (xi - width)
        end if
    end function pair_map

    subroutine construct_positions(dim, n, x, ids, dx, n_new, x_new, key, stat, errmsg, box, &
            n_irregular, extra_edges)
        integer, intent(in) :: dim, n
        real(wp), intent(in) :: x(:, :), dx
        integer(i8), intent(in) :: ids(:)
        integer, intent(out) :: n_new
        real(wp), allocatable, intent(out) :: x_new(:, :)
        integer(i8), allocatable, intent(out) :: key(:, :)
        integer, intent(out), optional :: stat
        character(len=*), intent(out), optional :: errmsg
        real(wp), intent(in), optional :: box(3)
        integer, intent(out), optional :: n_irregular
        !> pairs (indices into x) that are edges whatever their distance (besides those closer
        !> than EDGE_FACTOR dx): a particle and its mirror (refine_positions)
        integer, intent(in), optional :: extra_edges(:, :)
        real(wp) :: rc, bx(3)
        logical :: periodic
        integer, allocatable :: astart(:), adj(:), npart(:), part(:, :)
        integer :: a, b, c, g, p, q, k, nc, cm(8), irregular, capacity, ncand, nb, ncorner
        integer :: cand(256), cnt(256), cs(3), corner(8)
        logical :: bad

        if (present(stat)) stat = 0
        periodic = present(box)
        bx = 0.0_wp
        if (periodic) bx = box
        rc = EDGE_FACTOR * dx
        if (periodic) then
            if (any(bx(1:dim) <= 4.0_wp * rc)) then
                call fail('refine_positions: periodic box shorter than 4 edge lengths')
                return
            end if
        end if
        if (any(ids(1:n) < 0_i8) .or. any(ids(1:n) >= 2_i8**61)) then
            call fail('refine_positions: ids must lie in [0, 2^61)')
            return
        end if
        call adjacency()

        ! face partners (diagonal pairs with exactly two non-adjacent common neighbours)
        allocate(npart(n), part(max_partners, n))
        npart = 0
        irregular = 0
        capacity = n * (1 + dim + dim * (dim - 1) / 2 + merge(1, 0, dim == 3))
        capacity = capacity + capacity / 4 + 16
        allocate(x_new(3, capacity), key(2, capacity))
        x_new = 0.0_wp
        n_new = 0
        do a = 1, n
            call emit(key_of(0, ids(a), ids(a)), x(:, a))
        end do
        do a = 1, n
            do p = astart(a), astart(a + 1) - 1
                b = adj(p)
                if (ids(b) < ids(a)) cycle
                call emit(key_of(1, ids(a), ids(b)), x(:, a) + 0.5_wp * disp(a, b))
            end do
        end do
        do a = 1, n
            call distance_two(a)
            do k = 1, ncand
                c = cand(k)
                if (ids(c) < ids(a)) cycle
                call common(a, c, cm, nc)
                if (nc < 2) cycle
                if (nc > 2 .or. adjacent(cm(1), cm(2))) then
                    irregular = irregular + 1
                    cycle
                end if
                if (npart(a) >= max_partners .or. npart(c) >= max_partners) then
                    irregular = irregular + 1
                    cycle
                end if
                npart(a) = npart(a) + 1; part(npart(a), a) = c
                npart(c) = npart(c) + 1; part(npart(c), c) = a
                ! each face has two diagonals: the one through its lowest id emits it
                corner(1:4) = [a, c, cm(1), cm(2)]
                if (min(ids(a), ids(c)) < min(ids(cm(1)), ids(cm(2)))) &
                    call emit_centre(2, corner(1:4), a, c)
            end do
        end do
        if (dim == 3) then
            do a = 1, n
                ! candidates g: neighbours of face partners of a, counted
                ncand = 0
                do q = 1, npart(a)
                    c = part(q, a)
                    do p = astart(c), astart(c + 1) - 1
                        g = adj(p)
                        if (g == a) cycle
                        call add_count(g)
                    end do
                end do
                do k = 1, ncand
                    g = cand(k)
                    if (cnt(k) /= 3 .or. ids(g) < ids(a)) cycle
                    if (adjacent(a, g) .or. any(part(1:npart(a), a) == g)) cycle
                    nb = 0
                    do q = 1, npart(a)
                        if (adjacent(part(q, a), g)) then
                            nb = nb + 1
                            cs(nb) = part(q, a)
                        end if
                    end do
                    corner(1:2) = [a, g]
                    corner(3:5) = cs
                    ncorner = 5
                    bad = .false.
                    do q = 1, 3
                        call common(a, cs(q), cm, nc)
                        if (nc /= 2) bad = .true.
                        do p = 1, min(nc, 8)
                            if (any(corner(1:ncorner) == cm(p))) cycle
                            if (ncorner == 8) then
                                bad = .true.
                            else
                                ncorner = ncorner + 1
                                corner(ncorner) = cm(p)
                            end if
                        end do
                    end do
                    if (bad .or. ncorner /= 8) then
                        irregular = irregular + 1
                        cycle
                    end if
                    ! each cube has four body diagonals: the one through its lowest id emits it
                    if (min(ids(a), ids(g)) == minval(ids(corner))) &
                        call emit_centre(3, corner, a, g)
                end do
            end do
        end if
        x_new = x_new(:, 1:n_new)
        key = key(:, 1:n_new)
        if (present(n_irregular)) n_irregular = irregular

    contains

        !> Neighbour pairs closer than rc among the originals (through images if periodic).
        subroutine adjacency()
            real(wp), allocatable :: xa(:, :)
            integer, allocatable :: orig(:)
            type(neighbour_list_t) :: nl
            integer :: i, m, t, ntot, j
            integer, allocatable :: estart(:), eother(:)
            integer :: ne, e
            call with_periodic_images(dim, n, x, periodic, bx, rc, xa, orig, ntot)
            call build_neighbour_list(xa, ntot, n, dim, rc, nl, reach=2)
            ! the extra edges of each point, both ways (CSR)
            ne = 0
            if (present(extra_edges)) ne = size(extra_edges, 2)
            allocate(estart(n + 2), eother(2 * ne))
            estart = 0
            do e = 1, ne
                estart(extra_edges(1, e) + 2) = estart(extra_edges(1, e) + 2) + 1
                estart(extra_edges(2, e) + 2) = estart(extra_edges(2, e) + 2) + 1
            end do
            estart(1) = 1
            estart(2) = 1
            do i = 3, n + 2
                estart(i) = estart(i) + estart(i - 1)
            end do
            do e = 1, ne
                eother(estart(extra_edges(1, e) + 1)) = extra_edges(2, e)
                estart(extra_edges(1, e) + 1) = estart(extra_edges(1, e) + 1) + 1
                eother(estart(extra_edges(2, e) + 1)) = extra_edges(1, e)
                estart(extra_edges(2, e) + 1) = estart(extra_edges(2, e) + 1) + 1
            end do
            ! (estart(i) now starts the edges of i)
            allocate(astart(n + 1), adj(nl%n_pairs + 2 * ne))
            m = 0
            do i = 1, n
                astart(i) = m + 1
                do t = nl%start(i), nl%start(i + 1) - 1
                    j = orig(nl%index(t))
                    if (j == i .or. any(adj(astart(i):m) == j)) cycle
                    m = m + 1
                    adj(m) = j
                end do
                do t = estart(i), estart(i + 1) - 1
                    j = eother(t)
                    if (j == i .or. any(adj(astart(i):m) == j)) cycle
                    m = m + 1
                    adj(m) = j
                end do
            end do
            astart(n + 1) = m + 1
        end subroutine adjacency

        logical function adjacent(i, j)
            integer, intent(in) :: i, j
            adjacent = any(adj(astart(i):astart(i + 1) - 1) == j)
        end function adjacent

        !> Common neighbours of i and j (at most 8 kept, count returned in full).
        subroutine common(i, j, out, nout)
            integer, intent(in) :: i, j
            integer, intent(out) :: out(8), nout
            integer :: t
            nout = 0
            out = 0
            do t = astart(i), astart(i + 1) - 1
                if (adjacent(j, adj(t))) then
                    nout = nout + 1
                    if (nout <= 8) out(nout) = adj(t)
                end if
            end do
        end subroutine common

        !> cand(1:ncand): particles at graph distance exactly 2 from i.
        subroutine distance_two(i)
            integer, intent(in) :: i
            integer :: t, u, j
            ncand = 0
            do t = astart(i), astart(i + 1) - 1
                do u = astart(adj(t)), astart(adj(t) + 1) - 1
                    j = adj(u)
                    if (j == i .or. adjacent(i, j)) cycle
                    if (any(cand(1:ncand) == j)) cycle
                    if (ncand < size(cand)) then
                        ncand = ncand + 1
                        cand(ncand) = j
                    end if
                end do
            end do
        end subroutine distance_two

        subroutine add_count(j)
            integer, intent(in) :: j
            integer :: t
            do t = 1, ncand
                if (cand(t) == j) then
                    cnt(t) = cnt(t) + 1
                    return
                end if
            end do
            if (ncand < size(cand)) then
                ncand = ncand + 1
                cand(ncand) = j
                cnt(ncand) = 1
            end if
        end subroutine add_count

        !> Minimum-image displacement x_j - x_i.
        function disp(i, j) result(d)
            integer, intent(in) :: i, j
            real(wp) :: d(3)
            d = x(:, j) - x(:, i)
            d(dim + 1:) = 0.0_wp
            if (periodic) d(1:dim) = d(1:dim) - bx(1:dim) * anint(d(1:dim) / bx(1:dim))
        end function disp

        !> Centre of the corners cn, summed in id order from the lowest-id corner; key from the
        !> diagonal (d1, d2) through the lowest id.
        subroutine emit_centre(kind, cn, d1, d2)
            integer, intent(in) :: kind, cn(:), d1, d2
            integer :: order(size(cn)), t, lo
            real(wp) :: sumd(3)
            order = sort_by_id(cn)
            lo = order(1)
            sumd = 0.0_wp
            do t = 2, size(cn)
                sumd = sumd + disp(lo, order(t))
            end do
            call emit(key_of(kind, ids(d1), ids(d2)), x(:, lo) + sumd / real(size(cn), wp))
        end subroutine emit_centre

        function sort_by_id(cn) result(o)
            integer, intent(in) :: cn(:)
            integer :: o(size(cn)), t, u, tmp
            o = cn
            do t = 2, size(o)
                tmp = o(t)
                u = t - 1
                do while (u >= 1)
                    if (ids(o(u)) <= ids(tmp)) exit
                    o(u + 1) = o(u)
                    u = u - 1
                end do
                o(u + 1) = tmp
            end do
        end function sort_by_id

        pure function key_of(kind, lo, hi) result(kk)
            integer, intent(in) :: kind
            integer(i8), intent(in) :: lo, hi
            integer(i8) :: kk(2)
            kk(1) = 4_i8 * min(lo, hi) + int(kind, i8)
            kk(2) = max(lo, hi)
        end function key_of

        subroutine emit(kk, y)
            integer(i8), intent(in) :: kk(2)
            real(wp), intent(in) :: y(3)
            real(wp), allocatable :: xt(:, :)
            integer(i8), allocatable :: kt(:, :)
            if (n_new == size(key, 2)) then
                allocate(xt(3, 2 * n_new), kt(2, 2 * n_new))
                xt = 0.0_wp; kt = 0_i8
                xt(:, 1:n_new) = x_new; kt(:, 1:n_new) = key
                call move_alloc(xt, x_new)
                call move_alloc(kt, key)
            end if
            n_new = n_new + 1
            key(:, n_new) = kk
            x_new(:, n_new) = y
            x_new(dim + 1:, n_new) = 0.0_wp
        end subroutine emit

        subroutine fail(msg)
            character(len=*), intent(in) :: msg
            n_new = 0
            allocate(x_new(3, 0), key(2, 0))
            if (present(errmsg)) errmsg = msg
            if (present(stat)) then
                stat = 1
                return
            end if
            error stop 'refine_positions: invalid input'
        end subroutine fail
    end subroutine construct_positions

    !> The largest particle id a remesh can encode with n_solids solids: the construction
    !> keys a point by the ids of its sources and of their mirror images across up to three
    !> surfaces (n_solids + n_solids^2 + n_solids^3 codes), in 61 bits.
    pure integer(i8) function largest_remesh_id(n_solids) result(largest)
        integer, intent(in) :: n_solids
        integer(i8) :: n_codes
        n_codes = int(n_solids, i8) + int(n_solids, i8)**2 + int(n_solids, i8)**3
        largest = 2_i8**61 / (n_codes + 1_i8) - 1_i8
    end function largest_remesh_id
end module sph_refine
