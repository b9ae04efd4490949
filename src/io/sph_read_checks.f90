!> Checks of the particles read from a checkpoint or snapshot that a run continues from
!> (--restart) or that --remesh remeshes: values no run writes, which would otherwise stop
!> the run later with a floating-point trap, an index out of range or a hang (a NaN
!> position, a zero density, a kind or solid number out of range, an id given twice: a file
!> edited or damaged outside sphremesh). A file written by sphremesh passes (virtual
!> particles' ids are hashes: only fluid and wall ids are checked). Collective: every rank
!> checks its own rows, the counts are summed and the message, the same on every rank, shows
!> the first example of each problem (from the lowest rank that has one).
module sph_read_checks
    use sph_kinds, only: wp, i8
    use sph_mpi_env, only: mpi_env_t, global_sum, global_max, broadcast_text
    use sph_logger, only: int_text
    use sph_particles, only: particles_t, KIND_FLUID, KIND_WALL, KIND_VIRTUAL
    use sph_global_ids, only: find_duplicate_ids
    use sph_solids, only: solids_t, solid_distance
    use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
    implicit none
    private
    public :: check_read_particles, check_fluid_outside_solids, fluid_too_deep
    public :: append_problems, LARGEST_VALUE

    integer, parameter :: N_PROBLEMS = 9
    !> The largest magnitude taken: squares and products of a few such values stay finite
    !> (a velocity of 1e300 m/s overflowed in the first time step limit)
    real(wp), parameter :: LARGEST_VALUE = 1.0e150_wp
    character(len=*), parameter :: PROBLEM_TEXT(N_PROBLEMS) = [character(len=128) :: &
        'particles of a kind other than 0 (fluid), 1 (wall) or 2 (virtual)', &
        'particles not finite (position, velocity, density, mass or energy)', &
        'fluid or wall particles with mass <= 0 or density <= 0', &
        'fluid or wall particles with id <= 0', &
        'particles of a level outside the input''s levels', &
        'wall particles of a solid the input does not have', &
        'particles with a value above 1e150 in magnitude (position, velocity, density, ' // &
        'mass or energy)', &
        'particles whose smoothing length is not finite, not > 0 or above 1e150', &
        'particles whose stored rates or wall data (acceleration, density_rate, ' // &
        'energy_rate, wall_normal, wall_distance) are not finite or above 1e150']

contains

    !> stat /= 0 and errmsg (naming path and every problem) when the owned particles of p
    !> hold a problem above; n_levels and n_solids: the levels and solids of the input the
    !> run continues with.
    subroutine check_read_particles(env, p, n_levels, n_solids, path, stat, errmsg)
        type(mpi_env_t), intent(in) :: env
        type(particles_t), intent(in) :: p
        integer, intent(in) :: n_levels, n_solids
        character(len=*), intent(in) :: path
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: errmsg
        integer(i8) :: counts(N_PROBLEMS), n_duplicates, duplicate
        character(len=160) :: example(N_PROBLEMS)
        character(len=:), allocatable :: message
        integer :: i
        logical :: real_kind
        integer(i8), allocatable :: real_ids(:)

        counts = 0
        example = ''
        do i = 1, p%n_owned
            real_kind = p%kind(i) == KIND_FLUID .or. p%kind(i) == KIND_WALL
            if (.not. (real_kind .or. p%kind(i) == KIND_VIRTUAL)) call problem(1)
            ! (no comparison with a NaN: it traps where floating-point exceptions do)
            if (.not. (all(ieee_is_finite(p%x(:, i))) .and. all(ieee_is_finite(p%v(:, i))) &
                       .and. ieee_is_finite(p%rho(i)) .and. ieee_is_finite(p%m(i)) .and. &
                       ieee_is_finite(p%e(i)))) then
                call problem(2)
            else
                if (any(abs(p%x(:, i)) > LARGEST_VALUE) .or. any(abs(p%v(:, i)) > &
                    LARGEST_VALUE) .or. max(abs(p%rho(i)), abs(p%m(i)), abs(p%e(i))) > &
                    LARGEST_VALUE) call problem(7)
                if (real_kind .and. .not. (p%m(i) > 0.0_wp .and. p%rho(i) > 0.0_wp)) &
                    call problem(3)
            end if
            ! (a checkpoint's: a Verlet step starts from the rates)
            if (.not. usable([p%dvdt(:, i), p%drhodt(i), p%dedt(i), p%wall_normal(:, i), &
                p%wall_distance(i)])) call problem(9)
            ! (the health check compares positions with it)
            if (.not. ieee_is_finite(p%h(i))) then
                call problem(8)
            else if (.not. (p%h(i) > 0.0_wp .and. p%h(i) <= LARGEST_VALUE)) then
                call problem(8)
            end if
            ! (virtual particles carry hashed ids, of either sign, that no real one has)
            if (real_kind .and. p%id(i) <= 0) call problem(4)
            if (p%level(i) < 0 .or. p%level(i) >= n_levels) call problem(5)
            if (p%kind(i) == KIND_WALL .and. (p%solid(i) < 1 .or. p%solid(i) > n_solids)) &
                call problem(6)
        end do
        message = ''
        call append_problems(env, counts, example, PROBLEM_TEXT, message)
        real_ids = pack(p%id(1:p%n_owned), p%kind(1:p%n_owned) == KIND_FLUID .or. &
            p%kind(1:p%n_owned) == KIND_WALL)
        call find_duplicate_ids(env, real_ids, size(real_ids), n_duplicates, duplicate)
        if (n_duplicates > 0) message = message // '; ' // int_text(n_duplicates) // &
            ' fluid or wall ids given more than once (the smallest: ' // &
            int_text(duplicate) // ')'
        stat = merge(1, 0, len(message) > 0)   ! the same on every rank (global counts)
        errmsg = ''
        if (stat /= 0) errmsg = "'" // path // "' holds particles no run writes: " // &
            message(3:) // '; refused (a file edited or damaged outside sphremesh?)'

    contains

        !> Every value finite and at most LARGEST_VALUE in magnitude (no comparison with a
        !> NaN, which traps where floating-point exceptions do).
        pure logical function usable(values)
            real(wp), intent(in) :: values(:)
            usable = all(ieee_is_finite(values))
            if (usable) usable = all(abs(values) <= LARGEST_VALUE)
        end function usable

        subroutine problem(which)
            integer, intent(in) :: which
            counts(which) = counts(which) + 1
            if (counts(which) > 1) return
            write(example(which), '(a,i0,a,3es14.6,a,i0,a,i0)') 'id ', p%id(i), ' at', &
                p%x(:, i), ' m, kind ', p%kind(i), ', level ', p%level(i)
        end subroutine problem
    end subroutine check_read_particles

    !> stat /= 0 and errmsg (naming path) when a fluid particle of p lies deeper than slack h
    !> inside one of the solids (the health check's limit: such a run stopped after its first
    !> step, with a failure snapshot, and --remesh with an internal message). Run after
    !> check_read_particles has passed (finite positions, valid smoothing lengths) and after
    !> the geometry was compared with the checkpoint's (a moved body is said so there).
    !> Collective.
    subroutine check_fluid_outside_solids(env, p, solids, slack, path, stat, errmsg)
        type(mpi_env_t), intent(in) :: env
        type(particles_t), intent(in) :: p
        type(solids_t), intent(in) :: solids
        real(wp), intent(in) :: slack
        character(len=*), intent(in) :: path
        integer, intent(out) :: stat
        character(len=:), allocatable, intent(out) :: errmsg
        integer(i8) :: counts(1)
        character(len=160) :: example(1)
        character(len=:), allocatable :: message
        integer :: i
        counts = 0
        example = ''
        do i = 1, p%n_owned
            if (p%kind(i) /= KIND_FLUID) cycle
            if (.not. fluid_too_deep(solids, p%x(:, i), slack * p%h(i))) cycle
            counts(1) = counts(1) + 1
            if (counts(1) == 1) write(example(1), '(a,i0,a,3es14.6,a)') 'id ', p%id(i), ' at', &
                p%x(:, i), ' m'
        end do
        message = ''
        call append_problems(env, counts, example, [character(len=80) :: 'fluid particles ' // &
            'inside a solid, deeper than the health check takes'], message)
        stat = merge(1, 0, len(message) > 0)
        errmsg = ''
        if (stat /= 0) errmsg = "'" // path // "' holds particles no run writes: " // &
            message(3:) // '; refused (a file edited or damaged outside sphremesh?)'
    end subroutine check_fluid_outside_solids

    !> Whether x lies deeper than `depth` inside one of the solids (the health check's
    !> criterion, with depth its slack times h).
    pure logical function fluid_too_deep(solids, x, depth) result(deep)
        type(solids_t), intent(in) :: solids
        real(wp), intent(in) :: x(3), depth
        integer :: k
        deep = .false.
        if (.not. allocated(solids%list)) return
        do k = 1, size(solids%list)
            if (solid_distance(solids%list(k), x) < -depth) then
                deep = .true.
                return
            end if
        end do
    end function fluid_too_deep

    !> message // '; <count> <problem text> (first: <example>)' for every problem counted on
    !> some rank: counts summed over the ranks, the example from the lowest rank that has one
    !> (collective; the same message on every rank).
    subroutine append_problems(env, counts, example, problem_text, message)
        type(mpi_env_t), intent(in) :: env
        integer(i8), intent(in) :: counts(:)
        character(len=*), intent(in) :: example(:), problem_text(:)
        character(len=:), allocatable, intent(inout) :: message
        integer(i8) :: total
        integer :: k, reporter
        character(len=:), allocatable :: text
        do k = 1, size(counts)
            total = global_sum(env, counts(k))
            if (total == 0) cycle
            reporter = int(-global_max(env, int(merge(-env%rank, -huge(0), counts(k) > 0), i8)))
            text = trim(example(k))
            call broadcast_text(env, text, reporter)
            message = message // '; ' // int_text(total) // ' ' // trim(problem_text(k)) // &
                ' (first: ' // text // ')'
        end do
    end subroutine append_problems
end module sph_read_checks
