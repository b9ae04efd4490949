!> The two fatal-error paths of the code, written once:
!>  - fatal_collective: every rank reaches it with the same condition (input checks, set-up);
!>    rank 0 prints one message, MPI is finalized and the process exits with status 1.
!>  - fatal_abort: one rank may hit it alone; it prints its rank and aborts the communicator.
!> No traceback is printed: these are diagnosed errors, not crashes.
module sph_errors
    use, intrinsic :: iso_fortran_env, only: error_unit
    use, intrinsic :: iso_c_binding, only: c_int
    use mpi_f08
    implicit none
    private
    public :: fatal_collective, fatal_abort, check_mpi, set_error_comm, exit_process

    !> Exit status of a run stopped because an output file could not be written (a full or
    !> read-only file system): the files written before are whole and a restart continues
    !> from the newest checkpoint. 74 is EX_IOERR of sysexits.h, as 75 (stopped early, a
    !> checkpoint written) is EX_TEMPFAIL.
    integer, parameter, public :: STATUS_OUTPUT_FAILED = 74

    type(MPI_Comm), save :: error_comm  !< set once by sph_mpi_env; MPI_COMM_SELF until then
    logical, save :: have_comm = .false.

    interface
        subroutine c_exit(status) bind(C, name="exit")
            import :: c_int
            integer(c_int), value :: status
        end subroutine c_exit
    end interface

contains

    !> Tell the error module which communicator a collective stop or an abort concerns.
    subroutine set_error_comm(comm)
        type(MPI_Comm), intent(in) :: comm
        error_comm = comm
        have_comm = .true.
    end subroutine set_error_comm

    !> Collective stop: same condition on every rank; one message from rank 0; exit status 1
    !> (bad input, set-up), or `status` (3: the run became unhealthy, see sph_health;
    !> STATUS_OUTPUT_FAILED).
    subroutine fatal_collective(where, message, status)
        character(len=*), intent(in) :: where, message
        integer, intent(in), optional :: status
        integer :: rank, ierr
        logical :: initialized, finalized

        rank = 0
        call MPI_Initialized(initialized, ierr)
        call MPI_Finalized(finalized, ierr)
        if (initialized .and. .not. finalized .and. have_comm) then
            call MPI_Comm_rank(error_comm, rank, ierr)
        end if
        if (rank == 0) then
            write(error_unit, '(a)') 'sphremesh: error in ' // trim(where) // ': ' // trim(message)
            flush(error_unit)
        end if
        if (initialized .and. .not. finalized) then
            if (have_comm) call MPI_Barrier(error_comm, ierr)
            call MPI_Finalize(ierr)
        end if
        if (present(status)) then
            call exit_process(status)
        else
            call exit_process(1)
        end if
    end subroutine fatal_collective

    !> Abort from a single rank: prints the rank and takes the whole job down.
    subroutine fatal_abort(where, message)
        character(len=*), intent(in) :: where, message
        integer :: rank, ierr
        logical :: initialized, finalized
        character(len=16) :: rank_text

        rank = -1
        call MPI_Initialized(initialized, ierr)
        call MPI_Finalized(finalized, ierr)
        if (initialized .and. .not. finalized) then
            if (have_comm) then
                call MPI_Comm_rank(error_comm, rank, ierr)
            else
                call MPI_Comm_rank(MPI_COMM_SELF, rank, ierr)
            end if
        end if
        write(rank_text, '(i0)') rank
        write(error_unit, '(a)') 'sphremesh: rank ' // trim(rank_text) // ': error in ' // &
            trim(where) // ': ' // trim(message)
        flush(error_unit)
        if (initialized .and. .not. finalized) then
            if (have_comm) then
                call MPI_Abort(error_comm, 1, ierr)
            else
                call MPI_Abort(MPI_COMM_SELF, 1, ierr)
            end if
        end if
        call exit_process(1)
    end subroutine fatal_abort

    !> Every MPI return code goes through here.
    subroutine check_mpi(ierr, where)
        integer, intent(in) :: ierr
        character(len=*), intent(in) :: where
        character(len=MPI_MAX_ERROR_STRING) :: text
        integer :: length, ierr2
        if (ierr == MPI_SUCCESS) return
        call MPI_Error_string(ierr, text, length, ierr2)
        call fatal_abort(where, 'MPI error: ' // text(1:length))
    end subroutine check_mpi

    !> Leave the process with a status and no STOP banner.
    subroutine exit_process(status)
        integer, intent(in) :: status
        flush(error_unit)
        call c_exit(int(status, c_int))
    end subroutine exit_process
end module sph_errors
