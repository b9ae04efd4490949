!> Cheap checks of a run's health, made after every step: non-finite values, a fluid particle
!> inside a solid (outside the fluid region), a fluid density outside a band around rho0, a
!> fluid particle faster than sound, a collapsing time step. "Inside" means deeper than
!> IN_SOLID_SLACK h behind the surface: Morris' first wall row lies half a spacing (0.38 h
!> with the cubic spline) behind it, and a fluid particle between the surface and that row
!> has not gone through the wall; with no slack, remeshed cylinder flows stopped on
!> particles 1e-4 dx behind the surface. No MPI here: the stepper agrees on the verdict
!> across ranks, writes a failure snapshot and stops every rank.
module sph_health
    use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
    use sph_kinds, only: wp, i8
    use sph_particles, only: particles_t, KIND_FLUID
    use sph_solids, only: solids_t, deepest_solid, solid_distance, SOLID_PLANE
    use sph_health_input, only: health_input_t
    use sph_logger, only: sci_text
    implicit none
    private
    public :: health_problem_t, check_particles, check_timestep
    public :: HEALTH_OK, HEALTH_NONFINITE, HEALTH_IN_SOLID, HEALTH_DENSITY, HEALTH_TIMESTEP
    public :: HEALTH_RUNAWAY, HEALTH_SPEED, check_displacement, IN_SOLID_SLACK

    integer, parameter :: HEALTH_OK = 0
    integer, parameter :: HEALTH_NONFINITE = 1   !< a position, velocity or density is NaN/Inf
    integer, parameter :: HEALTH_IN_SOLID = 2    !< a fluid particle inside a wall or body
    integer, parameter :: HEALTH_DENSITY = 3     !< a fluid density outside the band
    integer, parameter :: HEALTH_TIMESTEP = 4    !< the time step collapsed
    integer, parameter :: HEALTH_RUNAWAY = 5     !< a particle moved farther than the box in a step
    !> a fluid particle faster than the sound speed: the weakly compressible model assumes
    !> speeds of a tenth of it, and an unstable step (fixed_dt 1.27e-3 s on the L/20
    !> Poiseuille channel) ran to its end with speeds 1500 times the flow's, its densities
    !> within 1.3 % of rho0 (the force limit throttled the step), an error of 3.9e4 % and
    !> exit status 0 (fz41)
    integer, parameter :: HEALTH_SPEED = 6
    !> no speed check with a sound speed this large (its square would overflow)
    real(wp), parameter :: LARGEST_SPEED = 1.0e150_wp
    !> how deep (in the particle's smoothing length) behind a solid's surface counts as inside
    real(wp), parameter :: IN_SOLID_SLACK = 0.2_wp
    !> the screen of check_particles tests depths against the slack less this fraction of it
    real(wp), parameter :: SCREEN_HAIR = 1.0e-9_wp
    !> particles a block of the screen (their values stay in the cache between its loops)
    integer, parameter :: SCREEN_BLOCK = 2048

    !> The first problem found on this rank (code HEALTH_OK when none).
    type :: health_problem_t
        integer :: code = HEALTH_OK
        integer(i8) :: id = 0
        real(wp) :: x(3) = 0.0_wp
        character(len=:), allocatable :: what
    end type health_problem_t

contains

    !> Check every owned particle; the first problem found is returned. sound_speed (when
    !> given): the fastest a fluid particle may move.
    subroutine check_particles(limits, rho0, solids, p, problem, sound_speed)
        type(health_input_t), intent(in) :: limits
        real(wp), intent(in) :: rho0
        real(wp), intent(in), optional :: sound_speed
        type(solids_t), intent(in) :: solids
        type(particles_t), intent(in) :: p
        type(health_problem_t), intent(out) :: problem
        real(wp), parameter :: EIGHTH = 0.125_wp
        integer :: i, k, n_solids
        character(len=96) :: text
        real(wp) :: c
        logical :: check_speed
        logical, allocatable :: plane(:)
        real(wp), allocatable :: normal(:, :), point(:, :)
        problem%what = ''
        ! (no speed check without a sound speed, nor with one whose square would overflow)
        c = huge(1.0_wp)
        check_speed = .false.
        if (present(sound_speed)) then
            check_speed = sound_speed < LARGEST_SPEED
            if (check_speed) c = sound_speed
        end if
        ! planes tested inline (a dot product per particle and plane: every step, every
        ! particle), bodies through solid_distance; the deepest solid named only on a hit
        n_solids = 0
        if (allocated(solids%list)) n_solids = size(solids%list)
        allocate(plane(n_solids), normal(3, n_solids), point(3, n_solids))
        do k = 1, n_solids
            plane(k) = solids%list(k)%shape == SOLID_PLANE
            normal(:, k) = solids%list(k)%normal
            point(:, k) = solids%list(k)%point
        end do
        ! the search below, with its early exits and calls, cost 4 % of a channel step; when
        ! every solid is a plane, a screen the compiler vectorises clears a healthy step
        if (all(plane)) then
            if (all_clear(p%n_owned)) return
        end if
        do i = 1, p%n_owned
            ! one test per particle: a NaN or an infinity among the seven values makes their
            ! sum non-finite; each is scaled by 1/8 (exactly) so the sum cannot overflow
            if (.not. ieee_is_finite(EIGHTH * p%x(1, i) + EIGHTH * p%x(2, i) + &
                EIGHTH * p%x(3, i) + EIGHTH * p%v(1, i) + EIGHTH * p%v(2, i) + &
                EIGHTH * p%v(3, i) + EIGHTH * p%rho(i))) then
                call found(HEALTH_NONFINITE, 'a non-finite position, velocity or density')
                return
            end if
            if (p%kind(i) /= KIND_FLUID) cycle
            if (inside_a_solid(p%x(:, i), IN_SOLID_SLACK * p%h(i))) then
                k = deepest_solid(solids, p%x(:, i), 0.0_wp)
                call found(HEALTH_IN_SOLID, 'a fluid particle inside the solid ' // &
                    trim(solids%list(k)%name))
                return
            end if
            if (abs(p%rho(i) - rho0) > limits%density_band * rho0) then
                write(text, '(a,f6.3,a)') 'fluid density ' // sci_text(p%rho(i), 5) // &
                    ' kg/m^3 outside rho0 (1 +- ', limits%density_band, ')'
                call found(HEALTH_DENSITY, trim(text) // ' (&health density_band)')
                return
            end if
            if (.not. check_speed) cycle
            if (faster_than(p%v(:, i), c)) then
                call found(HEALTH_SPEED, 'a fluid particle at ' // &
                    sci_text(norm2(EIGHTH * p%v(:, i)) / EIGHTH, 3) // ' m/s, faster than ' // &
                    'the sound speed ' // sci_text(c, 3) // ' m/s: the step is unstable ' // &
                    '(&numerics fixed_dt, viscous_safety, cfl) or the flow outruns what ' // &
                    '&fluid sound_speed (or velocity_scale) was chosen for')
                return
            end if
        end do
    contains
        !> No particle among 1..n can fail a check of the search (screen_clear's, block by
        !> block, so that its loops find a block's values in the cache: one pass over memory
        !> instead of 2 + n_solids).
        logical function all_clear(n)
            integer, intent(in) :: n
            integer :: j0, j1
            do j0 = 1, n, SCREEN_BLOCK
                j1 = min(n, j0 + SCREEN_BLOCK - 1)
                if (.not. screen_clear(j1 - j0 + 1, p%x(:, j0:j1), p%v(:, j0:j1), &
                    p%rho(j0:j1), p%kind(j0:j1), p%h(j0:j1), rho0, limits%density_band, &
                    c, n_solids, normal, point)) then
                    all_clear = .false.
                    return
                end if
            end do
            all_clear = .true.
        end function all_clear

        !> x lies deeper than slack inside some solid.
        logical function inside_a_solid(x, slack)
            real(wp), intent(in) :: x(3), slack
            integer :: kk
            inside_a_solid = .true.
            do kk = 1, n_solids
                if (plane(kk)) then
                    if (normal(1, kk) * (x(1) - point(1, kk)) + normal(2, kk) * (x(2) - &
                        point(2, kk)) + normal(3, kk) * (x(3) - point(3, kk)) < -slack) return
                else
                    if (solid_distance(solids%list(kk), x) < -slack) return
                end if
            end do
            inside_a_solid = .false.
        end function inside_a_solid

        subroutine found(code, what)
            integer, intent(in) :: code
            character(len=*), intent(in) :: what
            problem%code = code
            problem%id = p%id(i)
            problem%x = p%x(:, i)
            problem%what = what
        end subroutine found
    end subroutine check_particles

    !> No particle of a block of n can fail a check of check_particles' search: every value
    !> finite and, for fluid particles, the density in its band, the speed below c and no
    !> plane crossed deeper
    !> than a hair less than the slack (a superset of the search's hits, whatever the
    !> rounding of the dot products). Explicit shapes and no branches (nor .and., which
    !> gfortran evaluates by branching), so that the loops vectorise over the whole vector
    !> width: with the strides unknown (the particle arrays' sections) they ran two lanes
    !> wide and gathered x and v, 3 % of a channel step. The comparisons only once every
    !> value is known to be finite (a NaN in an ordered comparison raises the invalid flag,
    !> which Debug builds trap).
    logical function screen_clear(n, x, v, rho, kind, h, rho0, density_band, c, n_solids, &
            normal, point)
        integer, intent(in) :: n, kind(n), n_solids
        !> c: the fastest a fluid particle may move
        real(wp), intent(in) :: x(3, n), v(3, n), rho(n), h(n), rho0, density_band, c
        real(wp), intent(in) :: normal(3, n_solids), point(3, n_solids)
        real(wp), parameter :: EIGHTH = 0.125_wp
        real(wp) :: band, s, thr, cs
        integer :: j, kk, n_bad
        n_bad = 0
        do j = 1, n
            s = EIGHTH * x(1, j) + EIGHTH * x(2, j) + EIGHTH * x(3, j) + EIGHTH * v(1, j) + &
                EIGHTH * v(2, j) + EIGHTH * v(3, j) + EIGHTH * rho(j)
            n_bad = n_bad + merge(0, 1, ieee_is_finite(s))
        end do
        screen_clear = .false.
        if (n_bad > 0) return
        band = density_band * rho0
        thr = -(1.0_wp - SCREEN_HAIR) * IN_SOLID_SLACK
        do j = 1, n
            n_bad = n_bad + merge(1, 0, kind(j) == KIND_FLUID) * &
                merge(1, 0, abs(rho(j) - rho0) > band)
        end do
        ! (a component above c / sqrt(3) for each speed above c: no square that overflows)
        cs = c / sqrt(3.0_wp)
        do j = 1, n
            n_bad = n_bad + merge(1, 0, kind(j) == KIND_FLUID) * &
                merge(1, 0, max(abs(v(1, j)), abs(v(2, j)), abs(v(3, j))) > cs)
        end do
        do kk = 1, n_solids
            do j = 1, n
                n_bad = n_bad + merge(1, 0, kind(j) == KIND_FLUID) * merge(1, 0, &
                    normal(1, kk) * (x(1, j) - point(1, kk)) + normal(2, kk) * &
                    (x(2, j) - point(2, kk)) + normal(3, kk) * (x(3, j) - point(3, kk)) < &
                    thr * h(j))
            end do
        end do
        screen_clear = n_bad == 0
    end function screen_clear

    !> |v| > c, without squares that overflow (any finite v, c below LARGEST_SPEED).
    pure logical function faster_than(v, c)
        real(wp), intent(in) :: v(3), c
        if (maxval(abs(v)) > c) then
            faster_than = .true.
        else
            faster_than = sum(v**2) > c * c
        end if
    end function faster_than

    !> The time step against the first one of the run, and (time given) against the
    !> resolution of the time: a step that no longer advances it (fixed_dt = 1e-30 s at
    !> t = 0.02 s ran thousands of steps at one time, writing checkpoints, until killed; the
    !> floor compares with the first step, which after a restart is the restart's own).
    subroutine check_timestep(limits, first_dt, dt, problem, time)
        type(health_input_t), intent(in) :: limits
        real(wp), intent(in) :: first_dt, dt
        type(health_problem_t), intent(inout) :: problem
        real(wp), intent(in), optional :: time
        character(len=256) :: text
        if (problem%code /= HEALTH_OK) return
        if (present(time)) then
            ! (a hundred steps to move the time by its last digit: hopeless all the same)
            if (dt < 100.0_wp * spacing(abs(time))) then
                text = 'the time step ' // sci_text(dt, 3) // ' s no longer advances the ' // &
                    'time (t = ' // sci_text(time, 5) // ' s): the time-step limits ' // &
                    '(&numerics fixed_dt, cfl; the sound speed) ask for too short a step'
                problem%code = HEALTH_TIMESTEP
                problem%what = trim(text)
                return
            end if
        end if
        if (limits%timestep_floor <= 0.0_wp) return
        if (dt >= limits%timestep_floor * first_dt) return
        text = 'the time step collapsed to ' // sci_text(dt, 3) // ' s from ' // &
            sci_text(first_dt, 3) // ' s (&health timestep_floor)'
        problem%code = HEALTH_TIMESTEP
        problem%what = trim(text)
    end subroutine check_timestep

    !> The largest distance a particle moved in the step against the box's largest length:
    !> farther (or not finite) and the step was far too long for its forces (a background
    !> pressure of 1e30 Pa with a fixed step of 1 ms threw particles 1e27 m, and the cell
    !> list's index overflowed before the particle check saw them).
    subroutine check_displacement(moved, box_length, problem)
        real(wp), intent(in) :: moved, box_length
        type(health_problem_t), intent(inout) :: problem
        character(len=200) :: text
        if (problem%code /= HEALTH_OK) return
        ! (finiteness first: a comparison with NaN traps in a debug build)
        if (ieee_is_finite(moved)) then
            if (moved <= box_length) return
        end if
        text = 'a particle moved ' // sci_text(moved, 3) // ' m in one step, farther ' // &
            'than the box is long (' // sci_text(box_length, 3) // ' m): the time step is ' // &
            'far too long for the forces (&numerics fixed_dt, cfl; the sound speed)'
        problem%code = HEALTH_RUNAWAY
        problem%what = trim(text)
    end subroutine check_displacement
end module sph_health
