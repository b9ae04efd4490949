!> The new positions of a full-domain remesh (thesis sec. 3.2, issue 10), serial: the rules
!> that sph_refine's construction and sph_coarsen's selection leave to their caller, for the
!> set of every fluid position that sph_remesh_driver gathers on rank 0 (its header says why
!> on one rank). No MPI here. A remesh goes through
!>  1. new_set_init (the gathered positions and ids in set%x, set%ids, set%n);
!>  2. set_aside_gaps (same level): the particles of narrow gaps moved to the end;
!>  3. new_positions: refine (construction, wall rule, relaxation of a clumped set; set%idn
!>     then holds the refinement keys, two per point), coarsen (the whole selection, set%idn
!>     the kept ids) or the same level's construction;
!>  4. finish_same_level, once the caller has turned the keys into ids: the selection back
!>     to the count, the gaps' particles joined, the relaxation.
!> Positions are relative to box_lo throughout.
!>
!> Coarsening: the candidates closer than WALL_GAP new spacings to a body are dropped (the
!> fine first row lies 0.25 new spacings off: kept, it let a particle into Morris' cylinder
!> within 900 s of the coarse run), the kept set follows the flow's spacing (sph_coarsen's
!> follow_spacing), next to plane walls it is moved so that its first row lies half a new
!> spacing off each (place_plane_rows: every other fine row lies a quarter of a new spacing
!> off that, so the first coarse row lay 0.25 or 0.75 new spacings off a wall, and with the
!> 0.25 row dropped one wall had a gap of 1.25 spacings; the coarsened Poiseuille channel
!> continued at 2.52 times the error of the run made coarse throughout, now 0.81 times), and
!> the set is relaxed as the same-level one is (below): the transfer
!> gives each particle the mass of its volume, and the kept set's uneven volumes (masses
!> 17-23 % apart, up to 2.3 times the mean) cost the coarse cylinder flow 4-11 % of its mean
!> velocity; relaxed, 5-8 % apart and within 0.4 % of the coarse run's (doc/validation.md).
!> Not when the selection found no disordered particle (sph_coarsen) and there is no body:
!> the kept set of a near-lattice is its sublattice (of a channel, placed by
!> place_plane_rows), whose volumes are even; the relaxation moved it by less than 1 % of a
!> spacing, and its one pass was a tenth of the coarsening of 10^5 particles (the L/40
!> channel's coarse set is now the lattice exactly: mean ratio 2, CoV 0 against 1.994 and
!> 0.003; continued, 0.403 % against 0.405 %).
!>
!> Same level = refine, then coarsen the refined set (not following the flow's spacing: it is
!> there to give a clumped flow a fresh set), first rows WALL_GAP off each solid, relaxed.
module sph_remesh_positions
    use sph_kinds, only: wp, i8
    use sph_refine, only: refine_positions, WALL_BAND
    use sph_solids, only: solids_t, solid_distance, solid_normal, facing_plane, SOLID_PLANE
    use sph_cell_list, only: neighbour_list_t, build_neighbour_list
    use sph_remesh_images, only: with_images, with_mirrors_and_images
    use sph_remesh_relax, only: relax_displacements, relax_list_t, RELAX_PASSES, RELAX_H_FACTOR, &
        RELAX_TOLERANCE
    use sph_coarsen, only: coarsen_select
    use sph_key_sort, only: id_order   ! the stable id sort (serial)
    implicit none
    private
    public :: new_set_t, new_set_init, set_aside_gaps, new_positions, finish_same_level
    public :: into_id_order, snapped_to_grid, SNAP_FRACTION
    public :: REMESH_NONE, REMESH_REFINE, REMESH_COARSEN, REMESH_SAME, NARROW_GAP

    integer, parameter :: REMESH_NONE = 0
    integer, parameter :: REMESH_REFINE = 1
    integer, parameter :: REMESH_COARSEN = 2
    integer, parameter :: REMESH_SAME = 3

    !> same-level remeshing and coarsening keep no new particle closer than this (in new
    !> spacings) to a solid
    real(wp), parameter :: WALL_GAP = 0.4_wp
    !> the relaxation squeezes no pair below this (in new spacings): issue 10's floor
    real(wp), parameter :: RELAX_FLOOR = 0.4_wp
    !> the grid (in old spacings) that snapped_to_grid puts the old positions on: 2^-20
    real(wp), parameter :: SNAP_FRACTION = 1.0_wp / 1048576.0_wp
    !> a refined or coarsened set's relaxation moves two particles that are each other's
    !> nearest, closer than this (in new spacings), together: a clumped flow's pairs stay
    !> pairs, and the set keeps the flow's nearest distances (issue 10). Relaxed one by one,
    !> the L/25 cylinder flow at 1500 s refined to a mean nearest distance 0.532 of the flow's
    !> (0.495 with pairs kept), and the developed cylinder flows coarsened to nearest-distance
    !> CoVs 0.73-0.80 of the flows' and a mean ratio of 2.23 at L/50, 6000 s (0.78-0.91 and
    !> 1.97-2.06 with pairs kept; 0.6 kept too few at L/50: 2.14). The sets' kernel sums of
    !> volumes are as even either way. A lattice's nearest lie 0.9-1 apart.
    real(wp), parameter :: PAIR_GAP = 0.8_wp
    !> a same-level remesh leaves the particles of a narrow gap as they are (module header):
    !> a particle lies in one when two solids whose normals there are more than 120 degrees
    !> apart (cosine below GAP_FACING) are closer than NARROW_GAP spacings together (the sum
    !> of its distances to them); new points closer than GAP_CLEAR spacings to such a
    !> particle go
    real(wp), parameter :: NARROW_GAP = 2.5_wp
    real(wp), parameter :: GAP_FACING = -0.5_wp
    real(wp), parameter :: GAP_CLEAR = 0.75_wp

    !> The old positions and the new set of one remesh.
    type :: new_set_t
        integer :: mode = REMESH_NONE              !< REMESH_REFINE, _COARSEN or _SAME
        integer :: dim = 0                         !< 2 or 3
        real(wp) :: dx = 0.0_wp                    !< the old spacing
        real(wp) :: box_lo(3) = 0.0_wp, box_hi(3) = 0.0_wp
        logical :: periodic(3) = .false.
        !> the walls and bodies (absolute coordinates); not allocated: none
        type(solids_t), allocatable :: solids
        !> the old fluid positions and ids, n of them; the narrow gaps' particles last
        !> (after n_src)
        real(wp), allocatable :: x(:, :)
        integer(i8), allocatable :: ids(:)
        integer :: n = 0, n_src = 0
        !> the new set, n_new points: positions, and ids (refining: keys, two per point)
        real(wp), allocatable :: xn(:, :)
        integer(i8), allocatable :: idn(:)
        integer :: n_new = 0
        integer :: n_irregular = 0                 !< refinement: cells without a centre
        integer :: relax_passes = 0                !< relaxation passes made
    end type new_set_t

