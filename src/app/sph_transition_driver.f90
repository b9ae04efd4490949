!> The parallel side of multi-resolution runs (thesis sec. 3.3, issue 11): the particles of
!> every resolution level at set-up, and the transition zones' update after every step.
!>
!> Levels. Level L has spacing dx / 2^L (&domain dx is the coarsest) and its own kernel; its
!> real fluid particles (kind 0) live where sph_zones' level_at is L, its virtual particles
!> (kind 2) in its transition zone (in_transition), its wall particles wherever its fluid may
!> reach a wall (within the zone width plus its kernel support of its region). The neighbour
!> list pairs particles of one level only, so each level is a complete SPH system.
!>
!> Update after every step (the particles have been migrated and the halo built, so every
!> rank sees its own particles and their neighbours), following the thesis' Figure 1-4:
!>  1. conversions: a virtual particle that has moved into its level's region turns real (a
!>     fresh global id, sph_global_ids, keyed by its virtual id and position); a real particle
!>     that has moved out of it is deleted (its level no longer holds it: the other level's
!>     virtual particles there have become real or are made anew);
!>  2. for each interface (levels L-1 and L): fine virtuals from the coarse level's particles
!>     (real and the previous step's virtuals, owned and ghosts, near the zone) and coarse
!>     virtuals from the fine level's (sph_transition), each keeping the new positions in its
!>     zone, inside the box and in this rank's subdomain, with fields interpolated from the
!>     source level (M4'); masses are the sources' scaled by 2^-dim (fine) or 2^dim (coarse);
!>  3. every old virtual particle and every departed real one is removed; the new virtuals
!>     are appended as owned particles. The caller rebuilds the halo and the neighbour list.
!> Mass. A level's real mass changes only by conversions: it gains the mass of the virtuals
!> that turn real and loses the mass of the real particles that leave. Over both levels of
!> an interface, flow across it moves mass from one level to the other; the driver counts
!> both directions (level_stats_t) so the log shows the real mass of each level, of all
!> levels together, and how much crossed.
module sph_transition_driver
    use sph_kinds, only: wp, i8
    use sph_mpi_env, only: mpi_env_t, global_sum, global_max, exclusive_scan_i8
    use sph_remesh_images, only: with_periodic_images, with_mirrors
    use sph_refine, only: MIRROR_DEPTH, MIN_GAP
    use sph_errors, only: fatal_collective
    use sph_config, only: config_t
    use sph_particles, only: particles_t, particles_init, particles_free, particles_reserve, &
        particles_gather, particles_clear, particles_append, particles_add_field, KIND_FLUID, &
        KIND_WALL, KIND_VIRTUAL, moves_with_flow, FIELD_CHECKPOINT, FIELD_OPTIONAL, HALO_GHOST
    use sph_physics, only: physics_t
    use sph_solids, only: solids_t, deepest_solid, SOLID_PLANE
    use sph_remesh_relax, only: relax_displacements, relax_list_t, RELAX_PASSES, RELAX_H_FACTOR
    use sph_domain, only: domain_t, domain_owner
    use sph_halo, only: halo_t, halo_setup, halo_build
    use sph_zones, only: zones_t, MAX_LEVEL
    use sph_initial, only: create_lattice_particles, site_filter_t
    use sph_global_ids, only: global_max_id, assign_global_ids, id_order
    use sph_cell_list, only: neighbour_list_t, build_cross_list, build_neighbour_list
    use sph_kernel, only: kernel_t, kernel_lattice_sum
    use sph_transition, only: fine_virtual_positions, coarse_virtual_positions, &
        fine_virtual_split, coarse_virtual_parity, &
        interpolate_fields, virtual_id, image_source_id, bisect, fit_to_bodies, &
        fill_next_to_bodies, nearest_body
    implicit none
    private
    public :: level_stats_t, create_level_particles, update_transition_zones, level_totals
    public :: refresh_virtual_fields, refine_uniform_state, set_virtual_masses
    public :: refresh_plan_t, add_lineage_field

    !> Source particles are taken within the zone width plus SOURCE_MARGIN source spacings:
    !> enough for the refinement's cells (<= 1.8 dx), the coarsening's rows and tagging chains
    !> (<= 4.3 fine spacings) and the interpolation's reach (2 sqrt(dim) h).
    real(wp), parameter :: SOURCE_MARGIN = 4.0_wp
    !> refining a uniform state next to a body: the fill takes a lattice site where no new
    !> point lies within this many fine spacings (sph_transition fill_next_to_bodies)
    real(wp), parameter :: FILL_GAP = 0.6_wp
    !> the band next to a body whose new points are relaxed, and the least distances (in fine
    !> spacings) a relaxed point keeps from a body and from the others (refine_uniform_state;
    !> with a floor of 0.4 the 3D band around a sphere had pairs 0.40 spacings apart, a fresh
    !> lattice's closest are 0.60)
    real(wp), parameter :: RELAX_BODY_BAND = 3.0_wp, RELAX_BODY_GAP = 0.4_wp
    real(wp), parameter :: RELAX_PAIR_FLOOR = 0.6_wp

    !> Lineage (split rule). Each particle carries, in the run-time field LINEAGE_FIELD,
    !> (1) the identity its fine children descend from, 0 for its own id, and (2) the identity
    !> of the coarse particle it is a child of, 0 when unknown (set-up: the coarse lattice
    !> site it lies in). A coarse virtual particle made from a fine particle of parity 0 takes
    !> that particle's parent as its identity, so it names the same children as the coarse
    !> particle it stands in for. A fine virtual particle that would copy a real one (the same
    !> parent and corner, within COPY_DISTANCE fine spacings) is not made and does not turn
    !> real. Without that, a coarse particle's children and the children of the coarse
    !> virtual made from its first converted child both turned real, one on top of the other:
    !> on input/cylinder_multires.nml 51 of the ring's 529 fine particles sat within 0.01
    !> spacings of another by 6000 s, and the run broke down (doc/multiresolution.md).
    !> Identities are real global ids; they stay far below 2^53, so real(wp) holds them.
    character(len=*), parameter :: LINEAGE_FIELD = 'lineage'
    real(wp), parameter :: COPY_DISTANCE = 0.5_wp
    !> a slot this close (in its level's spacings, per axis) to a real particle of its level
    !> stands on it (find_coincident): duplicates came 0.0004-0.002 spacings apart, a fresh
    !> lattice's closest pairs lie 0.6 apart
    real(wp), parameter :: COINCIDENT = 0.05_wp

    !> What the transition updates did since the counters were last reset (this rank).
    type :: level_stats_t
        integer(i8) :: became_real(0:MAX_LEVEL) = 0   !< virtual -> real
        integer(i8) :: left(0:MAX_LEVEL) = 0          !< real particles that left their region
        real(wp) :: mass_in(0:MAX_LEVEL) = 0.0_wp     !< mass of those that became real
        real(wp) :: mass_out(0:MAX_LEVEL) = 0.0_wp    !< mass of those that left
        integer(i8) :: updates = 0
        integer(i8) :: fallbacks = 0                  !< interpolations below first order
        integer(i8) :: empty = 0                      !< virtuals with no source in reach
        integer(i8) :: clipped = 0                    !< values clipped to their sources' range
    end type level_stats_t

    type :: index_list_t
        integer, allocatable :: i(:)
    end type index_list_t

    !> refresh_virtual_fields' candidates, kept from one rebuild of the halo and the
    !> neighbour list to the next (particle indices are fixed in between): each level's owned
    !> virtual particles, and for each level and each neighbouring level (side 0 below, 1
    !> above) the source particles within reach + margin of it, margin a bound on how far a
    !> particle moves before the next rebuild. Each step then filters these short lists
    !> instead of testing every particle against the regions.
    type :: refresh_plan_t
        logical :: valid = .false.
        integer :: n_owned = -1, n_total = -1
        type(index_list_t) :: virtuals(0:MAX_LEVEL)
        type(index_list_t) :: sources(0:MAX_LEVEL, 0:1)
    end type refresh_plan_t

    !> The lattice sites a level keeps at set-up (create_level_particles): its fluid in its
    !> region and transition zone, its walls within reach of those.
    type, extends(site_filter_t) :: level_sites_t
        type(zones_t) :: zones
        integer :: level = 0
        real(wp) :: reach = 0.0_wp
    contains
        procedure :: keep => keep_level_site
    end type level_sites_t

    !> New virtual particles of one level, before they join the particle set.
    type :: new_set_t
        integer :: n = 0
        integer :: level = 0
        real(wp), allocatable :: x(:, :)
        real(wp), allocatable :: f(:, :)   !< velocity (3), density, energy, mass
        integer(i8), allocatable :: id(:)
        integer, allocatable :: parity(:)
        real(wp), allocatable :: lineage(:, :)   !< (2, n), when the particles carry it
    end type new_set_t

    !> Every position one level's virtual particles could be made at in one update (its
    !> slots), before the zone keeps some: their ids, positions and the ids' ascending order.
    type :: slot_set_t
        integer(i8), allocatable :: id(:)
        real(wp), allocatable :: x(:, :)
        integer, allocatable :: order(:)
        logical, allocatable :: copy(:)   !< a copy of a real particle (lineage): never real
    end type slot_set_t

    interface
        !> A uniform state (level 0 only, e.g. a checkpoint of a uniform run) turned into the
        !> levels of `zones` (collective): for each level L >= 1 in turn, every rank refines the
        !> same set, the real fluid particles of level L-1 near L's region (all ranks', with their
        !> periodic images), as the transition zones do (sph_transition: positions, parities,
        !> fields by quadratic MLS; masses rho dx_L^dim), and keeps its own positions in L's
        !> region (real, fresh ids from next_id in the refinement's output order, the same on any
        !> rank count) and zone (virtual); level L's wall particles come from its lattice. The
        !> particles of level L-1 inside L's region turn virtual within the zone and are deleted
        !> deeper. On entry the owned particles lie in this rank's subdomain; ghosts are stale on
        !> exit.
        module subroutine refine_uniform_state(env, cfg, level_phys, solids, domain, zones, &
                p, next_id)
            type(mpi_env_t), intent(in) :: env
            type(config_t), intent(in) :: cfg
            type(physics_t), intent(in) :: level_phys(0:)
            type(solids_t), intent(in) :: solids
            type(domain_t), intent(in) :: domain
            type(zones_t), intent(in) :: zones
            type(particles_t), intent(inout) :: p
            integer(i8), intent(inout) :: next_id
        end subroutine refine_uniform_state
    end interface

contains

    !> The slot of id `value` in `set` nearest to x, if within reach of it; 0 otherwise.
    !> A slot near a periodic face is held under one id on one side and under another on the
    !> other side (its sources there are periodic images, whose ids are marked by their side),
    !> and share_slots brings each rank the copies of its neighbours' slots (periodic images
    !> included) within reach: the copy nearest to the particle is then the same on any rank
    !> count (before, a virtual carried across the periodic face found its slot on 1 rank, as
    !> made on the far side, and none on 2 ranks; fz39).
    pure integer function nearest_slot(set, value, x, reach) result(k)
        type(slot_set_t), intent(in) :: set
        integer(i8), intent(in) :: value
        real(wp), intent(in) :: x(3), reach
        integer :: lo, hi, mid, first, j
        real(wp) :: best, d2
        k = 0
        if (.not. allocated(set%order)) return
        ! the first place of value in the id order
        lo = 1
        hi = size(set%order)
        first = 0
        do while (lo <= hi)
            mid = (lo + hi) / 2
            if (set%id(set%order(mid)) >= value) then
                if (set%id(set%order(mid)) == value) first = mid
                hi = mid - 1
            else
                lo = mid + 1
            end if
        end do
        if (first == 0) return
        best = reach * reach
        do j = first, size(set%order)
            if (set%id(set%order(j)) /= value) exit
            d2 = sum((set%x(:, set%order(j)) - x)**2)
            if (d2 <= best) then
                ! (ties: the first in id order, which sorts by id alone, stable in the
                ! storage order: the local copies come before the received ones)
                if (k == 0 .or. d2 < best) k = set%order(j)
                best = d2
            end if
        end do
    end function nearest_slot

    !> Append slots (ids, positions, copy flags) to a level's slot set, its id order anew. A
    !> middle level of three gets two: from the coarser level and from the finer one (it was
    !> allocated twice, and every run with a level-2 region stopped at its first zone update).
    subroutine add_slots(set, id, x, copy)
        type(slot_set_t), intent(inout) :: set
        integer(i8), intent(in) :: id(:)
        real(wp), intent(in) :: x(:, :)
        logical, intent(in) :: copy(:)
        if (.not. allocated(set%id)) then
            allocate(set%id(0), set%x(3, 0), set%copy(0))
        end if
        set%id = [set%id, id]
        set%x = reshape([set%x, x], [3, size(set%id)])
        set%copy = [set%copy, copy]
        if (allocated(set%order)) deallocate(set%order)
        allocate(set%order(size(set%id)))
        call id_order(set%id, size(set%id), set%order)
    end subroutine add_slots

    !> Give p the lineage field (multi-resolution runs with the split rule), before any
    !> particle is made or read: a restart then reads it from the checkpoint (older ones lack
    !> it: no lineage known, as for the remeshing rule).
    subroutine add_lineage_field(p)
        type(particles_t), intent(inout) :: p
        integer :: k
        k = particles_add_field(p, LINEAGE_FIELD, 2, FIELD_CHECKPOINT + FIELD_OPTIONAL + &
            HALO_GHOST)
    end subroutine add_lineage_field

    !> Index of the lineage field in p%extra, 0 when p carries none.
    pure integer function lineage_index(p) result(k)
        type(particles_t), intent(in) :: p
        if (allocated(p%extra)) then
            do k = 1, size(p%extra)
                if (trim(p%extra(k)%info%name) == LINEAGE_FIELD) return
            end do
        end if
        k = 0
    end function lineage_index

    !> A global id as the lineage field holds it: real ids (positive, below 2^53) exactly,
    !> others (virtual ids: hashes) as 0, unknown.
    pure real(wp) function lineage_value(id)
        integer(i8), intent(in) :: id
        lineage_value = 0.0_wp
        if (id > 0_i8 .and. id < shiftl(1_i8, 53)) lineage_value = real(id, wp)
    end function lineage_value

    !> The key copies are found by: the parent's identity and the corner (below 2^dim <= 8).
    pure integer(i8) function lineage_key(parent, corner)
        real(wp), intent(in) :: parent
        integer, intent(in) :: corner
        lineage_key = 8_i8 * nint(parent, i8) + corner
    end function lineage_key

    !> Set-up of a multi-resolution run: for every level, the lattice of its spacing
    !> (sph_initial) keeps its fluid sites in the level's region (real) and transition zone
    !> (virtual), and its wall sites within reach of those. Real ids are unique over the
    !> levels: each level's lattice ids are offset by the largest id of the levels before.
    subroutine create_level_particles(env, cfg, level_phys, solids, domain, zones, p, &
            fluid_mass_total)
        type(mpi_env_t), intent(in) :: env
        type(config_t), intent(in) :: cfg
        type(physics_t), intent(in) :: level_phys(0:)
        type(solids_t), intent(in) :: solids
        type(domain_t), intent(in) :: domain
        type(zones_t), intent(in) :: zones
        type(particles_t), intent(inout) :: p
        !> the mass of the fluid of the whole domain at level 0's spacing: what the uniform
        !> run's lattice holds (rho0 times the fluid volume with bodies)
        real(wp), intent(out), optional :: fluid_mass_total
        type(config_t) :: level_cfg
        type(particles_t) :: lattice
        type(level_sites_t) :: sites
        integer :: lv, k, lin, n_sites(3, 0:MAX_LEVEL), axis
        logical :: carries_lineage
        integer(i8) :: offset, level_max, previous_offset, linear

        carries_lineage = lineage_index(p) > 0
        lin = 0
        n_sites = 1
        do lv = 0, zones%n_levels - 1
            do axis = 1, cfg%domain%dimension
                n_sites(axis, lv) = nint((cfg%domain%box_hi(axis) - cfg%domain%box_lo(axis)) / &
                    (cfg%domain%dx / 2.0_wp**lv))
            end do
        end do
        previous_offset = 0
        p%n_owned = 0
        p%n_total = 0
        offset = 0
        sites%zones = zones
        do lv = 0, zones%n_levels - 1
            level_cfg = cfg
            level_cfg%domain%dx = cfg%domain%dx / 2.0_wp**lv
            sites%level = lv
            sites%reach = zones%width + level_phys(lv)%kernel%support
            call particles_init(lattice, 1024, cfg%domain%dimension)
            if (carries_lineage) then
                call add_lineage_field(lattice)
                lin = lineage_index(lattice)   ! the lattice's own field
            end if
            ! only the sites the level keeps: the whole lattice of a fine level would be the
            ! memory of the uniformly fine run
            if (lv == 0 .and. present(fluid_mass_total)) then
                call create_lattice_particles(level_cfg, level_phys(lv), solids, domain, &
                    lattice, filter=sites, fluid_mass_total=fluid_mass_total)
            else
                call create_lattice_particles(level_cfg, level_phys(lv), solids, domain, &
                    lattice, filter=sites)
            end if
            level_max = global_max_id(env, lattice%id, lattice%n_owned)
            ! the fluid outside the level's region lies in its transition zone: virtual
            do k = 1, lattice%n_owned
                lattice%level(k) = lv
                linear = lattice%id(k)
                lattice%id(k) = lattice%id(k) + offset
                if (lattice%kind(k) /= KIND_FLUID) cycle
                ! lineage: a fluid site's parent is the coarser level's site it lies in (the
                ! sites at +- dx/4 of a coarse site are its split children); a virtual one
                ! keeps its site's id as its identity
                if (lin > 0) lattice%extra(lin)%a(:, k) = [lineage_value(lattice%id(k)), &
                    parent_site(linear, lv)]
                if (zones%level_at(lattice%x(:, k)) == lv) then
                    if (lin > 0) lattice%extra(lin)%a(1, k) = 0.0_wp
                    cycle
                end if
                lattice%kind(k) = KIND_VIRTUAL
                lattice%id(k) = virtual_id(lv, lattice%id(k), -1_i8)
            end do
            previous_offset = offset
            offset = offset + level_max
            call particles_append(p, lattice, [(k, k = 1, lattice%n_owned)])
            call particles_free(lattice)
        end do
        p%n_ghost = 0

    contains

        !> The id of the level lv - 1 fluid site that holds level lv's fluid site `linear`
        !> (sph_initial's numbering), 0 on level 0 or where the lattices do not nest.
        real(wp) function parent_site(linear, lv) result(parent)
            integer(i8), intent(in) :: linear
            integer, intent(in) :: lv
            integer(i8) :: q, idx(3), coarse
            parent = 0.0_wp
            if (lv == 0) return
            if (any(n_sites(:, lv) /= merge(2 * n_sites(:, lv - 1), 1, &
                [1, 2, 3] <= cfg%domain%dimension))) return
            q = linear - 1
            idx(1) = mod(q, int(n_sites(1, lv), i8))
            q = q / n_sites(1, lv)
            idx(2) = mod(q, int(n_sites(2, lv), i8))
            idx(3) = q / n_sites(2, lv)
            idx(1:cfg%domain%dimension) = idx(1:cfg%domain%dimension) / 2
            coarse = 1 + idx(1) + n_sites(1, lv - 1) * (idx(2) + int(n_sites(2, lv - 1), i8) &
                * idx(3))
            parent = lineage_value(coarse + previous_offset)
        end function parent_site
    end subroutine create_level_particles

    !> The transition zones after a step (see the module header; collective). On entry the
    !> owned particles lie in this rank's subdomain and the ghosts are current; on exit the
    !> owned set has changed and the ghosts are stale (the caller rebuilds them).
    !> next_id: the next unused global id base, the same on every rank, advanced here.
    subroutine update_transition_zones(env, zones, level_phys, solids, domain, box_lo, box_hi, &
            p, next_id, stats)
        type(mpi_env_t), intent(in) :: env
        type(zones_t), intent(in) :: zones
        type(solids_t), intent(in) :: solids
        type(physics_t), intent(in) :: level_phys(0:)
        type(domain_t), intent(in) :: domain
        real(wp), intent(in) :: box_lo(3), box_hi(3)
        type(particles_t), intent(inout) :: p
        integer(i8), intent(inout) :: next_id
        type(level_stats_t), intent(inout) :: stats
        integer :: dim, i, lv, n_conv, k, stat, lin
        logical, allocatable :: drop(:), slotless_copy(:)
        integer, allocatable :: converted(:), keep(:)
        integer(i8), allocatable :: keys(:, :), new_ids(:)
        integer(i8) :: base
        type(new_set_t), allocatable :: sets(:)
        type(slot_set_t), allocatable :: slots(:)
        character(len=256) :: errmsg

        dim = p%dim
        lin = 0
        if (zones%split_virtuals) lin = lineage_index(p)
        ! 1. the new virtual particles of every zone, from the particles as they are now, and
        !    every slot they could have been made at, for the conversions
        allocate(sets(2 * (zones%n_levels - 1)), slots(0:zones%n_levels - 1))
        stat = 0
        errmsg = ''
        do lv = 1, zones%n_levels - 1
            call make_virtuals(lv, lv - 1, sets(2 * lv - 1))   ! fine, from the coarse level
            call make_virtuals(lv - 1, lv, sets(2 * lv))       ! coarse, from the fine level
        end do
        if (global_max(env, int(stat, i8)) /= 0) call fatal_collective('transition zones', &
            'making virtual particles failed: ' // trim(errmsg))
        ! the neighbours' slots within reach, periodic images included (nearest_slot)
        do lv = 0, zones%n_levels - 1
            call share_slots(slots(lv), slot_reach(lv))
        end do
        ! 2. conversions (owned particles; old virtuals are dropped after serving as sources)
        call find_slotless_copies()
        allocate(drop(p%n_owned), converted(p%n_owned))
        drop = .false.
        n_conv = 0
        do i = 1, p%n_owned
            select case (p%kind(i))
            case (KIND_FLUID)
                if (zones%level_at(p%x(:, i)) /= p%level(i)) then
                    drop(i) = .true.
                    stats%left(p%level(i)) = stats%left(p%level(i)) + 1
                    stats%mass_out(p%level(i)) = stats%mass_out(p%level(i)) + p%m(i)
                end if
            case (KIND_VIRTUAL)
                if (turns_real(i)) then
                    n_conv = n_conv + 1
                    converted(n_conv) = i
                    stats%became_real(p%level(i)) = stats%became_real(p%level(i)) + 1
                    stats%mass_in(p%level(i)) = stats%mass_in(p%level(i)) + p%m(i)
                else
                    drop(i) = .true.
                end if
            end select
        end do
        call keep_conversions_off_reals()
        ! 3. fresh ids for the virtuals that became real (rank-count independent keys)
        allocate(keys(2, max(n_conv, 1)), new_ids(max(n_conv, 1)))
        do k = 1, n_conv
            keys(1, k) = p%id(converted(k))
            keys(2, k) = transfer(p%x(1, converted(k)), 1_i8)
        end do
        base = next_id
        call assign_global_ids(env, keys, n_conv, base, new_ids, next_id)
        do k = 1, n_conv
            p%kind(converted(k)) = KIND_FLUID
            p%id(converted(k)) = new_ids(k)
        end do
        ! 4. drop the old virtuals and the departed, append the new virtuals
        keep = pack([(i, i = 1, p%n_owned)], .not. drop)
        call particles_gather(p, keep)
        p%n_owned = size(keep)
        p%n_ghost = 0
        p%n_total = p%n_owned
        do k = 1, size(sets)
            call append_set(sets(k))
        end do
        stats%updates = stats%updates + 1

    contains

        !> Whether virtual particle i turns real. Its slot, the position it would be made at
        !> now (found by its id), decides where there is one. The particle has moved since it
        !> was made with the velocity at its own position, its slot with its sources; in a
        !> shear flow they part by a fraction of a spacing. Judged by the particle alone, one
        !> behind its slot would miss its crossing (dropped, and its slot, now across, not
        !> made again: a hole), one ahead would cross twice (turned real, and made again
        !> behind: a clump). Measured on input/multires_cost.nml to 3 s: fine rows 2-3
        !> spacings short at the inflow and densities 995-1004 kg/m^3, against none and
        !> 1000.0-1001.6 with the slot deciding. A particle that turns real behind its slot
        !> moves to it, as every virtual particle that stays virtual does. Without a slot
        !> (its sources have left the zone) its own position decides.
        logical function turns_real(i)
            integer, intent(in) :: i
            integer :: lv_i, k
            real(wp) :: shift(3)
            lv_i = p%level(i)
            k = nearest_slot(slots(lv_i), p%id(i), p%x(:, i), slot_reach(lv_i))
            if (k == 0) then
                turns_real = zones%level_at(p%x(:, i)) == lv_i .and. .not. slotless_copy(i)
                return
            end if
            turns_real = zones%level_at(slots(lv_i)%x(:, k)) == lv_i .and. &
                .not. slots(lv_i)%copy(k)
            if (turns_real .and. zones%level_at(p%x(:, i)) /= lv_i) then
                shift = slots(lv_i)%x(:, k) - p%x(:, i)
                p%x(:, i) = p%x(:, i) + shift
                p%x_old(:, i) = p%x_old(:, i) + shift
            end if
        end function turns_real

        !> A virtual that turns real where it is (its slot inside the region, itself too)
        !> may stand on a real particle of its level that its slot did not: the slot is
        !> checked (find_coincident) where the sources put it now, the particle moved with
        !> the flow since it was made. Around a sphere with virtual_rule = 'remesh' a fine
        !> virtual on the band's edge turned real 0.005 spacings from a real particle that
        !> had just stayed inside (fz49). Such a conversion is not made: the virtual goes,
        !> as a copy does.
        subroutine keep_conversions_off_reals()
            integer, allocatable :: reals(:), cand(:)
            real(wp), allocatable :: xr(:, :)
            type(neighbour_list_t) :: near
            integer :: lv_c, j, kept
            if (n_conv == 0) return
            do lv_c = 0, zones%n_levels - 1
                cand = pack(converted(1:n_conv), p%level(converted(1:n_conv)) == lv_c)
                if (size(cand) == 0) cycle
                reals = staying_reals(lv_c)
                if (size(reals) == 0) cycle
                xr = p%x(:, reals)
                call build_cross_list(p%x(:, cand), size(cand), xr, size(reals), dim, &
                    COINCIDENT * level_phys(lv_c)%dx, near)
                do j = 1, size(cand)
                    if (near%start(j + 1) == near%start(j)) cycle
                    drop(cand(j)) = .true.
                    stats%became_real(lv_c) = stats%became_real(lv_c) - 1
                    stats%mass_in(lv_c) = stats%mass_in(lv_c) - p%m(cand(j))
                end do
            end do
            kept = 0
            do j = 1, n_conv
                if (drop(converted(j))) cycle
                kept = kept + 1
                converted(kept) = converted(j)
            end do
            n_conv = kept
        end subroutine keep_conversions_off_reals

        !> The real fluid particles of level lv, owned and ghosts, that stay in its region.
        function staying_reals(lv) result(reals)
            integer, intent(in) :: lv
            integer, allocatable :: reals(:)
            integer :: r
            reals = pack([(r, r = 1, p%n_owned + p%n_ghost)], &
                p%level(1:p%n_owned + p%n_ghost) == lv .and. &
                p%kind(1:p%n_owned + p%n_ghost) == KIND_FLUID)
            reals = pack(reals, [(zones%level_at(p%x(:, reals(r))) == lv, r = 1, size(reals))])
        end function staying_reals

        !> slotless_copy(i): owned virtual i has no slot, would turn real by its own position,
        !> and copies a real particle of its level (find_copies: the same parent and corner).
        !> A slot is checked when it is made, against the real particles of then; a virtual
        !> whose slot is gone never was against the ones that turned real after it was made.
        !> Around a sphere with three levels (3D), a set-up virtual turned real by position
        !> in the update that made the rule's child of the same parent and corner, that child
        !> lost its slot (its sources left the reach) and turned real by position at the next
        !> update, 0.07 spacings from the first: 18 such level-2 pairs by step 300.
        subroutine find_slotless_copies()
            integer, allocatable :: cand(:)
            logical, allocatable :: copy(:)
            integer :: j, lv_c
            allocate(slotless_copy(p%n_owned))
            slotless_copy = .false.
            if (lin == 0) return
            do lv_c = 1, zones%n_levels - 1
                cand = pack([(j, j = 1, p%n_owned)], p%kind(1:p%n_owned) == KIND_VIRTUAL .and. &
                    p%level(1:p%n_owned) == lv_c)
                cand = pack(cand, [(nearest_slot(slots(lv_c), p%id(cand(j)), &
                    p%x(:, cand(j)), slot_reach(lv_c)) == 0 .and. &
                    zones%level_at(p%x(:, cand(j))) == lv_c, j = 1, size(cand))])
                if (size(cand) == 0) cycle
                allocate(copy(size(cand)))
                copy = .false.
                call find_copies(lv_c, size(cand), p%x(:, cand), p%parity(cand), &
                    p%extra(lin)%a(:, cand), copy)
                slotless_copy(cand) = copy
                deallocate(copy)
            end do
        end subroutine find_slotless_copies

        !> How far from a virtual particle of level lv its slot may lie: one spacing. A
        !> virtual is made at its slot and both move with the flow until the next update,
        !> which comes with the next rebuild of the neighbour list, before any particle has
        !> moved half its skin (0.1 h): they part by a fraction of that. Copies of one slot
        !> lie a period apart, so the nearest is never in doubt.
        pure real(wp) function slot_reach(lv)
            integer, intent(in) :: lv
            slot_reach = level_phys(lv)%dx
        end function slot_reach

        !> Add to set the slots of the other ranks, and the periodic images of all, that lie
        !> within reach of this rank's region (a halo of the slots; collective).
        subroutine share_slots(set, reach)
            type(slot_set_t), intent(inout) :: set
            real(wp), intent(in) :: reach
            type(particles_t) :: q
            type(halo_t) :: slot_halo
            integer :: n
            n = 0
            if (allocated(set%id)) n = size(set%id)
            call particles_init(q, max(n, 1), dim)
            q%n_owned = n
            q%n_total = n
            if (n > 0) then
                q%x(:, 1:n) = set%x(:, 1:n)
                q%id(1:n) = set%id(1:n)
                q%kind(1:n) = merge(1, 0, set%copy(1:n))
            end if
            call halo_setup(slot_halo, domain, reach)
            call halo_build(slot_halo, domain, env, q)
            if (q%n_ghost > 0) call add_slots(set, q%id(n + 1:n + q%n_ghost), &
                q%x(:, n + 1:n + q%n_ghost), q%kind(n + 1:n + q%n_ghost) == 1)
            call particles_free(q)
        end subroutine share_slots

        !> Virtual particles of level `target` made from the particles of level `source` (an
        !> adjacent level), kept where target's zone is and this rank owns the position.
        subroutine make_virtuals(target, source, set)
            integer, intent(in) :: target, source
            type(new_set_t), intent(out) :: set
            integer :: j, n_src, n_new, n_fb, n_empty, n_clip, a, st
            integer, allocatable :: src(:), keep_new(:), order(:)
            logical, allocatable :: take(:)
            real(wp), allocatable :: xs(:, :), xn(:, :), fs(:, :)
            integer(i8), allocatable :: ids(:), vid(:)
            integer, allocatable :: par(:), new_parity(:), parent(:)
            real(wp), allocatable :: parent_mass(:), lineage(:, :)
            logical, allocatable :: copy(:)
            real(wp) :: reach, dx_source, y(3), factor
            character(len=256) :: msg
            dx_source = level_phys(source)%dx
            reach = zones%width + SOURCE_MARGIN * dx_source
            allocate(take(p%n_owned + p%n_ghost))
            do j = 1, p%n_owned + p%n_ghost
                ! the remeshing rule's refinement also builds on the source level's wall
                ! particles, so the cells between the first fluid row and the wall give the
                ! fine row next to the wall (the split rule gives it from the fluid row)
                take(j) = p%level(j) == source .and. (moves_with_flow(p%kind(j)) .or. &
                    (target > source .and. p%kind(j) == KIND_WALL .and. &
                    .not. zones%split_virtuals))
                if (take(j)) take(j) = zones%distance_to_level(p%x(:, j), target) < reach
            end do
            src = pack([(j, j = 1, p%n_owned + p%n_ghost)], take)
            n_src = size(src)
            allocate(ids(max(n_src, 1)))
            do j = 1, n_src
                ids(j) = image_source_id(p%id(src(j)), p%x(:, src(j)), box_lo, box_hi, dim)
            end do
            ! a repeated id (two virtuals whose hashes agree modulo 2^55): keep the first in
            ! id order, which does not depend on storage order
            allocate(order(max(n_src, 1)))
            call id_order(ids, n_src, order)
            deallocate(take)
            allocate(take(n_src))
            take = .true.
            do j = 2, n_src
                if (ids(order(j)) == ids(order(j - 1))) take(order(j)) = .false.
            end do
            src = pack(src, take)
            ids = pack(ids(1:n_src), take)
            n_src = size(src)
            allocate(xs(3, max(n_src, 1)))
            do j = 1, n_src
                xs(:, j) = p%x(:, src(j))
            end do
            st = 0
            msg = ''
            par = p%parity(src)
            if (zones%split_virtuals .and. target > source) then
                call fine_virtual_split(dim, target, n_src, xs, ids, dx_source, n_new, xn, &
                    vid, new_parity, parent)
            else if (zones%split_virtuals) then
                call coarse_virtual_parity(dim, target, n_src, xs, ids, par, dx_source, &
                    box_lo, n_new, xn, vid, new_parity, parent)
            else if (target > source) then
                call fine_virtual_positions(dim, target, n_src, xs, ids, dx_source, n_new, xn, &
                    vid, new_parity, st, msg)
            else
                call coarse_virtual_positions(dim, target, n_src, xs, ids, par, dx_source, &
                    box_lo, n_new, xn, vid, new_parity, st, msg)
            end if
            if (st /= 0) then
                stat = st
                errmsg = msg
                n_new = 0
            end if
            allocate(copy(max(n_new, 1)))
            copy = .false.
            if (lin > 0) then
                ! children descend from their source's identity; a coarse virtual takes its
                ! fine source's parent as its own identity
                allocate(lineage(2, max(n_new, 1)))
                do j = 1, n_new
                    a = src(parent(j))
                    if (target > source) then
                        lineage(:, j) = [0.0_wp, identity(a)]
                    else
                        lineage(:, j) = [p%extra(lin)%a(2, a), 0.0_wp]
                    end if
                end do
                if (target > source) call find_copies(target, n_new, xn, new_parity, &
                    lineage, copy)
            end if
            call find_coincident(target, n_new, xn, copy)
            call add_slots(slots(target), vid(1:n_new), xn(:, 1:n_new), copy(1:n_new))
            deallocate(take)
            allocate(take(max(n_new, 0)))
            do j = 1, n_new
                y = xn(:, j)
                take(j) = .not. copy(j)
                if (take(j)) take(j) = .not. any(y(1:dim) < box_lo(1:dim) .or. &
                    y(1:dim) >= box_hi(1:dim))
                if (take(j)) take(j) = deepest_solid(solids, y, 0.0_wp) == 0
                if (take(j)) take(j) = zones%level_at(y) == source
                if (take(j)) take(j) = zones%in_transition(y, target)
                if (take(j)) take(j) = domain_owner(domain, y) == domain%rank
            end do
            keep_new = pack([(j, j = 1, n_new)], take)
            set%n = size(keep_new)
            set%level = target
            allocate(set%x(3, max(set%n, 1)), set%id(max(set%n, 1)), set%f(6, max(set%n, 1)))
            set%x(:, 1:set%n) = xn(:, keep_new)
            set%id(1:set%n) = vid(keep_new)
            set%parity = new_parity(keep_new)
            if (lin > 0) set%lineage = lineage(:, keep_new)
            ! the split rule's masses: exactly the parent's share (2^-dim of a coarse
            ! particle, 2^dim fine ones), so the mass that turns real is what left
            if (zones%split_virtuals) parent_mass = p%m(src(parent(keep_new)))
            ! fields from the source level's fluid: velocity, density, energy, mass
            src = pack(src, moves_with_flow(p%kind(src)))
            n_src = size(src)
            allocate(fs(6, max(n_src, 1)))
            do j = 1, n_src
                xs(:, j) = p%x(:, src(j))
                fs(1:3, j) = p%v(:, src(j))
                fs(4, j) = p%rho(src(j))
                fs(5, j) = p%e(src(j))
                fs(6, j) = p%m(src(j))
            end do
            call interpolate_fields(dim, dx_source, n_src, xs, fs, set%n, set%x, set%f, n_fb, &
                n_empty, n_clip, clip=[.false., .false., .false., .true., .false., .true.])
            stats%clipped = stats%clipped + n_clip
            factor = 2.0_wp**(dim * (source - target))
            set%f(6, 1:set%n) = set%f(6, 1:set%n) * factor
            if (zones%split_virtuals) set%f(6, 1:set%n) = parent_mass * factor
            stats%fallbacks = stats%fallbacks + n_fb
            stats%empty = stats%empty + n_empty
            if (n_empty > 0) then
                ! no source in reach: a hole in the source level (cannot happen while the zone
                ! is as wide as the support); keep the particle out rather than give it no
                ! density (the interpolation leaves zeros there)
                a = 0
                do j = 1, set%n
                    if (set%f(4, j) > 0.0_wp) then
                        a = a + 1
                        set%x(:, a) = set%x(:, j)
                        set%id(a) = set%id(j)
                        set%parity(a) = set%parity(j)
                        set%f(:, a) = set%f(:, j)
                        if (lin > 0) set%lineage(:, a) = set%lineage(:, j)
                    end if
                end do
                set%n = a
            end if
        end subroutine make_virtuals

        !> Particle i's identity as a parent (lineage): the one it took, else its own id.
        real(wp) function identity(i)
            integer, intent(in) :: i
            identity = p%extra(lin)%a(1, i)
            if (identity == 0.0_wp) identity = lineage_value(p%id(i))
        end function identity

        !> copy(j) set where fine slot j of level `target` (x, parity, lineage) would copy a
        !> real particle of that level that stays in its region: one of the same parent and
        !> corner within COPY_DISTANCE spacings. (Refusing coarse copies too, by identity,
        !> drained both levels of the cylinder's ring: doc/multiresolution.md.)
        subroutine find_copies(target, n, x, parity, lineage, copy)
            integer, intent(in) :: target, n
            real(wp), intent(in) :: x(:, :), lineage(:, :)
            integer, intent(in) :: parity(:)
            logical, intent(inout) :: copy(:)
            integer(i8), allocatable :: keys(:), sorted(:)
            integer, allocatable :: reals(:), order(:)
            integer(i8) :: key
            integer :: j, r, n_r, m
            real(wp) :: limit2, value
            limit2 = (COPY_DISTANCE * level_phys(target)%dx)**2
            allocate(keys(max(p%n_owned + p%n_ghost, 1)), reals(max(p%n_owned + p%n_ghost, 1)))
            n_r = 0
            do r = 1, p%n_owned + p%n_ghost
                if (p%level(r) /= target .or. p%kind(r) /= KIND_FLUID) cycle
                value = p%extra(lin)%a(2, r)
                if (value == 0.0_wp) cycle
                if (zones%level_at(p%x(:, r)) /= target) cycle   ! leaving now
                n_r = n_r + 1
                reals(n_r) = r
                keys(n_r) = lineage_key(value, p%parity(r))
            end do
            allocate(order(max(n_r, 1)))
            call id_order(keys, n_r, order)
            sorted = keys(order(1:n_r))
            do j = 1, n
                if (lineage(2, j) == 0.0_wp) cycle
                key = lineage_key(lineage(2, j), parity(j))
                ! every real with this key, from the first
                do m = bisect(sorted, key), n_r
                    if (sorted(m) /= key) exit
                    r = reals(order(m))
                    if (sum((p%x(1:dim, r) - x(1:dim, j))**2) < limit2) then
                        copy(j) = .true.
                        exit
                    end if
                end do
            end do
        end subroutine find_copies

        !> copy(j) set where slot j of level `target` lies within COINCIDENT spacings of a
        !> real particle of that level: it would stand on it. Lineage cannot say so for a
        !> coarse slot (refusing coarse copies by identity drained the ring, above), nor for
        !> particles without lineage; a slot that coincides with a real particle to round-off
        !> can only be its copy. Without it, a coarse particle on a band's edge (a lattice
        !> site exactly radius + distance from the body) was copied by the coarse virtual
        !> made from its own child whenever rounding put one on each side of the edge: 3-4
        !> real particles within 0.002 spacings of one another (input/cylinder_multires.nml,
        !> a 16 mm band at dx = 4 mm), and the same after refining a uniform channel.
        subroutine find_coincident(target, n, x, copy)
            integer, intent(in) :: target, n
            real(wp), intent(in) :: x(:, :)
            logical, intent(inout) :: copy(:)
            type(neighbour_list_t) :: near
            real(wp), allocatable :: xr(:, :)
            integer, allocatable :: reals(:)
            integer :: j
            if (n == 0) return
            ! (one leaving now is replaced by the virtual standing in for it)
            reals = staying_reals(target)
            if (size(reals) == 0) return
            xr = p%x(:, reals)
            call build_cross_list(x, n, xr, size(reals), dim, &
                COINCIDENT * level_phys(target)%dx, near)
            do j = 1, n
                if (near%start(j + 1) > near%start(j)) copy(j) = .true.
            end do
        end subroutine find_coincident

        subroutine append_set(set)
            type(new_set_t), intent(in) :: set
            integer :: first, j, n
            if (set%n == 0) return
            first = p%n_owned + 1
            call particles_reserve(p, p%n_owned + set%n)
            call particles_clear(p, first, p%n_owned + set%n)
            do j = 1, set%n
                n = first + j - 1
                p%x(:, n) = set%x(:, j)
                p%v(:, n) = set%f(1:3, j)
                p%rho(n) = set%f(4, j)
                p%e(n) = set%f(5, j)
                p%m(n) = set%f(6, j)
                p%h(n) = level_phys(set%level)%kernel%h
                p%x_old(:, n) = p%x(:, n)
                p%v_old(:, n) = p%v(:, n)
                p%rho_old(n) = p%rho(n)
                p%e_old(n) = p%e(n)
                p%id(n) = set%id(j)
                p%kind(n) = KIND_VIRTUAL
                p%level(n) = set%level
                p%parity(n) = set%parity(j)
                if (lin > 0) p%extra(lin)%a(:, n) = set%lineage(:, j)
            end do
            p%n_owned = p%n_owned + set%n
            p%n_total = p%n_owned
        end subroutine append_set
    end subroutine update_transition_zones

    !> Between two updates of the zones: every owned virtual particle takes the velocity,
    !> density and energy of the level whose real particles are where it now is,
    !> interpolated as when it was made (sph_transition); positions and masses stay. Every
    !> value is computed from the state on entry and written at the end: virtual particles of
    !> one level are sources for those of the other, and their ghosts on other ranks still
    !> hold the entry state. Needs current ghosts; no MPI. plan: the candidates (made anew
    !> when not valid or when the particle counts changed; the caller invalidates it at every
    !> rebuild), margin: a bound on how far any particle moves until the next rebuild.
    !> levels: refresh only the virtual particles of these levels (sub-cycling: those whose
    !> step has just ended); all when absent. step_state: the refreshed values also become
    !> the state the Verlet kick starts from (v_old, rho_old, e_old), so that a virtual
    !> particle's fields do not carry on an integration of their own from one refresh to the
    !> next, by SPH equations whose support is cut at the zone's edge (the channels' error
    !> then moved; multiresolution.md, "Time steps").
    subroutine refresh_virtual_fields(zones, level_phys, p, stats, plan, margin, levels, &
            step_state)
        type(zones_t), intent(in) :: zones
        type(physics_t), intent(in) :: level_phys(0:)
        type(particles_t), intent(inout) :: p
        type(level_stats_t), intent(inout) :: stats
        type(refresh_plan_t), intent(inout) :: plan
        real(wp), intent(in) :: margin
        logical, intent(in), optional :: levels(0:), step_state
        integer :: target, source, j, n_fb, n_empty, n_clip, dim
        integer, allocatable :: dst(:), src(:)
        logical, allocatable :: changed(:)
        real(wp), allocatable :: xs(:, :), fs(:, :), xd(:, :), fd(:, :), new_fields(:, :)
        real(wp) :: reach
        dim = p%dim
        if (.not. plan%valid .or. plan%n_owned /= p%n_owned .or. plan%n_total /= p%n_total) &
            call make_refresh_plan(zones, level_phys, p, margin, plan)
        allocate(new_fields(5, p%n_owned), changed(p%n_owned))
        changed = .false.
        do target = 0, zones%n_levels - 1
            if (present(levels)) then
                if (.not. levels(target)) cycle
            end if
            do source = max(target - 1, 0), min(target + 1, zones%n_levels - 1)
                if (source == target) cycle
                associate (cand => plan%virtuals(target)%i)
                    dst = pack(cand, [(zones%level_at(p%x(:, cand(j))) == source, &
                        j = 1, size(cand))])
                end associate
                if (size(dst) == 0) cycle
                reach = zones%width + SOURCE_MARGIN * level_phys(source)%dx
                associate (cand => plan%sources(target, merge(1, 0, source > target))%i)
                    src = pack(cand, [(zones%distance_to_level(p%x(:, cand(j)), target) < &
                        reach, j = 1, size(cand))])
                end associate
                allocate(xs(3, max(size(src), 1)), fs(5, max(size(src), 1)))
                allocate(xd(3, size(dst)), fd(5, size(dst)))
                do j = 1, size(src)
                    xs(:, j) = p%x(:, src(j))
                    fs(1:3, j) = p%v(:, src(j))
                    fs(4, j) = p%rho(src(j))
                    fs(5, j) = p%e(src(j))
                end do
                xd = p%x(:, dst)
                call interpolate_fields(dim, level_phys(source)%dx, size(src), xs, fs, &
                    size(dst), xd, fd, n_fb, n_empty, n_clip, &
                    clip=[.false., .false., .false., .true., .false.])
                stats%fallbacks = stats%fallbacks + n_fb
                stats%clipped = stats%clipped + n_clip
                stats%empty = stats%empty + n_empty
                do j = 1, size(dst)
                    if (fd(4, j) <= 0.0_wp) cycle   ! no source in reach: keep what it has
                    new_fields(:, dst(j)) = fd(:, j)
                    changed(dst(j)) = .true.
                end do
                deallocate(xs, fs, xd, fd)
            end do
        end do
        do j = 1, p%n_owned
            if (.not. changed(j)) cycle
            p%v(:, j) = new_fields(1:3, j)
            p%rho(j) = new_fields(4, j)
            p%e(j) = new_fields(5, j)
        end do
        if (.not. present(step_state)) return
        if (.not. step_state) return
        do j = 1, p%n_owned
            if (.not. changed(j)) cycle
            p%v_old(:, j) = p%v(:, j)
            p%rho_old(j) = p%rho(j)
            p%e_old(j) = p%e(j)
        end do
    end subroutine refresh_virtual_fields

    !> refresh_virtual_fields' candidates for the current particles: its tests with the reach
    !> widened by margin (distance_to_level is 1-Lipschitz, so a particle that moves less
    !> than margin cannot enter the reach from outside these lists), in index order.
    subroutine make_refresh_plan(zones, level_phys, p, margin, plan)
        type(zones_t), intent(in) :: zones
        type(physics_t), intent(in) :: level_phys(0:)
        type(particles_t), intent(in) :: p
        real(wp), intent(in) :: margin
        type(refresh_plan_t), intent(inout) :: plan
        integer :: target, side, source, j
        integer, allocatable :: cand(:)
        real(wp) :: reach
        do target = 0, MAX_LEVEL
            plan%virtuals(target)%i = pack([(j, j = 1, p%n_owned)], &
                p%kind(1:p%n_owned) == KIND_VIRTUAL .and. p%level(1:p%n_owned) == target)
            do side = 0, 1
                source = target - 1 + 2 * side
                if (target >= zones%n_levels .or. source < 0 .or. source >= zones%n_levels) then
                    plan%sources(target, side)%i = [integer ::]
                    cycle
                end if
                reach = zones%width + SOURCE_MARGIN * level_phys(source)%dx + margin
                cand = pack([(j, j = 1, p%n_total)], [(p%level(j) == source .and. &
                    moves_with_flow(p%kind(j)), j = 1, p%n_total)])
                plan%sources(target, side)%i = pack(cand, [(zones%distance_to_level( &
                    p%x(:, cand(j)), target) < reach, j = 1, size(cand))])
            end do
        end do
        plan%n_owned = p%n_owned
        plan%n_total = p%n_total
        plan%valid = .true.
    end subroutine make_refresh_plan

    !> level_sites_t: the fluid sites of the level's region and transition zone, the wall
    !> sites within reach of the level's points.
    logical function keep_level_site(self, x, kind) result(keep)
        class(level_sites_t), intent(in) :: self
        real(wp), intent(in) :: x(3)
        integer, intent(in) :: kind
        if (kind == KIND_FLUID) then
            keep = self%zones%level_at(x) == self%level
            if (.not. keep) keep = self%zones%in_transition(x, self%level)
        else
            keep = self%zones%distance_to_level(x, self%level) < self%reach
        end if
    end function keep_level_site

    !> Masses of the owned virtual particles near their level's region from the volume their
    !> own level's particles leave them: m = rho V, V = dx_L^dim S_L / sum_j W_ij over the
    !> particles of the level within its support (real, virtual and wall, owned and ghosts, i
    !> itself included), S_L the same sum on a regular lattice of spacing dx_L. On a lattice
    !> V = dx_L^dim, the mass of a real particle of the level. Where the constructions of
    !> sph_transition leave fewer particles than a lattice would (they do where the flow has
    !> stretched or clumped the source particles: around Morris' cylinder, 3.1 fine virtuals
    !> per coarse particle after 750 s instead of 4, one coarse per 5.6 fine instead of 4), each
    !> takes the larger volume, so the virtuals that turn real bring the mass density of the
    !> level that the other one loses there. Only virtuals whose whole support lies within the
    !> zone (distance to the region + support <= zone width) get it: further out the sum is cut
    !> by the zone's edge and would make them heavy next to the real particles (measured on
    !> the channels: +31 % at the edge of the coarse zone, and the error of the fine band up by a
    !> quarter). The others keep the masses scaled from their sources. Only for the remeshing
    !> rule (&refinement virtual_rule = 'remesh'): the split rule's virtuals carry exact
    !> shares of their parents' masses, and a volume from the arrangement would make the mass
    !> that turns real differ from the mass that left. Needs the neighbour list
    !> of the level-paired particles with current ghosts; no MPI (the caller refreshes the
    !> ghosts' masses).
    subroutine set_virtual_masses(zones, level_phys, p, nl)
        type(zones_t), intent(in) :: zones
        type(physics_t), intent(in) :: level_phys(0:)
        type(particles_t), intent(inout) :: p
        type(neighbour_list_t), intent(in) :: nl
        integer :: i, k, j, lv
        real(wp) :: d(3), r, sum_w
        real(wp), allocatable :: lattice_sum(:)
        ! the split rule's virtual particles carry their parents' exact shares
        if (zones%split_virtuals) return
        allocate(lattice_sum(0:size(level_phys) - 1))
        do lv = 0, size(level_phys) - 1
            lattice_sum(lv) = kernel_lattice_sum(level_phys(lv)%kernel, level_phys(lv)%dx, p%dim)
        end do
        do i = 1, p%n_owned
            if (p%kind(i) /= KIND_VIRTUAL) cycle
            lv = p%level(i)
            associate (kernel => level_phys(lv)%kernel)
                if (zones%distance_to_level(p%x(:, i), lv) + kernel%support > zones%width) cycle
                sum_w = kernel%w(0.0_wp)
                do k = nl%start(i), nl%start(i + 1) - 1
                    j = nl%index(k)
                    d = p%x(:, i) - p%x(:, j)
                    r = norm2(d)
                    if (r < kernel%support) sum_w = sum_w + kernel%w(r)
                end do
            end associate
            p%m(i) = p%rho(i) * level_phys(lv)%dx**p%dim * lattice_sum(lv) / sum_w
        end do
    end subroutine set_virtual_masses



    !> Per level (0:n_levels-1): real and virtual counts, real mass and momentum (collective).
    subroutine level_totals(env, p, n_levels, n_real, n_virtual, mass, momentum)
        type(mpi_env_t), intent(in) :: env
        type(particles_t), intent(in) :: p
        integer, intent(in) :: n_levels
        integer(i8), intent(out) :: n_real(0:), n_virtual(0:)
        real(wp), intent(out) :: mass(0:), momentum(:, 0:)
        integer :: i, lv
        real(wp) :: local(4 * n_levels)
        integer(i8) :: counts(2 * n_levels)
        local = 0.0_wp
        counts = 0
        do i = 1, p%n_owned
            lv = p%level(i)
            if (p%kind(i) == KIND_FLUID) then
                counts(2 * lv + 1) = counts(2 * lv + 1) + 1
                local(4 * lv + 1) = local(4 * lv + 1) + p%m(i)
                local(4 * lv + 2:4 * lv + 4) = local(4 * lv + 2:4 * lv + 4) + p%m(i) * p%v(:, i)
            else if (p%kind(i) == KIND_VIRTUAL) then
                counts(2 * lv + 2) = counts(2 * lv + 2) + 1
            end if
        end do
        local = global_sum(env, local)
        counts = global_sum(env, counts)
        do lv = 0, n_levels - 1
            n_real(lv) = counts(2 * lv + 1)
            n_virtual(lv) = counts(2 * lv + 2)
            mass(lv) = local(4 * lv + 1)
            momentum(:, lv) = local(4 * lv + 2:4 * lv + 4)
        end do
    end subroutine level_totals
end module sph_transition_driver
