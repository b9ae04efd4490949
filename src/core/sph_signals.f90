!> Requests to stop from outside: SIGTERM and SIGUSR1 (what schedulers send before a kill)
!> are recorded by a C handler (sph_signals.c); the run loop asks after every step.
module sph_signals
    use, intrinsic :: iso_c_binding, only: c_int
    implicit none
    private
    public :: signals_install, signal_received

    interface
        integer(c_int) function c_install() bind(C, name='sph_signals_install')
            import :: c_int
        end function c_install
        integer(c_int) function c_received() bind(C, name='sph_signal_received')
            import :: c_int
        end function c_received
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
end module sph_signals
