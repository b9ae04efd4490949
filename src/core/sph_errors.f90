!> The two fatal-error paths of the code, written once:
!>  - fatal_collective: every rank reaches it with the same condition (input checks, set-up);
!>    rank 0 prints one message, MPI is finalized and the process exits with status 1.
!>  - fatal_abort: one rank may hit it alone; it prints its rank and aborts the communicator.
!> No traceback is printed: these are diagnosed errors, not crashes.
module sph_errors
    use, intrinsic :: iso_fortran_env, only: error_unit
    use, intrinsic :: iso_c_binding, only: c_int, c_char, c_null_char
    use mpi_f08
    implicit none
    private
    public :: fatal_collective, fatal_abort, check_mpi, set_error_comm, exit_process
    public :: remove_at_exit

    !> Exit status of a run stopped because an output file could not be written (a full or
    !> read-only file system): the files written before are whole and a restart continues
    !> from the newest checkpoint. 74 is EX_IOERR of sysexits.h, as 75 (stopped early, a
    !> checkpoint written) is EX_TEMPFAIL.
    integer, parameter, public :: STATUS_OUTPUT_FAILED = 74

    type(MPI_Comm), save :: error_comm  !< set once by sph_mpi_env; MPI_COMM_SELF until then
    logical, save :: have_comm = .false.
    !> a file this process removes when it leaves (remove_at_exit), '' = none, and then the
    !> folders it made for it, deepest first, one per line (each removed while empty)
    character(len=:), allocatable, save :: exit_removal, exit_folders

    interface
        subroutine c_exit(status) bind(C, name="exit")
            import :: c_int
            integer(c_int), value :: status
        end subroutine c_exit
        integer(c_int) function c_unlink(path) bind(C, name="unlink")
            import :: c_int, c_char
            character(kind=c_char), intent(in) :: path(*)
        end function c_unlink
        integer(c_int) function c_rmdir(path) bind(C, name="rmdir")
            import :: c_int, c_char
            character(kind=c_char), intent(in) :: path(*)
        end function c_rmdir
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
    !> abort: leave through MPI_Abort instead of MPI_Finalize, after the one message (an
    !> HDF5 file whose closing failed is still open in the library, and its clean-up at
    !> MPI_Finalize crashed every rank with SIGSEGV).
    subroutine fatal_collective(where, message, status, abort)
        character(len=*), intent(in) :: where, message
        integer, intent(in), optional :: status
        logical, intent(in), optional :: abort
        integer :: rank, ierr, code
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
        code = 1
        if (present(status)) code = status
        ! the remove_at_exit file goes before the barrier: once a rank has left with a
        ! non-zero status mpirun may kill the others, and rank 0's OUT.tmp of a refused
        ! --remesh stayed behind (a fresh clone's CI, 2 ranks)
        call remove_exit_files()
        if (initialized .and. .not. finalized) then
            if (have_comm) call MPI_Barrier(error_comm, ierr)
            if (present(abort)) then
                if (abort .and. have_comm) then
                    call MPI_Abort(error_comm, code, ierr)
                end if
            end if
            call MPI_Finalize(ierr)
        end if
        call exit_process(code)
    end subroutine fatal_collective

    !> Abort from a single rank: prints the rank and takes the whole job down.
    subroutine fatal_abort(where, message, status)
        character(len=*), intent(in) :: where, message
        !> the exit status (default 1; STATUS_OUTPUT_FAILED for a write that failed)
        integer, intent(in), optional :: status
        integer :: rank, ierr, code
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
        code = 1
        if (present(status)) code = status
        ! (MPI_Abort does not come back to exit_process)
        call remove_exit_files()
        if (initialized .and. .not. finalized) then
            if (have_comm) then
                call MPI_Abort(error_comm, code, ierr)
            else
                call MPI_Abort(MPI_COMM_SELF, code, ierr)
            end if
        end if
        call exit_process(code)
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

    !> Have exit_process remove `path` (a run's lock file, which the run holds to its end
    !> whatever way it leaves: done, stopped, or on an error), then `folders` (the folders
    !> made for it, deepest first, one per line), each while it is empty: a restart that
    !> failed left the output folder it had made for its lock.
    subroutine remove_at_exit(path, folders)
        character(len=*), intent(in) :: path
        character(len=*), intent(in), optional :: folders
        exit_removal = path
        exit_folders = ''
        if (present(folders)) exit_folders = folders
    end subroutine remove_at_exit

    !> The remove_at_exit file and empty folders removed (a process that leaves).
    subroutine remove_exit_files()
        integer(c_int) :: rc
        integer :: start, k
        if (.not. allocated(exit_removal)) return
        if (len(exit_removal) > 0) rc = c_unlink(exit_removal // c_null_char)
        start = 1
        do k = 1, len(exit_folders)
            if (exit_folders(k:k) /= new_line('a')) cycle
            ! (a folder with files in it stays, and so do those above it)
            if (c_rmdir(exit_folders(start:k - 1) // c_null_char) /= 0) exit
            start = k + 1
        end do
        exit_removal = ''
        exit_folders = ''
    end subroutine remove_exit_files

    !> Leave the process with a status and no STOP banner (removing the remove_at_exit file).
    subroutine exit_process(status)
        integer, intent(in) :: status
        call remove_exit_files()
        flush(error_unit)
        call c_exit(int(status, c_int))
    end subroutine exit_process
end module sph_errors