contains

    !> Position x (absolute) put on the grid of step SNAP_FRACTION dx from box_lo (on a
    !> periodic axis the step is adjusted to divide the box, and a point on box_hi goes to
    !> box_lo), before the remesh sees it. Why: the construction, the selection and the
    !> relaxation decide by thresholds and ties (an edge below 1.2 dx, the nearest of
    !> equidistant neighbours, the greedy passes' orders), and a run on another rank count
    !> reaches the remesh with positions that differ in their last bits; one flipped decision
    !> spreads through the greedy passes, the relaxation and the mass adjustment (Morris'
    !> cylinder at L/50 refined in a run at 200 s: masses 11-16 % apart between 1 and 3
    !> ranks, positions 0.32 new spacings, velocities 1.1e-2 of the peak; a cavity's
    !> refinement moved 2218 of its 2500 new particles when the input moved by one ulp).
    !> On the grid the same positions come from both, unless a point lies within its
    !> round-off of a cell's edge (about 1e-7 per particle and axis for differences of 1e-13
    !> dx); a move of at most 5e-7 dx changes nothing that the flow resolves.
    pure function snapped_to_grid(x, dim, dx, box_lo, box_hi, periodic) result(y)
        real(wp), intent(in) :: x(3), dx, box_lo(3), box_hi(3)
        integer, intent(in) :: dim
        logical, intent(in) :: periodic(3)
        real(wp) :: y(3), step, length
        integer(i8) :: k, cells
        integer :: a
        y = x
        do a = 1, dim
            step = SNAP_FRACTION * dx
            length = box_hi(a) - box_lo(a)
            cells = 0_i8
            if (periodic(a)) then
                cells = max(1_i8, nint(length / step, i8))
                step = length / real(cells, wp)
            end if
            k = nint((x(a) - box_lo(a)) / step, i8)
            if (periodic(a)) k = modulo(k, cells)
            y(a) = box_lo(a) + real(k, wp) * step
        end do
    end function snapped_to_grid

    !> Ready set (whose x, ids and n hold the old fluid) for a remesh of the given mode:
    !> no particle set aside, an empty new set.
    subroutine new_set_init(set, mode, dim, dx, box_lo, box_hi, periodic, solids)
        type(new_set_t), intent(inout) :: set
        integer, intent(in) :: mode, dim
        real(wp), intent(in) :: dx, box_lo(3), box_hi(3)
        logical, intent(in) :: periodic(3)
        type(solids_t), intent(in), optional :: solids
        set%mode = mode
        set%dim = dim
        set%dx = dx
        set%box_lo = box_lo
        set%box_hi = box_hi
        set%periodic = periodic
        if (allocated(set%solids)) deallocate(set%solids)
        if (present(solids)) set%solids = solids
        set%n_src = set%n
        if (allocated(set%xn)) deallocate(set%xn)
        if (allocated(set%idn)) deallocate(set%idn)
        allocate(set%xn(3, 0), set%idn(0))
        set%n_new = 0
        set%n_irregular = 0
        set%relax_passes = 0
    end subroutine new_set_init

    !> Same level, after the caller has turned the refinement keys into ids: back to the
    !> count the fluid had (the fill pass of sph_coarsen), with the first row about half a
    !> spacing from each solid, as in the initial lattice (the refined set's rows next to a
    !> plane wall lie at 0.5 and 1.0 dx: none is dropped); the particles of the narrow gaps
    !> join the set as they were, with their ids (below every fresh one), and the relaxation
    !> moves none of them.
    subroutine finish_same_level(set, st, msg)
        type(new_set_t), intent(inout) :: set
        integer, intent(out) :: st
        character(len=:), allocatable, intent(inout) :: msg
        integer :: n_gap
        call keep_off_solids(set, WALL_GAP * set%dx)
        n_gap = set%n - set%n_src
        if (n_gap > 0) call keep_out_of_gaps(set)
        call coarsen_step(set, set%dx / 2.0_wp, set%n_src, st, msg)
        if (st /= 0) return
        if (n_gap > 0) then
            set%xn = reshape([set%xn(:, 1:set%n_new), set%x(:, set%n_src + 1:set%n)], &
                [3, set%n_new + n_gap])
            set%idn = [set%idn(1:set%n_new), set%ids(set%n_src + 1:set%n)]
            set%n_new = set%n_new + n_gap
        end if
        call relax_new_set(set, set%dx)
    end subroutine finish_same_level

    !> Xn and (coarsening) idn of the new set, positions relative to box_lo.
    subroutine new_positions(set, st, msg)
        type(new_set_t), intent(inout) :: set
        integer, intent(out) :: st
        character(len=:), allocatable, intent(inout) :: msg
        integer(i8), allocatable :: keys(:, :)
        character(len=200) :: text
        integer :: irregular, n_disordered
        st = 0
        text = ''
        select case (set%mode)
        case (REMESH_REFINE, REMESH_SAME)
            deallocate(set%xn)
            call refine_positions(set%dim, set%n_src, set%x, set%ids, set%dx, set%n_new, set%xn, &
                keys, st, text, &
                algorithm_box(set, set%dx), irregular, set%solids, set%box_lo, &
                merge(0.0_wp, WALL_BAND, set%mode == REMESH_SAME), &
                merge(2**set%dim * set%n, 0, set%mode == REMESH_REFINE))
            set%n_irregular = irregular
            ! where the construction's wall rules meet (a body close to a wall, a box's
            ! edges) a point may lie closer than WALL_GAP new spacings to a solid (0.31
            ! in a closed 3D box with a sphere): it goes, as in a coarsening, and its
            ! share of the mass goes to its neighbours (the relaxation moves none there)
            if (st == 0 .and. set%mode == REMESH_REFINE) call refined_off_solids(set, keys)
            ! a clumped flow's construction (irregular cells, gaps filled) and the cells
            ! next to a body's staircase leave uneven volumes: kernel sums 0.41-1.86 of
            ! the even value on Morris' L/25 cylinder at 1500 s refined, whose continued
            ! run then broke down at 5649 s (module header); a lattice's refinement is one
            if (st == 0 .and. set%mode == REMESH_REFINE .and. (irregular > 0 .or. has_body(set))) &
                call relax_new_set(set, 0.5_wp * set%dx, PAIR_GAP)
            ! the keys travel in idn's place until fresh_ids turns them into ids
            deallocate(set%idn)
            allocate(set%idn(2 * set%n_new))
            if (set%n_new > 0) set%idn = reshape(keys(:, 1:set%n_new), [2 * set%n_new])
        case (REMESH_COARSEN)
            deallocate(set%idn)
            allocate(set%idn(set%n))
            set%idn = set%ids(1:set%n)
            deallocate(set%xn)
            allocate(set%xn(3, set%n))
            set%xn = set%x(:, 1:set%n)
            set%n_new = set%n
            ! the first coarse row about half a new spacing from each solid, as in the
            ! initial lattice: next to a body the fine first row (0.25 new spacings off)
            ! is not kept; next to a plane wall the kept rows are moved (module header)
            call keep_off_solids(set, WALL_GAP * 2.0_wp * set%dx, curved_only=.true.)
            call coarsen_step(set, set%dx, nint(real(set%n, wp) / 2.0_wp**set%dim), st, msg, &
                n_disordered)
            if (st == 0) call place_plane_rows(set, 2.0_wp * set%dx)
            ! a selection from a near-lattice (no particle whose rows sit off whole
            ! spacings) with no body in it is its sublattice, whose volumes are even
            ! already (next to a body the lattice's staircase leaves uneven ones)
            ! the kept set in id order, whatever the ranks' share of the gathered one: the
            ! selection does not depend on the order, but the relaxation's sums and its
            ! pairs' ties do (a coarsened lattice next to a body kept other pairs on 2
            ! ranks than on 1); a refined set comes in key order
            if (st == 0 .and. (n_disordered > 0 .or. has_body(set))) then
                call into_id_order(set%xn, set%idn, set%n_new)
                call relax_new_set(set, 2.0_wp * set%dx, PAIR_GAP)
            end if
            ! where a body lies within a spacing of a plane wall, place_plane_rows cannot
            ! put the rows between them on the wall's gap without crossing the body's:
            ! what is left closer than WALL_GAP to any solid goes (its mass is handed on;
            ! 6 particles 0.25 new spacings off the wall under a 3D cylinder 1.5 old
            ! spacings from it were kept, against the documented 0.4). The factor lets
            ! the particles put on a gap's edge stay, to round-off.
            if (st == 0) call keep_off_solids(set, (1.0_wp - 1.0e-9_wp) * WALL_GAP * 2.0_wp * &
                set%dx)
            ! the rows put half a spacing off plane walls may come closer than the floor
            ! to a particle kept next to them (0.395 new spacings in a closed 3D box); a
            ! near-lattice's sublattice has none (its pairs are a whole new spacing apart)
            if (st == 0 .and. (n_disordered > 0 .or. has_body(set))) &
                call drop_close_pairs(set, (1.0_wp - 1.0e-9_wp) * RELAX_FLOOR * 2.0_wp * set%dx)
            return
        case default
            st = 1
            text = 'unknown mode'
        end select
        if (st /= 0) msg = trim(text)
    end subroutine new_positions

    !> Keep the coarsen_select set of xn/idn (spacing dxs), filled up to n_target particles
    !> where the set is disordered. Coarsening follows the flow's spacing (the kept set
    !> keeps the flow's clumping at twice the spacing, issue 10's "disorder kept"); the
    !> same-level remesh does not: it is there to give a clumped flow a fresh set, and a
    !> kept clumping cost the developed cylinder flow 9 % of its mean velocity
    !> (doc/validation.md).
    subroutine coarsen_step(set, dxs, n_target, st, msg, n_disordered)
        type(new_set_t), intent(inout) :: set
        real(wp), intent(in) :: dxs
        integer, intent(in) :: n_target
        integer, intent(out) :: st
        character(len=:), allocatable, intent(inout) :: msg
        !> the set's particles whose rows sit off whole spacings (sph_coarsen)
        integer, intent(out), optional :: n_disordered
        integer, allocatable :: kept(:), tag(:)
        integer :: n_kept
        character(len=200) :: text
        text = ''
        call coarsen_select(set%dim, set%n_new, set%xn, set%idn, dxs, n_kept, kept, tag, st, &
            text, algorithm_box(set, dxs), n_target=n_target, &
            follow_spacing=set%mode == REMESH_COARSEN, n_disordered=n_disordered)
        if (st /= 0) then
            msg = trim(text)
            return
        end if
        set%xn = set%xn(:, kept)
        set%idn = set%idn(kept)
        set%n_new = n_kept
    end subroutine coarsen_step

    !> Drop the refined points xn and their keys closer than WALL_GAP new
    !> spacings to a solid (to round-off: a plane wall's first row, half a spacing off,
    !> stays).
    subroutine refined_off_solids(set, keys)
        type(new_set_t), intent(inout) :: set
        integer(i8), allocatable, intent(inout) :: keys(:, :)
        logical, allocatable :: clear(:)
        integer :: a
        clear = clear_mask(set, (1.0_wp - 1.0e-9_wp) * WALL_GAP * 0.5_wp * set%dx)
        if (all(clear)) return
        set%xn = set%xn(:, pack([(a, a = 1, set%n_new)], clear))
        keys = keys(:, pack([(a, a = 1, set%n_new)], clear))
        set%n_new = size(set%xn, 2)
    end subroutine refined_off_solids

    !> Of every pair of xn closer than `floor` (through the periodic faces too),
    !> the particle with the larger id goes (its mass is handed on to the others).
    subroutine drop_close_pairs(set, floor)
        type(new_set_t), intent(inout) :: set
        real(wp), intent(in) :: floor
        real(wp), allocatable :: y(:, :)
        integer, allocatable :: orig(:)
        logical, allocatable :: keep(:)
        type(neighbour_list_t) :: near
        integer :: ny, a, k, b
        if (set%n_new < 2) return
        call with_images(set%dim, set%box_lo, set%box_hi, set%periodic, set%n_new, set%xn, &
            floor, y, orig, ny)
        call build_neighbour_list(y, ny, set%n_new, set%dim, floor, near)
        allocate(keep(set%n_new))
        keep = .true.
        do a = 1, set%n_new
            do k = near%start(a), near%start(a + 1) - 1
                b = orig(near%index(k))
                if (b == a .or. .not. keep(a) .or. .not. keep(b)) cycle
                if (sum((y(1:set%dim, a) - y(1:set%dim, near%index(k)))**2) >= floor**2) cycle
                if (set%idn(b) > set%idn(a)) then
                    keep(b) = .false.
                else
                    keep(a) = .false.
                end if
            end do
        end do
        call keep_only(set, keep)
    end subroutine drop_close_pairs

    !> Keep the points of xn/idn marked in keep, in their order.
    subroutine keep_only(set, keep)
        type(new_set_t), intent(inout) :: set
        logical, intent(in) :: keep(:)
        integer :: a
        if (all(keep)) return
        set%xn = set%xn(:, pack([(a, a = 1, set%n_new)], keep))
        set%idn = set%idn(pack([(a, a = 1, set%n_new)], keep))
        set%n_new = size(set%idn)
    end subroutine keep_only

    !> Drop the candidates xn/idn closer than gap to any solid surface (with
    !> curved_only, to any solid that is not a plane).
    subroutine keep_off_solids(set, gap, curved_only)
        type(new_set_t), intent(inout) :: set
        real(wp), intent(in) :: gap
        logical, intent(in), optional :: curved_only
        call keep_only(set, clear_mask(set, gap, curved_only))
    end subroutine keep_off_solids

    !> Whether each point of xn is at least gap from every solid surface (with
    !> curved_only, from every solid that is not a plane); all true, with no pass over
    !> the set, when no solid applies (a periodic box; only planes with curved_only).
    function clear_mask(set, gap, curved_only) result(clear)
        type(new_set_t), intent(in) :: set
        real(wp), intent(in) :: gap
        logical, intent(in), optional :: curved_only
        logical, allocatable :: clear(:)
        logical :: planes
        integer :: a
        allocate(clear(set%n_new))
        clear = .true.
        if (.not. allocated(set%solids)) return
        if (.not. allocated(set%solids%list)) return
        if (size(set%solids%list) == 0) return
        planes = .true.
        if (present(curved_only)) planes = .not. curved_only
        if (.not. planes .and. all(set%solids%list(:)%shape == SOLID_PLANE)) return
        do a = 1, set%n_new
            clear(a) = clear_of_solids(set, set%xn(:, a), gap, curved_only)
        end do
    end function clear_mask

    !> Even out the volumes of the selected set xn of spacing sp (sph_remesh_relax),
    !> its periodic images and mirrors across the solids pushing; a move that would bring a
    !> particle closer than WALL_GAP sp to a solid is not made. At most RELAX_PASSES
    !> passes; it stops after a pass whose largest move is below RELAX_TOLERANCE sp.
    subroutine relax_new_set(set, sp, pair_gap)
        type(new_set_t), intent(inout) :: set
        real(wp), intent(in) :: sp
        real(wp), intent(in), optional :: pair_gap
        real(wp), allocatable :: y(:, :), moves(:, :)
        integer, allocatable :: orig(:), moves_with(:)
        real(wp) :: reach, largest, relax_gap
        integer :: pass, ny, a
        type(relax_list_t) :: kept
        reach = 2.0_wp * RELAX_H_FACTOR * sp
        relax_gap = WALL_GAP * sp
        allocate(moves(3, max(set%n_new, 1)))
        do pass = 1, RELAX_PASSES
            call with_mirrors_and_images(set%dim, set%box_lo, set%box_hi, set%periodic, &
                set%solids, reach, reach, set%n_new, set%xn, y, orig, ny, moves_with)
            call relax_displacements(set%dim, set%n_new, ny, y, sp, moves, kept, RELAX_FLOOR, &
                off_solids, pair_gap, moves_with)
            largest = 0.0_wp
            do a = 1, set%n_new
                set%xn(:, a) = wrapped(set, set%xn(:, a) + moves(:, a))
                largest = max(largest, norm2(moves(:, a)))
            end do
            set%relax_passes = pass
            ! an even set (a lattice's sublattice) barely moves: the passes left would not
            ! move it either
            if (largest < RELAX_TOLERANCE * sp) exit
        end do
    contains

        !> The relaxation's constraint: a move that would bring a particle closer than
        !> relax_gap to a solid is refused
        logical function off_solids(z)
            real(wp), intent(in) :: z(3)
            off_solids = clear_of_solids(set, wrapped(set, z), relax_gap)
            ! (and, with particles left in narrow gaps, out of the gaps: those stay put)
            if (off_solids .and. set%n_src < set%n) &
                off_solids = .not. in_narrow_gap(set, wrapped(set, z))
        end function off_solids
    end subroutine relax_new_set

    !> Same level: the particles of x/ids that lie in a narrow gap moved to the
    !> end (their order kept), n_src the count before them. Across a gap narrower than
    !> NARROW_GAP spacings the free strip (WALL_GAP off each side) is narrower than the
    !> selection's radius, so the construction and selection leave one row at a whole
    !> spacing where the flow holds its particles closer (a gap of 1.4 spacings: one row
    !> at 0.7), and the transfer takes the difference's mass out of the gap; remeshed
    !> every 20 steps, a channel with such gaps ran 29 % faster than the run made at half
    !> the spacing (unremeshed: 6 %).
    !> A particle closer than RELAX_FLOOR spacings to another is remeshed with the rest,
    !> both of the pair: a pair the set-up left 0.095 dx apart between two discs 1 dx
    !> apart was kept through 47 remeshes. (Closer than WALL_GAP to a solid is the flow's
    !> own place, as unremeshed; remeshing those too halved the flux through a gap of 1.4
    !> spacings under a disc: 0.34-0.37 against 0.58-0.65, at half the spacing 0.63.)
    subroutine set_aside_gaps(set)
        type(new_set_t), intent(inout) :: set
        logical, allocatable :: gap(:)
        integer, allocatable :: order(:), orig(:)
        real(wp), allocatable :: y(:, :)
        type(neighbour_list_t) :: near
        real(wp) :: floor
        integer :: a, k, b, ny
        allocate(gap(set%n))
        do a = 1, set%n
            gap(a) = in_narrow_gap(set, set%x(:, a))
        end do
        if (.not. any(gap)) return
        ! a pair closer than the floor is remeshed with the rest, both of it
        floor = (1.0_wp - 1.0e-9_wp) * RELAX_FLOOR * set%dx
        call with_images(set%dim, set%box_lo, set%box_hi, set%periodic, set%n, set%x, floor, &
            y, orig, ny)
        call build_neighbour_list(y, ny, set%n, set%dim, floor, near)
        do a = 1, set%n
            do k = near%start(a), near%start(a + 1) - 1
                b = orig(near%index(k))
                if (b == a .or. .not. (gap(a) .or. gap(b))) cycle
                if (sum((y(1:set%dim, a) - y(1:set%dim, near%index(k)))**2) >= floor**2) cycle
                gap(a) = .false.
                gap(b) = .false.
            end do
        end do
        if (.not. any(gap)) return
        set%n_src = count(.not. gap)
        allocate(order(set%n))
        order(1:set%n_src) = pack([(a, a = 1, set%n)], .not. gap)
        order(set%n_src + 1:set%n) = pack([(a, a = 1, set%n)], gap)
        set%x(:, 1:set%n) = set%x(:, order)
        set%ids(1:set%n) = set%ids(order)
    end subroutine set_aside_gaps

    !> Whether z (relative to box_lo) lies in a narrow gap (set_aside_gaps): two solids
    !> facing each other there, closer than NARROW_GAP spacings together.
    logical function in_narrow_gap(set, z)
        type(new_set_t), intent(in) :: set
        real(wp), intent(in) :: z(3)
        ! the solids within NARROW_GAP spacings of z (only those can make a gap with it)
        integer, parameter :: MAX_NEAR = 32
        real(wp) :: d, normal(3, MAX_NEAR), d_near(MAX_NEAR)
        integer :: s, t, n_near
        in_narrow_gap = .false.
        if (.not. allocated(set%solids)) return
        if (.not. allocated(set%solids%list)) return
        n_near = 0
        do s = 1, size(set%solids%list)
            d = solid_distance(set%solids%list(s), z + set%box_lo)
            if (d >= NARROW_GAP * set%dx .or. n_near == MAX_NEAR) cycle
            n_near = n_near + 1
            d_near(n_near) = d
            normal(:, n_near) = solid_normal(set%solids%list(s), z + set%box_lo)
        end do
        do s = 1, n_near
            do t = s + 1, n_near
                if (d_near(s) + d_near(t) >= NARROW_GAP * set%dx) cycle
                if (dot_product(normal(:, s), normal(:, t)) >= GAP_FACING) cycle
                in_narrow_gap = .true.
                return
            end do
        end do
    end function in_narrow_gap

    !> Same level: drop the new points xn/idn that lie in a narrow gap or closer
    !> than GAP_CLEAR spacings to a particle left there (x(:, n_src + 1:n), periodic
    !> images included).
    subroutine keep_out_of_gaps(set)
        type(new_set_t), intent(inout) :: set
        real(wp), allocatable :: y(:, :), yi(:, :)
        integer, allocatable :: orig(:)
        logical, allocatable :: keep(:)
        type(neighbour_list_t) :: near
        integer :: a, k, b, n_gap, ny
        n_gap = set%n - set%n_src
        allocate(keep(set%n_new))
        do a = 1, set%n_new
            keep(a) = .not. in_narrow_gap(set, set%xn(:, a))
        end do
        ! the gap's particles are the list's rows, the new points its candidates
        y = reshape([set%x(:, set%n_src + 1:set%n), set%xn(:, 1:set%n_new)], &
            [3, n_gap + set%n_new])
        call with_images(set%dim, set%box_lo, set%box_hi, set%periodic, n_gap + set%n_new, y, &
            GAP_CLEAR * set%dx, yi, orig, ny)
        call build_neighbour_list(yi, ny, n_gap, set%dim, GAP_CLEAR * set%dx, near)
        do a = 1, n_gap
            do k = near%start(a), near%start(a + 1) - 1
                b = orig(near%index(k)) - n_gap
                if (b < 1) cycle
                if (sum((yi(1:set%dim, a) - yi(1:set%dim, near%index(k)))**2) < &
                    (GAP_CLEAR * set%dx)**2) &
                    keep(b) = .false.
            end do
        end do
        call keep_only(set, keep)
    end subroutine keep_out_of_gaps

    !> z wrapped into the box along the periodic axes
    function wrapped(set, z) result(w)
        type(new_set_t), intent(in) :: set
        real(wp), intent(in) :: z(3)
        real(wp) :: w(3)
        integer :: ax
        w = z
        do ax = 1, set%dim
            if (set%periodic(ax)) w(ax) = modulo(w(ax), set%box_hi(ax) - set%box_lo(ax))
        end do
    end function wrapped

    !> Whether some solid is not a plane (a body).
    logical function has_body(set)
        type(new_set_t), intent(in) :: set
        has_body = .false.
        if (.not. allocated(set%solids)) return
        if (.not. allocated(set%solids%list)) return
        has_body = any(set%solids%list(:)%shape /= SOLID_PLANE)
    end function has_body

    !> Whether the point z (relative to box_lo) lies at least gap from every solid (with
    !> curved_only, from every solid that is not a plane).
    logical function clear_of_solids(set, z, gap, curved_only)
        type(new_set_t), intent(in) :: set
        real(wp), intent(in) :: z(3), gap
        logical, intent(in), optional :: curved_only
        integer :: s
        logical :: planes
        clear_of_solids = .true.
        if (.not. allocated(set%solids)) return
        if (.not. allocated(set%solids%list)) return
        planes = .true.
        if (present(curved_only)) planes = .not. curved_only
        do s = 1, size(set%solids%list)
            if (.not. planes .and. set%solids%list(s)%shape == SOLID_PLANE) cycle
            if (solid_distance(set%solids%list(s), z + set%box_lo) < gap) clear_of_solids = .false.
        end do
    end function clear_of_solids

    !> The coarsened set xn (spacing sp) moved so that its first row next to each
    !> plane wall lies half a spacing off it (module header, "Coarsening"). Wall s wants
    !> its first row (the particles within one spacing of it that have it as their
    !> nearest plane; mean distance f_s) moved by delta_s = sp / 2 - f_s along its
    !> normal. Between two facing walls (opposite normals, distances d_s and d_t) a
    !> particle moves by delta_s d_t / (d_s + d_t) along the one normal plus delta_t d_s /
    !> (d_s + d_t) along the other: the move varies linearly across the channel, so the
    !> rows stay evenly spaced (when both walls want the same shift, as a set of every
    !> other fine row does, the whole set moves by it); next to a wall that faces none the
    !> move fades out over WALL_BAND spacings. A particle left within WALL_GAP sp of a
    !> plane (a disordered first row, spread over the gap, whose mean barely moves) is put
    !> on the gap's edge; a move that would bring a particle within the gap of a body is
    !> not made. (Measured on the lid-driven cavity coarsened at 0.02 s: without that
    !> edge 23 of 625 particles ended within the gap, down to 0.15 spacings.)
    subroutine place_plane_rows(set, sp)
        type(new_set_t), intent(inout) :: set
        real(wp), intent(in) :: sp
        real(wp), allocatable :: row_sum(:), delta(:), d(:, :)
        integer, allocatable :: row_count(:), facing(:)
        real(wp) :: u(3), z(3)
        integer :: a, s, t, ns, near
        if (.not. allocated(set%solids)) return
        if (.not. allocated(set%solids%list)) return
        if (.not. any(set%solids%list(:)%shape == SOLID_PLANE)) return
        ns = size(set%solids%list)
        allocate(row_sum(ns), row_count(ns), delta(ns), facing(ns), d(ns, set%n_new))
        ! the facing wall of each plane (0: none)
        facing = [(facing_plane(set%solids, s), s = 1, ns)]
        ! every particle's distances from the planes, and each plane's first row
        row_sum = 0.0_wp
        row_count = 0
        do a = 1, set%n_new
            near = 0
            do s = 1, ns
                d(s, a) = huge(1.0_wp)
                if (set%solids%list(s)%shape /= SOLID_PLANE) cycle
                d(s, a) = solid_distance(set%solids%list(s), set%xn(:, a) + set%box_lo)
                if (near == 0) then
                    near = s
                else if (d(s, a) < d(near, a)) then
                    near = s
                end if
            end do
            if (d(near, a) >= sp) cycle
            row_sum(near) = row_sum(near) + d(near, a)
            row_count(near) = row_count(near) + 1
        end do
        delta = 0.0_wp
        where (row_count > 0) delta = 0.5_wp * sp - row_sum / max(row_count, 1)
        do a = 1, set%n_new
            u = 0.0_wp
            do s = 1, ns
                if (set%solids%list(s)%shape /= SOLID_PLANE) cycle
                t = facing(s)
                if (t > 0) then
                    if (d(s, a) + d(t, a) > 0.0_wp) u = u + delta(s) * d(t, a) / &
                        (d(s, a) + d(t, a)) * set%solids%list(s)%normal
                else
                    u = u + delta(s) * max(0.0_wp, 1.0_wp - d(s, a) / (WALL_BAND * sp)) * &
                        set%solids%list(s)%normal
                end if
            end do
            ! a particle of a disordered first row that still lies within the gap (the
            ! row's mean barely moves where it is spread over the gap) is put on its edge
            do s = 1, ns
                if (set%solids%list(s)%shape /= SOLID_PLANE) cycle
                u = u + max(0.0_wp, WALL_GAP * sp - (d(s, a) + dot_product(u, &
                    set%solids%list(s)%normal))) * set%solids%list(s)%normal
            end do
            u(set%dim + 1:) = 0.0_wp
            z = set%xn(:, a) + u
            ! (the planes' gaps hold by construction)
            if (clear_of_solids(set, z, WALL_GAP * sp, curved_only=.true.)) set%xn(:, a) = z
        end do
    end subroutine place_plane_rows

    !> The points xs(:, 1:count) and their ids idv in id order.
    subroutine into_id_order(xs, idv, count)
        real(wp), intent(inout) :: xs(:, :)
        integer(i8), intent(inout) :: idv(:)
        integer, intent(in) :: count
        integer, allocatable :: order(:)
        allocate(order(count))
        call id_order(idv, count, order)
        xs(:, 1:count) = xs(:, order)
        idv(1:count) = idv(order)
    end subroutine into_id_order

    !> The box given to refine_positions / coarsen_select: the domain on periodic axes;
    !> on the others a length so much larger that their images never meet a particle.
    function algorithm_box(set, spacing) result(b)
        type(new_set_t), intent(in) :: set
        real(wp), intent(in) :: spacing
        real(wp) :: b(3)
        integer :: a
        b = 0.0_wp
        do a = 1, set%dim
            b(a) = set%box_hi(a) - set%box_lo(a)
            if (.not. set%periodic(a)) b(a) = 2.0_wp * b(a) + 64.0_wp * spacing
        end do
    end function algorithm_box
end module sph_remesh_positions
