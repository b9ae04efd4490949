!> Initial particles from a user's HDF5 file (&domain initial_particles): the datasets of the
!> snapshot schema under /particles, of which only `position` is required (doc/output.md,
!> "Starting from your own particles"). The rows are shared out evenly over the ranks (as a
!> checkpoint read on another rank count); the caller partitions and migrates.
!>
!> What a file lacks is made as the lattice set-up makes it: velocity 0 (wall particles:
!> their solid's velocity), kind fluid, mass rho0 dx^dim, density rho0, id 1..N in file
!> order, energy 0, level 0; wall particles without solid/wall_normal/wall_distance get them
!> from the solid they lie in (sph_walls wall_site). Pressure always follows from the EOS and
!> the smoothing length from the kernel. Unlike snapshots, a file needs no root attributes;
!> one written by sphremesh (it has `format`) must carry write_complete, and an attribute
!> `dimension`, if present, must match &domain. Every problem found is reported in one
!> message naming the file; the status is the same on every rank. Collective on env%comm.
module sph_particle_file
    use sph_kinds, only: wp, i4, i8
    use sph_config, only: config_t
    use sph_mpi_env, only: mpi_env_t, agreed_status, global_sum
    use sph_logger, only: int_text, log_warn
    use sph_particles, only: particles_t, particles_reserve, particles_clear, particles_gather, &
        KIND_FLUID, KIND_WALL
    use sph_physics, only: physics_t, WALLS_MIRROR
    use sph_health, only: IN_SOLID_SLACK
    use sph_solids, only: solids_t, solid_velocity, solid_distance
    use sph_refine, only: largest_remesh_id
    use sph_walls, only: wall_site
    use sph_eos, only: eos_pressure
    use sph_initial, only: lattice_mass_factor
    use sph_global_ids, only: find_duplicate_ids
    use sph_read_checks, only: append_problems, fluid_too_deep, LARGEST_VALUE
    use sph_hdf5, only: h5_file_t, h5_open_read, h5_close, h5_read_rows, h5_dataset_rows, &
        h5_read_attribute, h5_attribute_exists
    use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
    implicit none
    private
    public :: read_initial_particles

    ! the per-particle problems, counted over all ranks and shown with a first example
    integer, parameter :: n_problems = 13
    integer, parameter :: PROBLEM_ID_LIMIT = 13
    character(len=*), parameter :: problem_text(n_problems) = [character(len=120) :: &
        'particles of a kind other than 0 (fluid) or 1 (wall)', &
        'particles not finite (position, velocity, density, mass, energy or wall data)', &
        'fluid particles outside the box', &
        'fluid particles inside a solid (deeper than the health check takes, 0.2 h)', &
        'wall particles outside every solid', &
        'particles with mass <= 0 or density <= 0', &
        'particles with id <= 0', &
        'particles with z /= 0 in a 2D run (&domain dimension = 2)', &
        'particles with a value above 1e150 in magnitude (position, velocity, density, ' // &
        'mass, energy or wall data)', &
        'particles with a level other than 0 (a run from a file has one level)', &
        'fluid particles with a solid other than 0', &
        'wall particles whose solid (1..number of walls and bodies) is not one they lie in', &
        'particles with an id above the largest a remesh can encode']

    !> The optional datasets: name and width (0: one value per row).
    character(len=16), parameter :: optional_names(10) = [character(len=16) :: 'velocity', &
        'density', 'mass', 'energy', 'id', 'kind', 'level', 'solid', 'wall_normal', &
        'wall_distance']
    integer, parameter :: optional_widths(10) = [3, 0, 0, 0, 0, 0, 0, 0, 3, 0]
    !> whether the dataset holds integers (id, kind, level, solid)
    logical, parameter :: integral(10) = [.false., .false., .false., .false., .true., &
        .true., .true., .true., .false., .false.]

contains

    !> Read `path` into p (owned particles, rows shared evenly over the ranks) or return
    !> stat /= 0 (the same on every rank) with a message naming the file and every problem.
    subroutine read_initial_particles(env, cfg, phys, solids, path, p, stat, errmsg)
        type(mpi_env_t), intent(in) :: env
        type(config_t), intent(in) :: cfg
        type(physics_t), intent(in) :: phys
        type(solids_t), intent(in) :: solids
        character(len=*), intent(in) :: path
        type(particles_t), intent(inout) :: p
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: errmsg
        type(h5_file_t) :: file
        integer :: dim, n, width, my_stat
        integer(i8) :: n_rows, share, extra, offset, duplicate, n_duplicates, n_deep
        integer :: k
        logical :: have(size(optional_names))
        logical, allocatable :: too_deep(:)
        character(len=:), allocatable :: message

        dim = cfg%domain%dimension
        call h5_open_read(env, path, file, my_stat, message)
        stat = agreed_status(env, my_stat)
        if (stat /= 0) then
            errmsg = "cannot open the initial particle file '" // path // "' (&domain " // &
                "initial_particles): not there or not HDF5"
            if (my_stat == 0) call h5_close(file)
            return
        end if

        ! the layout: the same on every rank, checked on every rank
        message = ''
        call check_layout(file, dim, n_rows, width, have, message)
        stat = agreed_status(env, merge(1, 0, len(message) > 0))
        if (stat /= 0) then
            call h5_close(file)
            if (len(message) == 0) message = ' refused on another rank;'
            errmsg = "the initial particle file '" // path // "' is refused:" // &
                message(1:len(message) - 1)
            return
        end if

        ! rows shared out evenly
        share = n_rows / env%nranks
        extra = mod(n_rows, int(env%nranks, i8))
        n = int(share + merge(1_i8, 0_i8, env%rank < extra))
        offset = env%rank * share + min(int(env%rank, i8), extra)
        p%dim = dim
        call particles_reserve(p, max(n, 1))
        call particles_clear(p, 1, max(n, 1))
        call read_fields(file, n, offset, width, have, p)
        call h5_close(file, my_stat)
        p%n_owned = n
        p%n_ghost = 0
        p%n_total = n
        if (agreed_status(env, my_stat) /= 0) then
            stat = 1
            errmsg = "closing the initial particle file '" // path // "' failed"
            return
        end if

        call complete_and_check(env, cfg, phys, solids, have, offset, p, message, too_deep)
        call find_duplicate_ids(env, p%id, n, n_duplicates, duplicate)
        if (n_duplicates > 0) message = message // '; ' // int_text(n_duplicates) // &
            ' ids given more than once (the smallest: ' // int_text(duplicate) // ')'
        stat = merge(1, 0, len(message) > 0)   ! the same on every rank (global counts)
        errmsg = ''
        if (stat /= 0) errmsg = "the initial particle file '" // path // "' is refused: " // &
            message(3:)
        if (stat /= 0) return
        n_deep = global_sum(env, int(count(too_deep), i8))
        if (n_deep > 0) then
            call particles_gather(p, pack([(k, k = 1, n)], .not. too_deep))
            p%n_owned = count(.not. too_deep)
            p%n_total = p%n_owned
            call log_warn("initial particles: dropped " // int_text(n_deep) // ' wall ' // &
                'particles of ' // path // ' deeper inside their solid than a kernel ' // &
                'support and dx (they touch no fluid: layers of a run with a wider kernel?)')
        end if
    end subroutine read_initial_particles

    !> Root attributes and dataset shapes; appends '; ...' to message for every problem.
    subroutine check_layout(file, dim, n_rows, width, have, message)
        type(h5_file_t), intent(in) :: file
        integer, intent(in) :: dim
        integer(i8), intent(out) :: n_rows
        integer, intent(out) :: width
        logical, intent(out) :: have(:)
        character(len=:), allocatable, intent(inout) :: message
        integer(i4) :: value
        integer :: k, w, status
        integer(i8) :: rows
        logical :: floats
        if (h5_attribute_exists(file, 'format')) then
            ! written by sphremesh: whole only with the marker, as restarts demand
            value = 0
            if (h5_attribute_exists(file, 'write_complete')) &
                call h5_read_attribute(file, 'write_complete', value, status)
            if (value /= 1) message = message // ' it is incomplete (no write_complete ' // &
                'marker);'
        end if
        if (h5_attribute_exists(file, 'dimension')) then
            call h5_read_attribute(file, 'dimension', value, status)
            ! (one of another type, 2.0 or '2', read as 0: the message said 'dimension is 0')
            if (status /= 0) then
                message = message // ' its root attribute dimension is not an integer ' // &
                    '(2 or 3, as &domain dimension);'
            else if (value /= dim) then
                message = message // ' its root attribute dimension is ' // &
                    int_text(int(value, i8)) // ', &domain dimension is ' // &
                    int_text(int(dim, i8)) // ';'
            end if
        end if
        n_rows = h5_dataset_rows(file, 'particles/position', width, floats)
        have = .false.
        if (n_rows < 0 .or. .not. (width == 3 .or. width == dim) .or. .not. floats) then
            message = message // ' the dataset /particles/position (N x 3 float64) is ' // &
                'missing, of another shape or not floating point;'
            n_rows = 0
            return
        end if
        if (n_rows == 0) message = message // ' it holds no particle (/particles/position ' // &
            'has 0 rows);'
        do k = 1, size(optional_names)
            rows = h5_dataset_rows(file, 'particles/' // trim(optional_names(k)), w, floats)
            if (rows < 0) cycle
            if (rows /= n_rows .or. (w /= optional_widths(k) .and. .not. &
                    (optional_widths(k) == 3 .and. w == dim))) then
                message = message // ' /particles/' // trim(optional_names(k)) // ' has ' // &
                    int_text(rows) // ' rows of width ' // int_text(int(max(w, 1), i8)) // &
                    ', expected ' // int_text(n_rows) // ' of width ' // &
                    int_text(int(max(optional_widths(k), 1), i8)) // ';'
            else if (floats .neqv. .not. integral(k)) then
                ! (HDF5 would convert it: floats rounded, a NaN trapping where floating-point
                ! exceptions do; positions or masses written as integers truncated)
                message = message // ' /particles/' // trim(optional_names(k)) // ' holds ' // &
                    merge('floating-point values where integers belong;', &
                          'integers where floating-point values belong;', integral(k))
            else
                have(k) = .true.
            end if
        end do
    end subroutine check_layout

    !> Rows offset+1 .. offset+n of the datasets present (collective); the rest is left zero.
    subroutine read_fields(file, n, offset, width, have, p)
        type(h5_file_t), intent(in) :: file
        integer, intent(in) :: n, width
        integer(i8), intent(in) :: offset
        logical, intent(in) :: have(:)
        type(particles_t), intent(inout) :: p
        real(wp), allocatable :: vectors(:, :), values(:)
        integer(i8), allocatable :: ids(:)
        integer(i4), allocatable :: ints(:)
        integer :: k, w
        allocate(values(max(n, 1)), ids(max(n, 1)), ints(max(n, 1)))
        allocate(vectors(width, max(n, 1)))
        call h5_read_rows(file, 'particles/position', vectors, n, offset)
        p%x(1:width, 1:n) = vectors(:, 1:n)
        do k = 1, size(optional_names)
            if (.not. have(k)) cycle
            associate (name => 'particles/' // trim(optional_names(k)))
                select case (trim(optional_names(k)))
                case ('velocity', 'wall_normal')
                    if (h5_dataset_rows(file, name, w) < 0) cycle
                    call read_vectors(name, w)
                    if (optional_names(k) == 'velocity') p%v(1:w, 1:n) = vectors(1:w, 1:n)
                    if (optional_names(k) == 'wall_normal') &
                        p%wall_normal(1:w, 1:n) = vectors(1:w, 1:n)
                case ('density', 'mass', 'energy', 'wall_distance')
                    call h5_read_rows(file, name, values, n, offset)
                    if (optional_names(k) == 'density') p%rho(1:n) = values(1:n)
                    if (optional_names(k) == 'mass') p%m(1:n) = values(1:n)
                    if (optional_names(k) == 'energy') p%e(1:n) = values(1:n)
                    if (optional_names(k) == 'wall_distance') p%wall_distance(1:n) = values(1:n)
                case ('id')
                    call h5_read_rows(file, name, ids, n, offset)
                    p%id(1:n) = ids(1:n)
                case default   ! kind, level, solid
                    call h5_read_rows(file, name, ints, n, offset)
                    if (optional_names(k) == 'kind') p%kind(1:n) = ints(1:n)
                    if (optional_names(k) == 'level') p%level(1:n) = ints(1:n)
                    if (optional_names(k) == 'solid') p%solid(1:n) = ints(1:n)
                end select
            end associate
        end do
    contains
        subroutine read_vectors(name, w)
            character(len=*), intent(in) :: name
            integer, intent(in) :: w
            deallocate(vectors)
            allocate(vectors(w, max(n, 1)))
            call h5_read_rows(file, name, vectors, n, offset)
        end subroutine read_vectors
    end subroutine read_fields

    !> Defaults for what the file lacks, the derived fields, and the checks of every
    !> particle; message gets '; <count> particles <problem> (first: ...)' per problem
    !> (counts over all ranks, the example from the lowest rank that has one: collective).
    subroutine complete_and_check(env, cfg, phys, solids, have, offset, p, message, too_deep)
        type(mpi_env_t), intent(in) :: env
        type(config_t), intent(in) :: cfg
        type(physics_t), intent(in) :: phys
        type(solids_t), intent(in) :: solids
        logical, intent(in) :: have(:)
        integer(i8), intent(in) :: offset
        type(particles_t), intent(inout) :: p
        character(len=:), allocatable, intent(inout) :: message
        !> the wall particles deeper inside their solid than a kernel support and dx
        logical, allocatable, intent(out) :: too_deep(:)
        integer(i8) :: counts(n_problems), largest_id
        integer(i8), allocatable :: walls_of(:)
        character(len=160) :: example(n_problems)
        character(len=len(problem_text) + 40) :: texts(n_problems)
        integer :: i, axis, solid, dim, n_solids
        real(wp) :: normal(3), distance, lo, hi, slack, mass_factor
        logical :: site, outside

        dim = cfg%domain%dimension
        counts = 0
        example = ''
        n_solids = 0
        if (allocated(solids%list)) n_solids = size(solids%list)
        allocate(walls_of(max(n_solids, 1)))
        walls_of = 0
        largest_id = largest_remesh_id(n_solids)
        allocate(too_deep(p%n_owned))
        too_deep = .false.
        slack = IN_SOLID_SLACK * phys%kernel%h
        ! masses as the lattice's (sph_initial), so a file of its positions repeats its run
        mass_factor = lattice_mass_factor(cfg, phys)
        do i = 1, p%n_owned
            if (.not. have(5)) p%id(i) = offset + i
            if (.not. have(2)) p%rho(i) = cfg%fluid%rho0
            if (.not. have(3)) p%m(i) = cfg%fluid%rho0 * cfg%domain%dx**dim * mass_factor
            if (.not. have(6)) p%kind(i) = KIND_FLUID
            if (p%kind(i) /= KIND_FLUID .and. p%kind(i) /= KIND_WALL) call problem(1)
            ! (the wall data of a file that has them: a non-finite normal trapped in the
            ! wall terms, and stopped a Release run at its first step as an instability)
            if (.not. (all(ieee_is_finite(p%x(:, i))) .and. all(ieee_is_finite(p%v(:, i))) &
                       .and. ieee_is_finite(p%rho(i)) .and. ieee_is_finite(p%m(i)) .and. &
                       ieee_is_finite(p%e(i)) .and. all(ieee_is_finite(p%wall_normal(:, i))) &
                       .and. ieee_is_finite(p%wall_distance(i)))) then
                ! (the checks below compare: with a NaN that traps where floating-point
                ! exceptions do)
                call problem(2)
                cycle
            end if
            if (max(maxval(abs(p%x(:, i))), maxval(abs(p%v(:, i))), abs(p%rho(i)), &
                abs(p%m(i)), abs(p%e(i)), maxval(abs(p%wall_normal(:, i))), &
                abs(p%wall_distance(i))) > LARGEST_VALUE) then
                call problem(9)
                cycle
            end if
            ! (a level indexed the per-level data out of bounds)
            if (p%level(i) /= 0) call problem(10)
            if (p%id(i) > largest_id) call problem(PROBLEM_ID_LIMIT)
            if (dim == 2 .and. p%x(3, i) /= 0.0_wp) call problem(8)
            if (p%kind(i) == KIND_FLUID) then
                ! within the health check's slack of a wall, as a run's own snapshot or
                ! checkpoint may hold it (a restart takes those: so does a file start)
                do axis = 1, dim
                    lo = cfg%domain%box_lo(axis)
                    hi = cfg%domain%box_hi(axis)
                    if (cfg%domain%is_periodic(axis)) then
                        outside = p%x(axis, i) < lo .or. p%x(axis, i) >= hi
                    else
                        outside = p%x(axis, i) < lo - slack .or. p%x(axis, i) > hi + slack
                    end if
                    if (outside) then
                        call problem(3)
                        exit
                    end if
                end do
                if (fluid_too_deep(solids, p%x(:, i), slack)) call problem(4)
                if (p%solid(i) /= 0) call problem(11)
            else if (p%kind(i) == KIND_WALL) then
                call wall_site(solids, p%x(:, i), cfg%domain%dx, site, solid, normal, distance)
                if (.not. site) then
                    call problem(5)
                else
                    ! a solid given must be one the particle lies in (its forces go there;
                    ! one beyond the solids wrote past the force sums)
                    if (have(8)) then
                        if (.not. lies_in(p%solid(i))) call problem(12)
                    else
                        p%solid(i) = solid
                    end if
                    ! deeper, it touches no fluid (a snapshot of a run with a wider kernel
                    ! has such layers): dropped below; far away it stretched the cell grid
                    ! until its cell count overflowed (a wall particle 1e6 m down)
                    too_deep(i) = distance > phys%kernel%support + cfg%domain%dx
                    if (.not. have(9)) p%wall_normal(:, i) = normal
                    if (.not. have(10)) p%wall_distance(i) = distance
                    if (.not. have(1)) p%v(:, i) = solid_velocity(solids%list(solid), p%x(:, i))
                    if (lies_in(p%solid(i)) .and. .not. too_deep(i)) &
                        walls_of(p%solid(i)) = walls_of(p%solid(i)) + 1
                end if
            end if
            if (.not. (p%m(i) > 0.0_wp .and. p%rho(i) > 0.0_wp)) call problem(6)
            if (p%id(i) <= 0) call problem(7)
            p%p(i) = eos_pressure(phys%eos, p%rho(i), phys%rho0, phys%c, phys%gamma) + &
                phys%background_pressure
            p%h(i) = phys%kernel%h
            ! a fluid particle's lattice parity as the lattice gives it at the nearest site
            ! (sph_initial: a bit for an odd index along each axis), so that a run from a
            ! file of the lattice is the lattice run in its checkpoints too (all 0 before:
            ! fz43); its multi-resolution refinement takes the same particles
            p%parity(i) = 0
            if (p%kind(i) == KIND_FLUID) then
                do axis = 1, cfg%domain%dimension
                    if (modulo(nint((p%x(axis, i) - cfg%domain%box_lo(axis)) / cfg%domain%dx + &
                        0.5_wp), 2) == 1) p%parity(i) = ibset(p%parity(i), axis - 1)
                end do
            end if
            p%x_old(:, i) = p%x(:, i)
            p%v_old(:, i) = p%v(:, i)
            p%rho_old(i) = p%rho(i)
            p%e_old(i) = p%e(i)
        end do
        texts = problem_text
        write(texts(PROBLEM_ID_LIMIT), '(a,i0,a,i0,a)') trim(problem_text(PROBLEM_ID_LIMIT)) // &
            ' with the input''s ', n_solids, ' walls and bodies (', largest_id, ')'
        call append_problems(env, counts, example, texts, message)
        ! every wall and body of the input needs its wall particles: a file without those of
        ! one ran without that solid, and its force was reported as 0 (not said when wall
        ! particles were refused above, by their values or labels: their counts by solid
        ! mean nothing then)
        ! (mirror walls have none: their images are made at each step)
        if (n_solids > 0 .and. phys%walls /= WALLS_MIRROR .and. &
            global_sum(env, counts(2) + counts(9) + counts(12)) == 0) then
            walls_of = global_sum(env, walls_of)
            if (any(walls_of(1:n_solids) == 0)) then
                message = message // '; no wall particles of'
                do solid = 1, n_solids
                    if (walls_of(solid) == 0) message = message // ' ' // &
                        trim(solids%list(solid)%name) // ','
                end do
                message = message(1:len(message) - 1) // ' (each wall and body of the ' // &
                    'input needs its wall particles in the file)'
            end if
        end if

    contains

        !> Whether solid s is one of the input's and holds the wall particle i.
        logical function lies_in(s)
            integer, intent(in) :: s
            lies_in = s >= 1 .and. s <= n_solids
            if (lies_in) lies_in = solid_distance(solids%list(s), p%x(:, i)) <= &
                1.0e-6_wp * cfg%domain%dx
        end function lies_in

        subroutine problem(which)
            integer, intent(in) :: which
            counts(which) = counts(which) + 1
            if (counts(which) > 1) return
            write(example(which), '(a,i0,a,3es14.6,a,i0)') 'id ', p%id(i), ' at', p%x(:, i), &
                ' m, kind ', p%kind(i)
        end subroutine problem
    end subroutine complete_and_check


end module sph_particle_file
