!> Where the wall time of a run's step loop goes: exclusive accumulators for its parts
!> (neighbour search, rates, halo exchange, integration, output, other). One part runs at a
!> time: entering a part charges the time since the last switch to the part that was
!> running and returns it, leaving charges the part and goes back to that one. A halo
!> refresh inside the rate evaluation is so charged to the halo only, and the parts add up
!> to the timed wall time. Nothing is charged outside timers_start .. timers_stop (set-up,
!> tests that call the stepper directly). Two MPI_Wtime calls per switch; the times can be
!> passed in (now) so the accounting is testable.
module sph_step_timers
    use mpi_f08, only: MPI_Wtime
    use sph_kinds, only: wp, i8
    implicit none
    private
    public :: step_timers_t, timers_start, timers_stop, timers_enter, timers_leave
    public :: timers_split_line
    public :: TIMER_IDLE, TIMER_SEARCH, TIMER_RATES, TIMER_HALO, TIMER_INTEGRATION, &
        TIMER_OUTPUT, TIMER_OTHER, N_TIMERS

    integer, parameter :: TIMER_IDLE = 0          !< not timing
    integer, parameter :: TIMER_SEARCH = 1        !< cell sort, neighbour list, mirrors
    integer, parameter :: TIMER_RATES = 2         !< pressure, densities, the pair loop
    integer, parameter :: TIMER_HALO = 3          !< halo build and refresh, migration
    !> the integrator's updates and what the step does besides (time-step limits, drift
    !> and health reductions, where a rank also waits for the slowest)
    integer, parameter :: TIMER_INTEGRATION = 4
    integer, parameter :: TIMER_OUTPUT = 5        !< snapshots, checkpoints, log lines
    integer, parameter :: TIMER_OTHER = 6         !< rebalancing, remeshing, zones, shifting
    integer, parameter :: N_TIMERS = 6
    character(len=11), parameter :: TIMER_NAMES(N_TIMERS) = [character(len=11) :: &
        'search', 'rates', 'halo', 'integration', 'output', 'other']

    type :: step_timers_t
        real(wp) :: seconds(N_TIMERS) = 0.0_wp   !< wall seconds charged to each part
        integer :: current = TIMER_IDLE          !< the part running now
        real(wp) :: since = 0.0_wp               !< when it was entered (MPI_Wtime)
        integer(i8) :: rate_evaluations = 0      !< evaluations of the rates while timing
    end type step_timers_t

contains

    !> Start timing; the time until the first part is entered is charged to `other`.
    subroutine timers_start(timers, now)
        type(step_timers_t), intent(inout) :: timers
        real(wp), intent(in), optional :: now
        timers%current = TIMER_OTHER
        timers%since = clock(now)
    end subroutine timers_start

    !> Charge the running part and stop timing.
    subroutine timers_stop(timers, now)
        type(step_timers_t), intent(inout) :: timers
        real(wp), intent(in), optional :: now
        call switch_to(timers, TIMER_IDLE, clock(now))
    end subroutine timers_stop

    !> Enter `part`; `previous` is the part to go back to with timers_leave.
    subroutine timers_enter(timers, part, previous, now)
        type(step_timers_t), intent(inout) :: timers
        integer, intent(in) :: part
        integer, intent(out) :: previous
        real(wp), intent(in), optional :: now
        previous = timers%current
        if (timers%current == TIMER_IDLE) return
        call switch_to(timers, part, clock(now))
    end subroutine timers_enter

    !> Leave the running part for `previous` (from the matching timers_enter).
    subroutine timers_leave(timers, previous, now)
        type(step_timers_t), intent(inout) :: timers
        integer, intent(in) :: previous
        real(wp), intent(in), optional :: now
        if (timers%current == TIMER_IDLE) return
        call switch_to(timers, previous, clock(now))
    end subroutine timers_leave

    subroutine switch_to(timers, part, now)
        type(step_timers_t), intent(inout) :: timers
        integer, intent(in) :: part
        real(wp), intent(in) :: now
        if (timers%current /= TIMER_IDLE) timers%seconds(timers%current) = &
            timers%seconds(timers%current) + (now - timers%since)
        timers%current = part
        timers%since = now
    end subroutine switch_to

    real(wp) function clock(now)
        real(wp), intent(in), optional :: now
        if (present(now)) then
            clock = now
        else
            clock = MPI_Wtime()
        end if
    end function clock

    !> The log's end-of-run line: seconds and share of each part (mean over the ranks), the
    !> timed total and the number of rate evaluations.
    pure function timers_split_line(seconds, rate_evaluations) result(line)
        real(wp), intent(in) :: seconds(N_TIMERS)
        integer(i8), intent(in) :: rate_evaluations
        character(len=:), allocatable :: line
        character(len=64) :: item
        real(wp) :: total
        integer :: k
        total = sum(seconds)
        line = 'time split:'
        do k = 1, N_TIMERS
            line = line // ' ' // trim(TIMER_NAMES(k)) // ' ' // fixed(seconds(k), 3) // &
                ' s (' // fixed(100.0_wp * seconds(k) / max(total, tiny(1.0_wp)), 1) // ' %)' &
                // merge(',', ';', k < N_TIMERS)
        end do
        write(item, '(i0)') rate_evaluations
        line = line // ' ' // fixed(total, 3) // ' s timed, ' // trim(item) // ' rate evaluations'
    contains
        !> value with `decimals` decimals and a leading zero, no blanks
        pure function fixed(value, decimals) result(text)
            real(wp), intent(in) :: value
            integer, intent(in) :: decimals
            character(len=:), allocatable :: text
            character(len=32) :: buffer
            character(len=16) :: form
            write(form, '(a,i0,a)') '(f32.', decimals, ')'
            write(buffer, form) value
            text = trim(adjustl(buffer))
        end function fixed
    end function timers_split_line
end module sph_step_timers
