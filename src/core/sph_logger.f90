!> Rank-0 logger with levels. Repeated warnings are counted under a key and summarised once,
!> so a per-particle condition never floods the log.
module sph_logger
    use, intrinsic :: iso_fortran_env, only: output_unit, error_unit, int64, real64
    use, intrinsic :: ieee_arithmetic, only: ieee_is_finite
    implicit none
    private
    public :: VERBOSITY_QUIET, VERBOSITY_INFO, VERBOSITY_DEBUG
    public :: logger_init, log_info, log_debug, log_warn, log_warn_counted, log_warning_summary
    public :: logger_is_root, int_text, sci_text, fixed_text, mb_text

    integer, parameter :: VERBOSITY_QUIET = 0, VERBOSITY_INFO = 1, VERBOSITY_DEBUG = 2
    integer, parameter :: max_keys = 64

    ! Logger settings: the logger's own state, set once by logger_init.
    integer, save :: my_rank = 0
    integer, save :: level = VERBOSITY_INFO
    character(len=64), save :: warn_keys(max_keys) = ''
    integer, save :: warn_counts(max_keys) = 0
    integer, save :: n_keys = 0

contains

    !> Set this process's rank (only rank 0 writes) and, optionally, the verbosity.
    subroutine logger_init(rank, verbosity)
        integer, intent(in) :: rank
        integer, intent(in), optional :: verbosity
        my_rank = rank
        if (present(verbosity)) level = verbosity
    end subroutine logger_init

    !> Whether this process writes the log (rank 0).
    logical function logger_is_root()
        logger_is_root = my_rank == 0
    end function logger_is_root

    !> Write one line of the log (rank 0, verbosity info and above).
    subroutine log_info(message)
        character(len=*), intent(in) :: message
        if (my_rank == 0 .and. level >= VERBOSITY_INFO) then
            write(output_unit, '(a)') trim(message)
            flush(output_unit)
        end if
    end subroutine log_info

    !> Write one debug line (rank 0, verbosity debug).
    subroutine log_debug(message)
        character(len=*), intent(in) :: message
        if (my_rank == 0 .and. level >= VERBOSITY_DEBUG) write(output_unit, &
            '(a)') '[debug] ' // trim(message)
    end subroutine log_debug

    !> A warning known to be the same on every rank: printed once by rank 0.
    subroutine log_warn(message)
        character(len=*), intent(in) :: message
        if (my_rank == 0) write(error_unit, '(a)') 'sphremesh: warning: ' // trim(message)
    end subroutine log_warn

    !> A warning that may repeat (per particle, per step): the first is printed, the rest counted.
    subroutine log_warn_counted(key, message)
        character(len=*), intent(in) :: key, message
        integer :: k
        do k = 1, n_keys
            if (warn_keys(k) == key) then
                warn_counts(k) = warn_counts(k) + 1
                return
            end if
        end do
        if (n_keys < max_keys) then
            n_keys = n_keys + 1
            warn_keys(n_keys) = key
            warn_counts(n_keys) = 1
        end if
        write(error_unit, '(a)') 'sphremesh: warning: ' // trim(message) // &
            ' (further occurrences counted, see summary)'
    end subroutine log_warn_counted

    !> At the end of a run: how many times each repeated warning was given.
    subroutine log_warning_summary()
        integer :: k
        character(len=16) :: text
        do k = 1, n_keys
            if (warn_counts(k) > 1) then
                write(text, '(i0)') warn_counts(k)
                write(error_unit, '(a)') 'sphremesh: warning "' // trim(warn_keys(k)) // &
                    '" occurred ' // trim(text) // ' times on this rank'
            end if
        end do
    end subroutine log_warning_summary

    !> An integer as text without padding, for messages.
    function int_text(value) result(text)
        integer(int64), intent(in) :: value
        character(len=:), allocatable :: text
        character(len=24) :: buffer
        write(buffer, '(i0)') value
        text = trim(buffer)
    end function int_text

    !> A memory or file size in megabytes (10^6 bytes, as the log's peak memory line), one
    !> decimal, without padding: '206.4 MB'; below 1 MB in kilobytes: '45.1 kB'.
    function mb_text(bytes) result(text)
        real(real64), intent(in) :: bytes
        character(len=:), allocatable :: text
        character(len=32) :: buffer
        if (abs(bytes) < 1.0e6_real64) then
            write(buffer, '(f0.1)') bytes / 1.0e3_real64
            text = ' kB'
        else
            write(buffer, '(f0.1)') bytes / 1.0e6_real64
            text = ' MB'
        end if
        if (buffer(1:1) == '.') buffer = '0' // buffer
        text = trim(buffer) // text
    end function mb_text

    !> A real in scientific notation with two decimals (or `decimals`), without padding, for
    !> messages. Beyond 1e+-99 the exponent takes three digits and keeps its E (an es format
    !> drops it there: a time of 6.56736-105 s in a health message).
    function sci_text(value, decimals) result(text)
        real(real64), intent(in) :: value
        integer, intent(in), optional :: decimals
        character(len=:), allocatable :: text
        character(len=40) :: buffer, form
        integer :: d
        logical :: wide
        d = 2
        if (present(decimals)) d = decimals
        ! (finiteness first: a comparison with NaN traps in a debug build)
        wide = .false.
        if (ieee_is_finite(value)) then
            if (value /= 0.0_real64) wide = abs(value) >= 9.9e99_real64 .or. &
                abs(value) < 1.0e-99_real64
        end if
        if (wide) then
            write(form, '(a, i0, a, i0, a)') '(es', d + 9, '.', d, 'e3)'
        else
            write(form, '(a, i0, a, i0, a)') '(es', d + 8, '.', d, ')'
        end if
        write(buffer, form) value
        text = trim(adjustl(buffer))
    end function sci_text

    !> A real in the fixed format f<width>.<decimals> (padded as that format pads it, so
    !> that columns stay aligned) when it fits, else in scientific notation (es12.5; also
    !> for a non-finite value): an error of 1000 % printed as asterisks before.
    function fixed_text(value, width, decimals) result(text)
        real(real64), intent(in) :: value
        integer, intent(in) :: width, decimals
        character(len=:), allocatable :: text
        character(len=32) :: buffer, form
        real(real64) :: limit
        ! the largest magnitude that fits once rounded (a minus sign takes a digit's place)
        limit = 10.0_real64**(width - decimals - 1) - 0.5_real64 * 10.0_real64**(-decimals)
        ! (finiteness first: a comparison with NaN traps in a debug build)
        if (.not. ieee_is_finite(value)) then
            form = '(es12.5)'
        else if (abs(value) < merge(limit / 10.0_real64, limit, value < 0.0_real64)) then
            write(form, '(a, i0, a, i0, a)') '(f', width, '.', decimals, ')'
        else
            form = '(es12.5)'
        end if
        write(buffer, form) value
        text = trim(buffer)
    end function fixed_text
end module sph_logger
