!> File-system operations Fortran lacks, in one place: mkdir -p, rename, link, delete and directory
!> listing (libc through bind(C); the listing through sph_directory.c). Serial: the caller
!> decides which rank acts.
module sph_filesystem
    use, intrinsic :: iso_c_binding, only: c_char, c_int, c_null_char
    implicit none
    private
    public :: make_directories, rename_file, link_file, delete_file, list_directory
    public :: MAX_FILE_PATH

    !> The longest file path handed to HDF5 over MPI-IO: Open MPI's I/O component (4.1)
    !> builds names in a fixed buffer and aborts the process beyond about 243 characters
    !> ("buffer overflow detected", measured with output folders of 200-225 characters).
    integer, parameter :: MAX_FILE_PATH = 240

    interface
        integer(c_int) function c_mkdir(path, mode) bind(C, name="mkdir")
            import :: c_char, c_int
            character(kind=c_char), intent(in) :: path(*)
            integer(c_int), value :: mode
        end function c_mkdir
        integer(c_int) function c_rename(old, new) bind(C, name="rename")
            import :: c_char, c_int
            character(kind=c_char), intent(in) :: old(*), new(*)
        end function c_rename
        integer(c_int) function c_link(old, new) bind(C, name="link")
            import :: c_char, c_int
            character(kind=c_char), intent(in) :: old(*), new(*)
        end function c_link
        integer(c_int) function c_list_directory(path, buffer, capacity) &
                bind(C, name="sph_list_directory")
            import :: c_char, c_int
            character(kind=c_char), intent(in) :: path(*)
            character(kind=c_char), intent(out) :: buffer(*)
            integer(c_int), value :: capacity
        end function c_list_directory
    end interface

    integer, parameter :: listing_capacity = 4 * 1024 * 1024

contains

    !> mkdir -p. stat /= 0 when a component cannot be made.
    subroutine make_directories(path, stat)
        character(len=*), intent(in) :: path
        integer, intent(out) :: stat
        integer :: k
        logical :: exists
        integer(c_int) :: rc
        stat = 0
        do k = 2, len_trim(path) + 1
            if (k <= len_trim(path)) then
                if (path(k:k) /= '/') cycle
            end if
            inquire(file=path(1:k - 1) // '/.', exist=exists)
            if (exists) cycle
            rc = c_mkdir(path(1:k - 1) // c_null_char, int(o'755', c_int))
            inquire(file=path(1:k - 1) // '/.', exist=exists)
            if (.not. exists) then
                stat = 1
                return
            end if
        end do
    end subroutine make_directories

    !> Atomic rename within a file system. stat /= 0 on failure.
    subroutine rename_file(from, to, stat)
        character(len=*), intent(in) :: from, to
        integer, intent(out) :: stat
        stat = 0
        if (c_rename(from // c_null_char, to // c_null_char) /= 0) stat = 1
    end subroutine rename_file

    !> A second name `to` for the file `from` (a hard link: no copy, and the file stays
    !> whole under `to` when `from` is later moved or removed). stat /= 0 on failure (another
    !> file system, a file system without links, `to` exists).
    subroutine link_file(from, to, stat)
        character(len=*), intent(in) :: from, to
        integer, intent(out) :: stat
        stat = 0
        if (c_link(from // c_null_char, to // c_null_char) /= 0) stat = 1
    end subroutine link_file

    !> Remove a file if it exists.
    subroutine delete_file(path)
        character(len=*), intent(in) :: path
        integer :: unit, stat
        open(newunit=unit, file=path, status='old', iostat=stat)
        if (stat == 0) close(unit, status='delete')
    end subroutine delete_file

    !> The entry names of a directory, each followed by a new line. stat /= 0 when it cannot
    !> be read.
    subroutine list_directory(path, listing, stat)
        character(len=*), intent(in) :: path
        character(len=:), allocatable, intent(out) :: listing
        integer, intent(out) :: stat
        character(kind=c_char), allocatable :: buffer(:)
        integer :: used, k
        allocate(buffer(listing_capacity))
        used = c_list_directory(trim(path) // c_null_char, buffer, listing_capacity)
        stat = merge(0, 1, used >= 0)
        listing = repeat(' ', max(used, 0))
        do k = 1, used
            listing(k:k) = buffer(k)
        end do
    end subroutine list_directory
end module sph_filesystem
