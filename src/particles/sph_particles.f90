!> Particle storage: structure of arrays. Each rank holds its owned particles in 1:n_owned,
!> followed by ghost copies (periodic images and other ranks' particles within reach, made by
!> the halo exchange) in n_owned+1:n_owned+n_ghost, followed by per-stage virtual copies (wall
!> mirror images) up to n_total. Physics loops update owned particles only and read all.
!>
!> The field table. Every per-particle field is a named component of particles_t (the
!> physics reads it by name) and one line of `particles_visit`, which says its name in files,
!> its width and where it travels (FIELD_* flags below). Everything generic is driven by that
!> one list: allocation, growth, permutation, copying, packing any subset for the halo and
!> migration (reals as reals, integers as integers), snapshot/checkpoint writing and reading
!> (sph_snapshot). Adding a field is a component here and one line in particles_visit; a
!> module may also add a real field at run time (particles_add_field), which then takes part in
!> all of the above like the built-in ones.
!> Fields that only some models use are allocated and visited only when a run enables them
!> (particles_enable): the transport velocity's two vectors and the strain rate, 12 values
!> of a particle's 40, which a run with Morris' viscosity and no transport velocity would
!> otherwise allocate, grow, copy and zero for nothing (peak memory at 10^6 particles 588 ->
!> 502 bytes a particle).
module sph_particles
    use sph_kinds, only: wp, i8
    implicit none
    private
    public :: particles_t, particles_init, particles_free, particles_reserve, particles_enable
    public :: particles_copy, particles_gather, particles_clear, particles_visit, particles_swap
    public :: particles_add_field, particles_add_fields_of, particles_append
    public :: particles_pack, particles_unpack, pack_widths, field_list
    public :: field_info_t, field_op_t
    public :: KIND_FLUID, KIND_WALL, KIND_VIRTUAL, KIND_MIRROR, moves_with_flow
    public :: FIELD_REAL, FIELD_INT8, FIELD_INT
    public :: FIELD_SNAPSHOT, FIELD_CHECKPOINT, FIELD_SHIFTED, FIELD_OPTIONAL
    public :: HALO_GHOST, HALO_MOVE, HALO_DENSITY, HALO_STRAIN, HALO_TRANSPORT, ALL_FIELDS

    integer, parameter :: KIND_FLUID = 0    !< moves with the flow
    integer, parameter :: KIND_WALL = 1     !< fixed wall particle, carries its wall's velocity
    integer, parameter :: KIND_VIRTUAL = 2  !< remeshing: particle of the other resolution level
    !> type-2 mirror image, rebuilt each stage, never output
    integer, parameter :: KIND_MIRROR = 3

    ! storage types of a field
    integer, parameter :: FIELD_REAL = 1    !< real(wp)
    integer, parameter :: FIELD_INT8 = 2    !< integer(i8) (global ids)
    integer, parameter :: FIELD_INT = 3     !< default integer, int32 in files

    ! where a field goes (bit flags)
    integer, parameter :: FIELD_SNAPSHOT = 1     !< a dataset of every snapshot (and checkpoint)
    integer, parameter :: FIELD_CHECKPOINT = 2   !< a dataset of checkpoints only
    integer, parameter :: FIELD_SHIFTED = 4      !< a position: periodic images are shifted
    integer, parameter :: HALO_GHOST = 8         !< what a ghost needs: sent when ghosts are made
    integer, parameter :: HALO_MOVE = 16         !< refreshed after particles moved within a step
    integer, parameter :: HALO_DENSITY = 32      !< refreshed after a summation density
    integer, parameter :: HALO_STRAIN = 64       !< refreshed after the strain rate
    integer, parameter :: FIELD_OPTIONAL = 128   !< a file may lack it: readers keep the default
    !> sent after a halo build and with HALO_MOVE by runs with the transport velocity only (the
    !> others do not pay for sending it)
    integer, parameter :: HALO_TRANSPORT = 256
    integer, parameter :: ALL_FIELDS = -1        !< every field (migration, permutation)

    !> One field as the table describes it.
    type :: field_info_t
        character(len=24) :: name = ''   !< dataset name in snapshot and checkpoint files
        integer :: width = 1             !< values per particle
        integer :: flags = 0             !< FIELD_* and HALO_* bits
        integer :: storage = FIELD_REAL  !< FIELD_REAL, FIELD_INT8 or FIELD_INT
    end type field_info_t

    !> A real field added at run time.
    type :: extra_field_t
        type(field_info_t) :: info
        real(wp), allocatable :: a(:, :)
    end type extra_field_t

    type :: particles_t
        integer :: n_owned = 0
        integer :: n_ghost = 0
        integer :: n_total = 0        !< owned + ghost + mirror
        integer :: capacity = 0
        integer :: dim = 2
        ! state
        real(wp), allocatable :: x(:, :)        !< position (3, n); z unused in 2D
        real(wp), allocatable :: v(:, :)        !< velocity (3, n)
        real(wp), allocatable :: rho(:)         !< density
        real(wp), allocatable :: p(:)           !< pressure
        real(wp), allocatable :: m(:)           !< mass
        real(wp), allocatable :: h(:)           !< smoothing length
        real(wp), allocatable :: e(:)           !< specific internal energy
        ! time derivatives
        real(wp), allocatable :: dvdt(:, :)
        real(wp), allocatable :: drhodt(:)
        real(wp), allocatable :: dedt(:)
        ! predictor copies: the state at the start of the step
        real(wp), allocatable :: x_old(:, :)
        real(wp), allocatable :: v_old(:, :)
        real(wp), allocatable :: rho_old(:)
        real(wp), allocatable :: e_old(:)
        ! transport-velocity formulation (with_transport only): the particles move with
        ! v + dv_transport; the background pressure's acceleration gives
        ! dv_transport = dt_stage dvdt_background
        logical :: with_transport = .false.
        real(wp), allocatable :: dv_transport(:, :)
        real(wp), allocatable :: dvdt_background(:, :)
        ! viscous strain rate (xx, yy, zz, xy, xz, yz) for the strain-rate viscosity
        ! (with_strain only)
        logical :: with_strain = .false.
        real(wp), allocatable :: strain(:, :)
        ! wall particles: unit normal into the fluid and distance behind the wall plane
        real(wp), allocatable :: wall_normal(:, :)
        real(wp), allocatable :: wall_distance(:)
        ! identity
        integer(i8), allocatable :: id(:)       !< global id, survives migration and remeshing
        integer, allocatable :: kind(:)         !< KIND_*
        integer, allocatable :: level(:)        !< resolution level, 0 = coarsest
        integer, allocatable :: solid(:)        !< the solid a wall particle belongs to, 0: none
        !> lattice parity per axis (bit a-1 set: odd along axis a), carried with the particle:
        !> multi-resolution zones keep the particles with parity 0 when coarsening (see
        !> sph_transition)
        integer, allocatable :: parity(:)
        ! real fields added at run time (particles_add_field): extra(k)%a(width, capacity)
        type(extra_field_t), allocatable :: extra(:)
    end type particles_t

    !> An operation applied to every field in turn by particles_visit. Rank-1 fields come as
    !> real1/int8/int4, vector fields as real2 (width, capacity).
    type, abstract :: field_op_t
    contains
        procedure(op_real1), deferred :: real1
        procedure(op_real2), deferred :: real2
        procedure(op_int8), deferred :: int8
        procedure(op_int4), deferred :: int4
    end type field_op_t

    abstract interface
        subroutine op_real1(op, a, info)
            import :: field_op_t, wp, field_info_t
            class(field_op_t), intent(inout) :: op
            real(wp), allocatable, intent(inout) :: a(:)
            type(field_info_t), intent(in) :: info
        end subroutine op_real1
        subroutine op_real2(op, a, info)
            import :: field_op_t, wp, field_info_t
            class(field_op_t), intent(inout) :: op
            real(wp), allocatable, intent(inout) :: a(:, :)
            type(field_info_t), intent(in) :: info
        end subroutine op_real2
        subroutine op_int8(op, a, info)
            import :: field_op_t, i8, field_info_t
            class(field_op_t), intent(inout) :: op
            integer(i8), allocatable, intent(inout) :: a(:)
            type(field_info_t), intent(in) :: info
        end subroutine op_int8
        subroutine op_int4(op, a, info)
            import :: field_op_t, field_info_t
            class(field_op_t), intent(inout) :: op
            integer, allocatable, intent(inout) :: a(:)
            type(field_info_t), intent(in) :: info
        end subroutine op_int4
    end interface

    ! ---- the generic operations, each a field_op_t ----

    !> Allocate (or grow, keeping the first `keep` particles) to `capacity`; new slots zero.
    type, extends(field_op_t) :: resize_op_t
        integer :: capacity = 0, keep = 0
    contains
        procedure :: real1 => resize_real1, real2 => resize_real2
        procedure :: int8 => resize_int8, int4 => resize_int4
    end type resize_op_t

    !> a(:, dst(k)) = a(:, src(k)), k = 1..n, for every field (right-hand side read first).
    type, extends(field_op_t) :: copy_op_t
        integer, allocatable :: src(:), dst(:)
    contains
        procedure :: real1 => copy_real1, real2 => copy_real2
        procedure :: int8 => copy_int8, int4 => copy_int4
    end type copy_op_t

    !> Every field of slots first..last set to zero (a defined state before reading).
    type, extends(field_op_t) :: clear_op_t
        integer :: first = 1, last = 0
    contains
        procedure :: real1 => clear_real1, real2 => clear_real2
        procedure :: int8 => clear_int8, int4 => clear_int4
    end type clear_op_t

    !> Pack (or unpack) the selected fields of particles index(1:n) into columns of rbuf
    !> (reals) and ibuf (integers as int64); `row_r`/`row_i` advance through the fields.
    type, extends(field_op_t) :: pack_op_t
        integer :: mask = ALL_FIELDS
        logical :: unpack = .false.
        integer :: n = 0, first = 0        !< unpack: slots first .. first + n - 1
        integer :: row_r = 0, row_i = 0
        integer, allocatable :: index(:)   !< pack: the particles
        real(wp), allocatable :: shift(:, :)   !< pack: added to FIELD_SHIFTED fields (3, n)
        real(wp), pointer, contiguous :: rbuf(:, :) => null()
        integer(i8), pointer, contiguous :: ibuf(:, :) => null()
    contains
        procedure :: real1 => pack_real1, real2 => pack_real2
        procedure :: int8 => pack_int8, int4 => pack_int4
    end type pack_op_t

    !> One field's storage in transit (particles_swap): whichever of the four kinds it is.
    type :: field_slot_t
        real(wp), allocatable :: r1(:), r2(:, :)
        integer(i8), allocatable :: i8(:)
        integer, allocatable :: i4(:)
    end type field_slot_t

    !> particles_swap's three visits: STASH moves every field of the first table into
    !> slots(k), EXCHANGE swaps every field of the second with slots(k), RESTORE moves the
    !> slots into the first. Storage moves (move_alloc); nothing is copied.
    type, extends(field_op_t) :: swap_op_t
        integer :: stage = 0, k = 0
        type(field_slot_t), allocatable :: slots(:)
    contains
        procedure :: real1 => swap_real1, real2 => swap_real2
        procedure :: int8 => swap_int8, int4 => swap_int4
    end type swap_op_t
    integer, parameter :: SWAP_STASH = 1, SWAP_EXCHANGE = 2, SWAP_RESTORE = 3

    !> Records the table: every field's description, in visiting order.
    type, extends(field_op_t) :: list_op_t
        type(field_info_t), allocatable :: fields(:)
    contains
        procedure :: real1 => list_real1, real2 => list_real2
        procedure :: int8 => list_int8, int4 => list_int4
    end type list_op_t

