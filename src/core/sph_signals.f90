!> Requests to stop from outside: SIGTERM and SIGUSR1 (what schedulers send before a kill)
!> and SIGINT (Ctrl-C; a second one ends the program at once) are recorded by a C handler
!> (sph_signals.c); the run loop asks after every step.
module sph_signals
    use, intrinsic :: iso_c_binding, only: c_int, c_ptr, c_char, c_f_pointer, &
        c_associated
    implicit none
    private
    public :: signals_install, signal_received, signal_name

    interface
        integer(c_int) function c_install() bind(C, name='sph_signals_install')
            import :: c_int
        end function c_install
        integer(c_int) function c_received() bind(C, name='sph_signal_received')
            import :: c_int
        end function c_received
        type(c_ptr) function c_name(signum) bind(C, name='sph_signal_name')
            import :: c_int, c_ptr
            integer(c_int), value :: signum
        end function c_name
    end interface

contains

    !> Install the handlers; stat /= 0 when the system refused.
    subroutine signals_install(stat)
        integer, intent(out) :: stat
        stat = int(c_install())
    end subroutine signals_install

    !> The signal number received since the start (0: none).
    integer function signal_received()
        signal_received = int(c_received())
    end function signal_received

    !> The name of a signal that signals_install handles ('SIGTERM', ...; '' for another).
    function signal_name(signum) result(name)
        integer, intent(in) :: signum
        character(len=:), allocatable :: name
        character(kind=c_char), pointer :: chars(:)
        type(c_ptr) :: text
        integer :: n, k
        name = ''
        text = c_name(int(signum, c_int))
        if (.not. c_associated(text)) return
        ! (the C names are at most 7 characters, NUL-terminated)
        call c_f_pointer(text, chars, [8])
        n = 0
        do while (n < 8)
            if (chars(n + 1) == achar(0)) exit
            n = n + 1
        end do
        name = repeat(' ', n)
        do k = 1, n
            name(k:k) = chars(k)
        end do
    end function signal_name
end module sph_signals