contains

    !> Fluid particles, real or virtual (multi-resolution transition zones): they move with
    !> the SPH equations and take part in every sum of their level.
    pure elemental logical function moves_with_flow(kind)
        integer, intent(in) :: kind
        moves_with_flow = kind == KIND_FLUID .or. kind == KIND_VIRTUAL
    end function moves_with_flow

    !> The field table: one line per field (component, file name, width, where it travels).
    subroutine particles_visit(p, op)
        type(particles_t), intent(inout) :: p
        class(field_op_t), intent(inout) :: op
        integer, parameter :: snap = FIELD_SNAPSHOT, ckpt = FIELD_CHECKPOINT
        integer, parameter :: ghost = HALO_GHOST, move = HALO_MOVE
        integer :: k
        call op%real2(p%x, field_info_t('position', 3, snap + FIELD_SHIFTED + ghost + move))
        call op%real2(p%v, field_info_t('velocity', 3, snap + ghost + move))
        call op%real1(p%rho, field_info_t('density', 1, snap + ghost + move + HALO_DENSITY))
        call op%real1(p%p, field_info_t('pressure', 1, snap + ghost))
        call op%real1(p%m, field_info_t('mass', 1, snap + ghost))
        call op%real1(p%h, field_info_t('smoothing_length', 1, snap + ghost))
        call op%real1(p%e, field_info_t('energy', 1, snap + ghost + move))
        ! the rates are in checkpoints for &numerics integrator = 'verlet', whose steps start
        ! from the rates of the previous step (older checkpoints lack them)
        call op%real2(p%dvdt, field_info_t('acceleration', 3, ckpt + FIELD_OPTIONAL))
        call op%real1(p%drhodt, field_info_t('density_rate', 1, ckpt + FIELD_OPTIONAL))
        call op%real1(p%dedt, field_info_t('energy_rate', 1, ckpt + FIELD_OPTIONAL))
        call op%real2(p%x_old, field_info_t('position_old', 3, FIELD_SHIFTED))
        call op%real2(p%v_old, field_info_t('velocity_old', 3, 0))
        call op%real1(p%rho_old, field_info_t('density_old', 1, 0))
        call op%real1(p%e_old, field_info_t('energy_old', 1, 0))
        if (p%with_transport) then
            call op%real2(p%dv_transport, field_info_t('transport_offset', 3, ckpt + &
                FIELD_OPTIONAL + HALO_TRANSPORT))
            call op%real2(p%dvdt_background, field_info_t('background_acceleration', 3, 0))
        end if
        if (p%with_strain) call op%real2(p%strain, field_info_t('strain_rate', 6, &
            ghost + HALO_STRAIN))
        call op%real2(p%wall_normal, field_info_t('wall_normal', 3, ckpt + ghost))
        call op%real1(p%wall_distance, field_info_t('wall_distance', 1, ckpt + ghost))
        call op%int8(p%id, field_info_t('id', 1, snap + ghost, FIELD_INT8))
        call op%int4(p%kind, field_info_t('kind', 1, snap + ghost, FIELD_INT))
        call op%int4(p%level, field_info_t('level', 1, snap + ghost, FIELD_INT))
        call op%int4(p%solid, field_info_t('solid', 1, snap + FIELD_OPTIONAL + ghost, FIELD_INT))
        call op%int4(p%parity, field_info_t('lattice_parity', 1, ckpt + FIELD_OPTIONAL + ghost, &
            FIELD_INT))
        if (.not. allocated(p%extra)) return
        do k = 1, size(p%extra)
            call op%real2(p%extra(k)%a, p%extra(k)%info)
        end do
    end subroutine particles_visit

    !> Add a real field of `width` values per particle, travelling as `flags` say (FIELD_*,
    !> HALO_*), and return its index k: the values are p%extra(k)%a(1:width, i), zero for
    !> every particle at first. Adding a name that exists returns the existing field (a set-up
    !> may run again, e.g. on restart); its width and flags must agree.
    integer function particles_add_field(p, name, width, flags) result(k)
        type(particles_t), intent(inout) :: p
        character(len=*), intent(in) :: name
        integer, intent(in) :: width, flags
        type(extra_field_t), allocatable :: grown(:)
        integer :: j
        if (.not. allocated(p%extra)) allocate(p%extra(0))
        do k = 1, size(p%extra)
            if (trim(p%extra(k)%info%name) /= name) cycle
            if (p%extra(k)%info%width /= width .or. p%extra(k)%info%flags /= flags) &
                error stop 'particles_add_field: a field of that name exists with another shape'
            return
        end do
        allocate(grown(size(p%extra) + 1))
        do j = 1, size(p%extra)
            call move_alloc(p%extra(j)%a, grown(j)%a)
            grown(j)%info = p%extra(j)%info
        end do
        k = size(grown)
        grown(k)%info = field_info_t(name, width, flags, FIELD_REAL)
        allocate(grown(k)%a(width, max(p%capacity, 1)))
        grown(k)%a = 0.0_wp
        call move_alloc(grown, p%extra)
    end function particles_add_field

    !> Every run-time field of `source` that p lacks, added to p (zero there).
    subroutine particles_add_fields_of(p, source)
        type(particles_t), intent(inout) :: p
        type(particles_t), intent(in) :: source
        integer :: k, added
        call particles_enable(p, source%with_transport, source%with_strain)
        if (.not. allocated(source%extra)) return
        do k = 1, size(source%extra)
            added = particles_add_field(p, trim(source%extra(k)%info%name), &
                source%extra(k)%info%width, source%extra(k)%info%flags)
        end do
    end subroutine particles_add_fields_of

    !> Is a field with these flags selected by mask?
    pure logical function selected(flags, mask)
        integer, intent(in) :: flags, mask
        selected = mask == ALL_FIELDS .or. iand(flags, mask) /= 0
    end function selected

    !> The table itself: every field's description, in the order of particles_visit (with the
    !> fields p has added at run time, when p is given).
    function field_list(p) result(fields)
        type(particles_t), intent(in), optional :: p
        type(field_info_t), allocatable :: fields(:)
        type(particles_t) :: shape_only
        type(list_op_t) :: op
        integer :: k
        allocate(op%fields(0))
        ! without p: every built-in field, the optional ones included
        shape_only%with_transport = .true.
        shape_only%with_strain = .true.
        if (present(p)) then
            shape_only%with_transport = p%with_transport
            shape_only%with_strain = p%with_strain
            if (allocated(p%extra)) then
                allocate(shape_only%extra(size(p%extra)))
                do k = 1, size(p%extra)
                    shape_only%extra(k)%info = p%extra(k)%info
                end do
            end if
        end if
        call particles_visit(shape_only, op)
        call move_alloc(op%fields, fields)
    end function field_list

    !> Values per particle that a pack of p's fields with this mask produces: reals, integers.
    subroutine pack_widths(p, mask, n_real, n_int)
        type(particles_t), intent(in) :: p
        integer, intent(in) :: mask
        integer, intent(out) :: n_real, n_int
        type(field_info_t), allocatable :: fields(:)
        integer :: k
        fields = field_list(p)
        n_real = 0
        n_int = 0
        do k = 1, size(fields)
            if (.not. selected(fields(k)%flags, mask)) cycle
            if (fields(k)%storage == FIELD_REAL) then
                n_real = n_real + fields(k)%width
            else
                n_int = n_int + fields(k)%width
            end if
        end do
    end subroutine pack_widths

    !> An empty particle table for dim dimensions with room for `capacity` particles.
    subroutine particles_init(p, capacity, dim)
        type(particles_t), intent(out) :: p
        integer, intent(in) :: capacity, dim
        type(resize_op_t) :: op
        p%dim = dim
        op%capacity = max(capacity, 16)
        op%keep = 0
        call particles_visit(p, op)
        p%capacity = op%capacity
    end subroutine particles_init

    !> Enable the fields of the transport velocity (dv_transport, dvdt_background) and/or of
    !> the strain-rate viscosity (strain): from now on they are allocated (zero), grown,
    !> moved and written with the others. Enabling what is enabled changes nothing.
    subroutine particles_enable(p, transport, strain)
        type(particles_t), intent(inout) :: p
        logical, intent(in), optional :: transport, strain
        integer :: n
        n = max(p%capacity, 1)
        if (present(transport)) then
            if (transport .and. .not. p%with_transport) then
                p%with_transport = .true.
                allocate(p%dv_transport(3, n), p%dvdt_background(3, n), source=0.0_wp)
            end if
        end if
        if (present(strain)) then
            if (strain .and. .not. p%with_strain) then
                p%with_strain = .true.
                allocate(p%strain(6, n), source=0.0_wp)
            end if
        end if
    end subroutine particles_enable

    !> Release every array of the table (it can be initialised again).
    subroutine particles_free(p)
        type(particles_t), intent(inout) :: p
        type(particles_t) :: empty
        empty%dim = p%dim
        p = empty
    end subroutine particles_free

    !> Make room for at least n particles, keeping the first n_total (grows by 1.5x).
    subroutine particles_reserve(p, n)
        type(particles_t), intent(inout) :: p
        integer, intent(in) :: n
        type(resize_op_t) :: op
        if (n <= p%capacity) return
        op%capacity = max(n, p%capacity + p%capacity / 2, 16)
        op%keep = min(p%n_total, p%capacity)
        call particles_visit(p, op)
        p%capacity = op%capacity
    end subroutine particles_reserve

    !> Exchange the whole contents of two tables (every field, the counts and the capacity)
    !> without copying a value: a remesh hands the old particles' storage to its transfer and
    !> fills a fresh table, where a copy of 10^5 particles cost 20 ms, most of it in first
    !> touches of the new pages. Both tables must have the same run-time fields, in the same
    !> order (particles_add_fields_of on a fresh table gives them).
    subroutine particles_swap(a, b)
        type(particles_t), intent(inout) :: a, b
        type(swap_op_t) :: op
        integer :: counts(5), k
        logical :: same
        same = extra_count(a) == extra_count(b)
        if (same) then
            do k = 1, extra_count(a)
                if (a%extra(k)%info%name /= b%extra(k)%info%name) same = .false.
            end do
        end if
        if (a%with_transport .neqv. b%with_transport) same = .false.
        if (a%with_strain .neqv. b%with_strain) same = .false.
        if (.not. same) error stop 'particles_swap: the tables have different run-time fields'
        allocate(op%slots(64 + extra_count(a)))
        op%stage = SWAP_STASH
        call particles_visit(a, op)
        op%stage = SWAP_EXCHANGE
        op%k = 0
        call particles_visit(b, op)
        op%stage = SWAP_RESTORE
        op%k = 0
        call particles_visit(a, op)
        counts = [a%n_owned, a%n_ghost, a%n_total, a%capacity, a%dim]
        a%n_owned = b%n_owned
        a%n_ghost = b%n_ghost
        a%n_total = b%n_total
        a%capacity = b%capacity
        a%dim = b%dim
        b%n_owned = counts(1)
        b%n_ghost = counts(2)
        b%n_total = counts(3)
        b%capacity = counts(4)
        b%dim = counts(5)
    contains
        pure integer function extra_count(t)
            type(particles_t), intent(in) :: t
            extra_count = 0
            if (allocated(t%extra)) extra_count = size(t%extra)
        end function extra_count
    end subroutine particles_swap

    !> Copy particle `from` onto slot `to` within one set (every field).
    subroutine particles_copy(p, from, to)
        type(particles_t), intent(inout) :: p
        integer, intent(in) :: from, to
        type(copy_op_t) :: op
        if (from == to) return
        op%src = [from]
        op%dst = [to]
        call particles_visit(p, op)
    end subroutine particles_copy

    !> Slot k takes particle src(k), k = 1..size(src), every field (a permutation of the owned
    !> particles, or compaction). The counts are the caller's to set.
    subroutine particles_gather(p, src)
        type(particles_t), intent(inout) :: p
        integer, intent(in) :: src(:)
        type(copy_op_t) :: op
        integer :: k
        ! the identity (a set already in order) copies nothing
        do k = 1, size(src)
            if (src(k) /= k) exit
        end do
        if (k > size(src)) return
        op%src = src
        op%dst = [(k, k = 1, size(src))]
        call particles_visit(p, op)
    end subroutine particles_gather

    !> Append the particles keep(:) of `from` to the owned particles of p, every field (p has
    !> no ghosts then: n_total = n_owned). Run-time fields of p that `from` lacks are added to
    !> it first (zero); `from` has no run-time field p lacks.
    subroutine particles_append(p, from, keep)
        type(particles_t), intent(inout) :: p, from
        integer, intent(in) :: keep(:)
        integer :: first, n_real, n_int
        real(wp), allocatable :: rbuf(:, :)
        integer(i8), allocatable :: ibuf(:, :)
        first = p%n_owned + 1
        p%n_total = p%n_owned
        call particles_reserve(p, p%n_owned + size(keep))
        ! the run-time fields p has and `from` lacks (a lattice made on its own): zero there;
        ! and the optional fields `from` has, in p too, so both pack the same fields
        call particles_add_fields_of(from, p)
        call particles_enable(p, from%with_transport, from%with_strain)
        call pack_widths(from, ALL_FIELDS, n_real, n_int)
        allocate(rbuf(n_real, max(size(keep), 1)), ibuf(n_int, max(size(keep), 1)))
        call particles_pack(from, ALL_FIELDS, keep, size(keep), rbuf, ibuf)
        call particles_unpack(p, ALL_FIELDS, first, size(keep), rbuf, ibuf)
        p%n_owned = p%n_owned + size(keep)
        p%n_ghost = 0
        p%n_total = p%n_owned
    end subroutine particles_append

    !> Set every field of slots first..last to zero.
    subroutine particles_clear(p, first, last)
        type(particles_t), intent(inout) :: p
        integer, intent(in) :: first, last
        type(clear_op_t) :: op
        op%first = first
        op%last = last
        call particles_visit(p, op)
    end subroutine particles_clear

    !> Pack the fields selected by mask of particles index(1:n) into rbuf(:, 1:n) (reals) and
    !> ibuf(:, 1:n) (integers). shift(:, k), when given, is added to the positions.
    subroutine particles_pack(p, mask, index, n, rbuf, ibuf, shift)
        type(particles_t), intent(inout) :: p
        integer, intent(in) :: mask, n
        integer, intent(in) :: index(:)
        real(wp), intent(inout), target, contiguous :: rbuf(:, :)
        integer(i8), intent(inout), target, contiguous :: ibuf(:, :)
        real(wp), intent(in), optional :: shift(:, :)
        type(pack_op_t) :: op
        op%mask = mask
        op%n = n
        op%index = index(1:n)
        if (present(shift)) op%shift = shift(:, 1:n)
        op%rbuf => rbuf
        op%ibuf => ibuf
        call particles_visit(p, op)
    end subroutine particles_pack

    !> The inverse of particles_pack: columns 1..n become slots first..first+n-1.
    subroutine particles_unpack(p, mask, first, n, rbuf, ibuf)
        type(particles_t), intent(inout) :: p
        integer, intent(in) :: mask, first, n
        real(wp), intent(inout), target, contiguous :: rbuf(:, :)
        integer(i8), intent(inout), target, contiguous :: ibuf(:, :)
        type(pack_op_t) :: op
        op%mask = mask
        op%unpack = .true.
        op%first = first
        op%n = n
        op%rbuf => rbuf
        op%ibuf => ibuf
        call particles_visit(p, op)
    end subroutine particles_unpack

    ! ---- resize ----

    subroutine resize_real1(op, a, info)
        class(resize_op_t), intent(inout) :: op
        real(wp), allocatable, intent(inout) :: a(:)
        type(field_info_t), intent(in) :: info
        real(wp), allocatable :: b(:)
        allocate(b(op%capacity))
        b = 0.0_wp   ! defined values everywhere: unused slots must not trip FP traps
        if (op%keep > 0) b(1:op%keep) = a(1:op%keep)
        call move_alloc(b, a)
    end subroutine resize_real1

    subroutine resize_real2(op, a, info)
        class(resize_op_t), intent(inout) :: op
        real(wp), allocatable, intent(inout) :: a(:, :)
        type(field_info_t), intent(in) :: info
        real(wp), allocatable :: b(:, :)
        allocate(b(info%width, op%capacity))
        b = 0.0_wp
        if (op%keep > 0) b(:, 1:op%keep) = a(:, 1:op%keep)
        call move_alloc(b, a)
    end subroutine resize_real2

    subroutine resize_int8(op, a, info)
        class(resize_op_t), intent(inout) :: op
        integer(i8), allocatable, intent(inout) :: a(:)
        type(field_info_t), intent(in) :: info
        integer(i8), allocatable :: b(:)
        allocate(b(op%capacity))
        b = 0
        if (op%keep > 0) b(1:op%keep) = a(1:op%keep)
        call move_alloc(b, a)
    end subroutine resize_int8

    subroutine resize_int4(op, a, info)
        class(resize_op_t), intent(inout) :: op
        integer, allocatable, intent(inout) :: a(:)
        type(field_info_t), intent(in) :: info
        integer, allocatable :: b(:)
        allocate(b(op%capacity))
        b = 0
        if (op%keep > 0) b(1:op%keep) = a(1:op%keep)
        call move_alloc(b, a)
    end subroutine resize_int4

    ! ---- swap ----

    subroutine swap_real1(op, a, info)
        class(swap_op_t), intent(inout) :: op
        real(wp), allocatable, intent(inout) :: a(:)
        type(field_info_t), intent(in) :: info
        real(wp), allocatable :: t(:)
        op%k = op%k + 1
        select case (op%stage)
        case (SWAP_STASH)
            call move_alloc(a, op%slots(op%k)%r1)
        case (SWAP_EXCHANGE)
            call move_alloc(a, t)
            call move_alloc(op%slots(op%k)%r1, a)
            call move_alloc(t, op%slots(op%k)%r1)
        case default
            call move_alloc(op%slots(op%k)%r1, a)
        end select
    end subroutine swap_real1

    subroutine swap_real2(op, a, info)
        class(swap_op_t), intent(inout) :: op
        real(wp), allocatable, intent(inout) :: a(:, :)
        type(field_info_t), intent(in) :: info
        real(wp), allocatable :: t(:, :)
        op%k = op%k + 1
        select case (op%stage)
        case (SWAP_STASH)
            call move_alloc(a, op%slots(op%k)%r2)
        case (SWAP_EXCHANGE)
            call move_alloc(a, t)
            call move_alloc(op%slots(op%k)%r2, a)
            call move_alloc(t, op%slots(op%k)%r2)
        case default
            call move_alloc(op%slots(op%k)%r2, a)
        end select
    end subroutine swap_real2

    subroutine swap_int8(op, a, info)
        class(swap_op_t), intent(inout) :: op
        integer(i8), allocatable, intent(inout) :: a(:)
        type(field_info_t), intent(in) :: info
        integer(i8), allocatable :: t(:)
        op%k = op%k + 1
        select case (op%stage)
        case (SWAP_STASH)
            call move_alloc(a, op%slots(op%k)%i8)
        case (SWAP_EXCHANGE)
            call move_alloc(a, t)
            call move_alloc(op%slots(op%k)%i8, a)
            call move_alloc(t, op%slots(op%k)%i8)
        case default
            call move_alloc(op%slots(op%k)%i8, a)
        end select
    end subroutine swap_int8

    subroutine swap_int4(op, a, info)
        class(swap_op_t), intent(inout) :: op
        integer, allocatable, intent(inout) :: a(:)
        type(field_info_t), intent(in) :: info
        integer, allocatable :: t(:)
        op%k = op%k + 1
        select case (op%stage)
        case (SWAP_STASH)
            call move_alloc(a, op%slots(op%k)%i4)
        case (SWAP_EXCHANGE)
            call move_alloc(a, t)
            call move_alloc(op%slots(op%k)%i4, a)
            call move_alloc(t, op%slots(op%k)%i4)
        case default
            call move_alloc(op%slots(op%k)%i4, a)
        end select
    end subroutine swap_int4

    ! ---- copy ----

    subroutine copy_real1(op, a, info)
        class(copy_op_t), intent(inout) :: op
        real(wp), allocatable, intent(inout) :: a(:)
        type(field_info_t), intent(in) :: info
        a(op%dst) = a(op%src)
    end subroutine copy_real1

    subroutine copy_real2(op, a, info)
        class(copy_op_t), intent(inout) :: op
        real(wp), allocatable, intent(inout) :: a(:, :)
        type(field_info_t), intent(in) :: info
        a(:, op%dst) = a(:, op%src)
    end subroutine copy_real2

    subroutine copy_int8(op, a, info)
        class(copy_op_t), intent(inout) :: op
        integer(i8), allocatable, intent(inout) :: a(:)
        type(field_info_t), intent(in) :: info
        a(op%dst) = a(op%src)
    end subroutine copy_int8

    subroutine copy_int4(op, a, info)
        class(copy_op_t), intent(inout) :: op
        integer, allocatable, intent(inout) :: a(:)
        type(field_info_t), intent(in) :: info
        a(op%dst) = a(op%src)
    end subroutine copy_int4

    ! ---- clear ----

    subroutine clear_real1(op, a, info)
        class(clear_op_t), intent(inout) :: op
        real(wp), allocatable, intent(inout) :: a(:)
        type(field_info_t), intent(in) :: info
        a(op%first:op%last) = 0.0_wp
    end subroutine clear_real1

    subroutine clear_real2(op, a, info)
        class(clear_op_t), intent(inout) :: op
        real(wp), allocatable, intent(inout) :: a(:, :)
        type(field_info_t), intent(in) :: info
        a(:, op%first:op%last) = 0.0_wp
    end subroutine clear_real2

    subroutine clear_int8(op, a, info)
        class(clear_op_t), intent(inout) :: op
        integer(i8), allocatable, intent(inout) :: a(:)
        type(field_info_t), intent(in) :: info
        a(op%first:op%last) = 0
    end subroutine clear_int8

    subroutine clear_int4(op, a, info)
        class(clear_op_t), intent(inout) :: op
        integer, allocatable, intent(inout) :: a(:)
        type(field_info_t), intent(in) :: info
        a(op%first:op%last) = 0
    end subroutine clear_int4

    ! ---- pack / unpack ----

    subroutine pack_real1(op, a, info)
        class(pack_op_t), intent(inout) :: op
        real(wp), allocatable, intent(inout) :: a(:)
        type(field_info_t), intent(in) :: info
        integer :: r
        if (.not. selected(info%flags, op%mask)) return
        r = op%row_r + 1
        if (op%unpack) then
            a(op%first:op%first + op%n - 1) = op%rbuf(r, 1:op%n)
        else
            op%rbuf(r, 1:op%n) = a(op%index)
        end if
        op%row_r = r
    end subroutine pack_real1

    subroutine pack_real2(op, a, info)
        class(pack_op_t), intent(inout) :: op
        real(wp), allocatable, intent(inout) :: a(:, :)
        type(field_info_t), intent(in) :: info
        integer :: r0, r1, k
        if (.not. selected(info%flags, op%mask)) return
        r0 = op%row_r + 1
        r1 = op%row_r + info%width
        if (op%unpack) then
            a(:, op%first:op%first + op%n - 1) = op%rbuf(r0:r1, 1:op%n)
        else
            op%rbuf(r0:r1, 1:op%n) = a(:, op%index)
            if (allocated(op%shift) .and. iand(info%flags, FIELD_SHIFTED) /= 0) then
                do k = 1, op%n
                    op%rbuf(r0:r1, k) = op%rbuf(r0:r1, k) + op%shift(:, k)
                end do
            end if
        end if
        op%row_r = r1
    end subroutine pack_real2

    subroutine pack_int8(op, a, info)
        class(pack_op_t), intent(inout) :: op
        integer(i8), allocatable, intent(inout) :: a(:)
        type(field_info_t), intent(in) :: info
        integer :: r
        if (.not. selected(info%flags, op%mask)) return
        r = op%row_i + 1
        if (op%unpack) then
            a(op%first:op%first + op%n - 1) = op%ibuf(r, 1:op%n)
        else
            op%ibuf(r, 1:op%n) = a(op%index)
        end if
        op%row_i = r
    end subroutine pack_int8

    subroutine pack_int4(op, a, info)
        class(pack_op_t), intent(inout) :: op
        integer, allocatable, intent(inout) :: a(:)
        type(field_info_t), intent(in) :: info
        integer :: r
        if (.not. selected(info%flags, op%mask)) return
        r = op%row_i + 1
        if (op%unpack) then
            a(op%first:op%first + op%n - 1) = int(op%ibuf(r, 1:op%n))
        else
            op%ibuf(r, 1:op%n) = int(a(op%index), i8)
        end if
        op%row_i = r
    end subroutine pack_int4

    ! ---- list ----

    subroutine list_real1(op, a, info)
        class(list_op_t), intent(inout) :: op
        real(wp), allocatable, intent(inout) :: a(:)
        type(field_info_t), intent(in) :: info
        op%fields = [op%fields, info]
    end subroutine list_real1

    subroutine list_real2(op, a, info)
        class(list_op_t), intent(inout) :: op
        real(wp), allocatable, intent(inout) :: a(:, :)
        type(field_info_t), intent(in) :: info
        op%fields = [op%fields, info]
    end subroutine list_real2

    subroutine list_int8(op, a, info)
        class(list_op_t), intent(inout) :: op
        integer(i8), allocatable, intent(inout) :: a(:)
        type(field_info_t), intent(in) :: info
        op%fields = [op%fields, info]
    end subroutine list_int8

    subroutine list_int4(op, a, info)
        class(list_op_t), intent(inout) :: op
        integer, allocatable, intent(inout) :: a(:)
        type(field_info_t), intent(in) :: info
        op%fields = [op%fields, info]
    end subroutine list_int4
end module sph_particles
